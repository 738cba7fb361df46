"""Answers are delivered in bounded pieces, within a deadline, and the bytes waiting for slow readers
are bounded in total (issue 15, finding 4).

Without this, an answer left the app as one message: uvicorn wrote it whole into the connection's
buffer and kept it there for as long as the client did not read, with no timeout (16 clients that never
read a 15 MB point cloud held +263 MiB). Now:

- the body goes out in pieces of ``CHUNK_BYTES``; uvicorn waits for the socket to drain before it takes
  the next piece, so at most about one piece (plus uvicorn's 64 KiB high-water mark) sits in a
  connection's buffer;
- the whole body must be taken within ``write_timeout_s`` (``ADSM_WRITE_TIMEOUT_S``) of its first byte,
  else the delivery stops, the connection is closed (uvicorn logs "ASGI callable returned without
  completing response") and the answer is released;
- :class:`Unsent` counts the bytes of every answer not yet taken by a socket; while it is over
  ``ADSM_MAX_UNSENT_BYTES`` new stereo requests are answered 503 + ``Retry-After`` (api/inference.py), so
  slow readers cannot pile up answers in memory faster than the deadline frees them.
"""

from __future__ import annotations

import asyncio
import logging

from starlette.types import ASGIApp, Message, Receive, Scope, Send

from service.api.allocator import malloc_trim

logger = logging.getLogger("service.api")

CHUNK_BYTES = 64 * 1024


class Unsent:
    """Bytes of answer bodies handed to the server but not yet taken by a socket, over all connections."""

    def __init__(self) -> None:
        self.bytes = 0


class AnswerDelivery:
    """ASGI middleware: response bodies in ``CHUNK_BYTES`` pieces, all taken within ``write_timeout_s``."""

    def __init__(self, app: ASGIApp, *, write_timeout_s: float, unsent: Unsent) -> None:
        self.app = app
        self.write_timeout_s = write_timeout_s
        self.unsent = unsent

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        loop = asyncio.get_running_loop()
        deadline: float | None = None
        abandoned = False

        async def paced_send(message: Message) -> None:
            nonlocal deadline, abandoned
            if abandoned:
                return  # the rest of this answer is dropped with its connection
            if message["type"] != "http.response.body":
                await send(message)
                return
            body: bytes = message.get("body", b"")
            more_body = message.get("more_body", False)
            if deadline is None:
                deadline = loop.time() + self.write_timeout_s
            self.unsent.bytes += len(body)
            offset = 0
            try:
                while True:
                    piece = body[offset:offset + CHUNK_BYTES]
                    last = offset + CHUNK_BYTES >= len(body)
                    remaining = deadline - loop.time()
                    if remaining <= 0:
                        raise TimeoutError
                    await asyncio.wait_for(
                        send({"type": "http.response.body", "body": piece,
                              "more_body": more_body or not last}),
                        remaining,
                    )
                    self.unsent.bytes -= len(piece)
                    offset += len(piece)
                    if last:
                        return
            except TimeoutError:
                abandoned = True
                logger.warning(
                    "%s %s: the client took %d of %d bytes of the answer in %g s (ADSM_WRITE_TIMEOUT_S); "
                    "connection closed", scope.get("method"), scope.get("path"), offset, len(body),
                    self.write_timeout_s,
                )
            finally:
                self.unsent.bytes -= len(body) - offset

        try:
            await self.app(scope, receive, paced_send)
        finally:
            if abandoned:
                malloc_trim()
