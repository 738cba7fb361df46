"""A request whose body length is framed two ways is refused (issue 15, finding 7).

With both ``Content-Length`` and ``Transfer-Encoding``, a proxy in front and this server may disagree on
where the body ends (request smuggling). RFC 9112 section 6.3 lets a server reject such a message and says
the connection must be closed after it: 400 with ``Connection: close``, before any of the body is read.
"""

from __future__ import annotations

from starlette.responses import JSONResponse
from starlette.types import ASGIApp, Receive, Scope, Send


class RequestFraming:
    """ASGI middleware: 400 + ``Connection: close`` for Content-Length together with Transfer-Encoding."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] == "http":
            names = {name.lower() for name, _ in scope["headers"]}
            if b"content-length" in names and b"transfer-encoding" in names:
                answer = JSONResponse(
                    {"detail": "the request has both Content-Length and Transfer-Encoding, so its body "
                               "length is ambiguous (RFC 9112 section 6.3); send one of them"},
                    status_code=400, headers={"Connection": "close"},
                )
                await answer(scope, receive, send)
                return
        await self.app(scope, receive, send)
