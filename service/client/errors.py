"""What the client raises: one base class, split by who has to act.

    StereoClientError
    ├── ServiceError              the service answered with an error status (status_code, detail, request_id)
    │   ├── BadRequestError       4xx: the request is wrong (a parameter, an image, a size); do not retry
    │   ├── ServerBusyError       503 on every attempt the retry policy allowed (retry_after, attempts)
    │   └── ServerError           other 5xx: a fault of the service; quote request_id in a report
    ├── TransportError            no answer at all: connection refused or reset, DNS, protocol
    │   └── RequestTimeoutError   the answer did not come within the client's timeout
    └── AnswerFormatError         an answer that cannot be decoded (not the format asked for)

    PairWarning (a UserWarning, issued through Python's warnings module): the service answered but found
    the pair suspect (swapped, not rectified, few pixels passing the left-right check)
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


class PairWarning(UserWarning):
    """The service's ``X-ADSM-Warning`` about the pair (``kind``: ``swapped``, ``unrectified`` or
    ``few-valid``); the answer is still returned. Silence or raise it with :mod:`warnings` filters."""

    def __init__(self, message: str) -> None:
        super().__init__(message)
        self.kind = message.split(":", 1)[0]
