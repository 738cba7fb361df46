"""Why the service turns a request away, in the service's own words: no status codes here.

The service object (inference.py) and its queue (queue.py) raise these, as the runtime raises its own
(``service.limits.DisparityRangeError`` and ``LimitError``, ``service.io.ImageDecodeError`` and
``ImageTooLargeError``); ``service/api/errors.py`` maps every one of them to its HTTP status and headers
in one table, so the service could be driven by something other than HTTP without a change.
"""

from __future__ import annotations

# Seconds to wait after a refusal whose end the service cannot estimate (loading, warming up, draining, too
# many unsent answers); a full queue estimates its own wait (queue.py).
WARMING_RETRY_AFTER_S = 5


class BadRequest(ValueError):
    """The request itself is wrong: a missing, misspelt or textual multipart part, not a multipart body,
    images of different sizes, or options the matcher refuses for this pair."""


class ClientGone(Exception):
    """The client went away (during its upload or while waiting); nobody will read an answer."""


class Unavailable(Exception):
    """The service cannot take the request now; the client may retry after ``retry_after`` seconds.
    ``close_connection``: the connection should be closed after the answer (the process is leaving)."""

    def __init__(self, message: str, *, retry_after: int = WARMING_RETRY_AFTER_S,
                 close_connection: bool = False) -> None:
        super().__init__(message)
        self.retry_after = retry_after
        self.close_connection = close_connection


class NotReady(Unavailable):
    """The model is not loaded or not warmed up yet."""


class Draining(Unavailable):
    """The process is shutting down (SIGTERM, draining.py): admitted requests finish, new ones go
    elsewhere."""

    def __init__(self, message: str) -> None:
        super().__init__(message, close_connection=True)


class Backlogged(Unavailable):
    """Slow clients have left more answer bytes untaken than the service may hold (middleware/delivery.py)."""
