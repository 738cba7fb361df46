"""When a 503 is tried again: after the service's ``Retry-After``, a bounded number of times, within a
bounded total wait.

The service answers 503 when its queue is full, while it warms up and while it drains for a restart, each
time with ``Retry-After`` (whole seconds: its estimate of the queue's wait, or a fixed 5 s). Asking
earlier only takes a place from someone else's turn, so the client never retries sooner than that; if
the wait the service asks for does not fit in what is left of ``max_wait_s``, it gives up at once
instead of sleeping and failing anyway.
"""

from __future__ import annotations

import dataclasses
import email.utils
import time
from collections.abc import Callable
from datetime import UTC, datetime


@dataclasses.dataclass(frozen=True)
class RetryPolicy:
    """``retries`` further attempts after a 503, sleeping at most ``max_wait_s`` seconds in all.

    Without a ``Retry-After`` the waits are ``backoff_s``, then twice that, and so on. ``sleep`` is
    ``time.sleep`` (tests pass a recorder). ``RetryPolicy(retries=0)`` turns retrying off.
    """

    retries: int = 4
    max_wait_s: float = 60.0
    backoff_s: float = 1.0
    sleep: Callable[[float], object] = time.sleep

    def __post_init__(self) -> None:
        if self.retries < 0 or not self.max_wait_s >= 0 or not self.backoff_s >= 0:
            raise ValueError(f"retries, max_wait_s and backoff_s must be >= 0, got {self}")

    def delay(self, retry: int, retry_after: float | None, waited: float) -> float | None:
        """Seconds to wait before retry number ``retry`` (1, 2, ...), or None to give up."""
        if retry > self.retries:
            return None
        wait = self.backoff_s * 2.0 ** (retry - 1) if retry_after is None else retry_after
        return wait if waited + wait <= self.max_wait_s else None


def retry_after_seconds(value: str | None, *, now: datetime | None = None) -> float | None:
    """``Retry-After`` in seconds: delay-seconds or an HTTP date (RFC 9110 10.2.3); None if absent or
    unreadable."""
    if not value:
        return None
    value = value.strip()
    if value.isdigit():
        return float(value)
    try:
        when = email.utils.parsedate_to_datetime(value)
    except (TypeError, ValueError):
        return None
    if when.tzinfo is None:  # an HTTP date is always GMT
        when = when.replace(tzinfo=UTC)
    return max(0.0, (when - (now or datetime.now(UTC))).total_seconds())
