"""The inference slot: one inference at a time per process, a bounded FIFO of waiting requests.

The matcher is not thread-safe and each inference already uses every core, so running two at once
would only make both slower. Requests beyond the queue are turned away at once (503 + Retry-After)
instead of piling up until their clients time out; a request whose client disconnects while waiting
gives its place back without running.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import time
from collections.abc import AsyncIterator, Awaitable, Callable
from typing import TypeVar

from starlette.concurrency import run_in_threadpool

from service.api.refusals import ClientGone, Unavailable

T = TypeVar("T")

_DISCONNECT_POLL_S = 0.05


class QueueFull(Unavailable):
    """Every place in the queue is taken; ``retry_after`` is a whole-second estimate of the wait."""

    def __init__(self, retry_after: int) -> None:
        super().__init__(f"the inference queue is full; retry in {retry_after} s", retry_after=retry_after)


class ClientDisconnected(ClientGone):
    """The client went away while its request waited; the inference was never started."""


class InferenceSlot:
    """Admission control plus mutual exclusion for the matcher.

    ``admit()`` reserves a place (running or waiting) for the whole life of a request, so the
    check is done before the body is parsed; ``run()`` then waits its turn and runs the CPU work
    in a worker thread, keeping the event loop free for health checks and other admissions.
    """

    def __init__(self, *, queue_size: int) -> None:
        if queue_size < 0:
            raise ValueError(f"queue_size must be >= 0, got {queue_size}")
        self.queue_size = queue_size
        self._admitted = 0
        self._running = False
        self._lock = asyncio.Lock()
        self._recent_s = 1.0  # moving average of inference seconds, for Retry-After

    @property
    def waiting(self) -> int:
        """Requests admitted and not running (parsing their body, decoding or queued)."""
        return self._admitted - int(self._running)

    @property
    def running(self) -> bool:
        return self._running

    def retry_after(self) -> int:
        return max(1, math.ceil(self._recent_s * (self.waiting + 1)))

    def admit(self) -> Admission:
        """Reserve a place (raise ``QueueFull`` at once if there is none); release it by leaving the
        returned context manager."""
        if self._admitted >= self.queue_size + 1:
            raise QueueFull(self.retry_after())
        self._admitted += 1
        return Admission(self)

    def _release(self) -> None:
        self._admitted -= 1

    async def run(
        self,
        work: Callable[..., T],
        *args: object,
        disconnected: Callable[[], Awaitable[bool]] | None = None,
    ) -> T:
        """Wait for the slot (FIFO), then run ``work(*args)`` in a thread and return its result.

        ``disconnected`` is polled while waiting; when it answers True the wait is abandoned and
        ``ClientDisconnected`` raised. Once started, the work runs to completion: a thread cannot be
        interrupted, and the slot stays taken until it ends.
        """
        async with self._turn(disconnected):
            self._running = True
            started = time.perf_counter()
            try:
                return await run_in_threadpool(work, *args)
            finally:
                self._running = False
                self._recent_s = 0.7 * self._recent_s + 0.3 * (time.perf_counter() - started)

    @contextlib.asynccontextmanager
    async def _turn(self, disconnected: Callable[[], Awaitable[bool]] | None) -> AsyncIterator[None]:
        acquire = asyncio.ensure_future(self._lock.acquire())
        watcher = asyncio.ensure_future(_until_disconnected(disconnected)) if disconnected else None
        try:
            await asyncio.wait([t for t in (acquire, watcher) if t], return_when=asyncio.FIRST_COMPLETED)
        except BaseException:  # cancelled while waiting (e.g. server shutdown): never leak the lock
            if await _settle(acquire, watcher):
                self._lock.release()
            raise
        if not await _settle(acquire, watcher):
            raise ClientDisconnected("client disconnected while queued")
        try:
            yield
        finally:
            self._lock.release()


class Admission:
    """A place in the slot, held until the ``with`` block ends."""

    def __init__(self, slot: InferenceSlot) -> None:
        self._slot: InferenceSlot | None = slot

    def __enter__(self) -> Admission:
        return self

    def __exit__(self, *exc_info: object) -> None:
        if self._slot is not None:
            self._slot._release()
            self._slot = None


async def _settle(acquire: asyncio.Future, watcher: asyncio.Future | None) -> bool:
    """Stop both waits; True when the lock was acquired (the acquire may win the race with cancel)."""
    if watcher is not None:
        watcher.cancel()
    if not acquire.done():
        acquire.cancel()
    with contextlib.suppress(asyncio.CancelledError):
        await acquire
    return not acquire.cancelled()


async def _until_disconnected(disconnected: Callable[[], Awaitable[bool]]) -> None:
    while not await disconnected():
        await asyncio.sleep(_DISCONNECT_POLL_S)
