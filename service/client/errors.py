"""What the client raises: one base class, split by who has to act.

    StereoClientError
    ├── ServiceError              the service answered with an error status (status_code, detail, request_id)
    │   ├── BadRequestError       4xx: the request is wrong (a parameter, an image, a size); do not retry
    │   ├── ServerBusyError       503 on every attempt the retry policy allowed (retry_after, attempts)
    │   └── ServerError           other 5xx: a fault of the service; quote request_id in a report
    ├── TransportError            no answer at all: connection refused or reset, DNS, protocol
    │   └── RequestTimeoutError   the answer did not come within the client's timeout
    └── AnswerFormatError         an answer that cannot be decoded (not the format asked for)
"""

from __future__ import annotations

from typing import Any


class StereoClientError(Exception):
    """Base of every error :class:`~service.client.StereoClient` raises."""


class ServiceError(StereoClientError):
    """The service answered with an error status; ``detail`` is its own one-sentence explanation."""

    def __init__(self, status_code: int, detail: str, *, request_id: str | None = None,
                 errors: list[dict[str, Any]] | None = None) -> None:
        self.status_code = status_code
        self.detail = detail
        self.request_id = request_id
        self.errors = errors or []  # request-validation problems (loc, msg, type) when the service lists them
        where = f" (request {request_id})" if request_id else ""
        super().__init__(f"HTTP {status_code}: {detail}{where}")


class BadRequestError(ServiceError):
    """4xx: the request itself is wrong (400 parameters or pair, 408 slow upload, 413 too large, 415 not an
    image); sending it again gives the same answer."""


class ServerBusyError(ServiceError):
    """503 (queue full, warming up, shutting down) on every attempt within the retry policy's bounds."""

    def __init__(self, status_code: int, detail: str, *, request_id: str | None = None,
                 retry_after: float | None = None, attempts: int = 1) -> None:
        self.retry_after = retry_after  # the service's last Retry-After, seconds
        self.attempts = attempts
        super().__init__(status_code, f"{detail} (gave up after {attempts} attempt"
                         f"{'s' if attempts != 1 else ''})", request_id=request_id)


class ServerError(ServiceError):
    """A 5xx other than 503: a fault of the service, not of the request."""


class TransportError(StereoClientError):
    """No answer: the connection failed or broke (the httpx exception is chained as ``__cause__``)."""


class RequestTimeoutError(TransportError):
    """The service did not answer within the client's timeout."""


class AnswerFormatError(StereoClientError):
    """A 2xx answer whose body is not what was asked for (wrong media type, truncated, missing part)."""
