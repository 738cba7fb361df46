"""What the two body guards (size limit, deadline) share: running the app with a guarded ``receive``.

A guard raises its HTTPException inside the body read. Inside a route the app's exception handlers turn
it into the usual JSON answer; a read outside any route (no handler on the way) ends here, and is answered
the same way unless a response has already started.
"""

from __future__ import annotations

from starlette.exceptions import HTTPException
from starlette.responses import JSONResponse
from starlette.types import ASGIApp, Message, Receive, Scope, Send


async def run_guarded(app: ASGIApp, scope: Scope, receive: Receive, send: Send, *,
                      guarded_receive: Receive, error_type: type[HTTPException]) -> None:
    """``app(scope, guarded_receive, send)``, answering an ``error_type`` that escapes it as JSON."""
    response_started = False

    async def tracking_send(message: Message) -> None:
        nonlocal response_started
        response_started |= message["type"] == "http.response.start"
        await send(message)

    try:
        await app(scope, guarded_receive, tracking_send)
    except error_type as error:
        if response_started:
            raise
        answer = JSONResponse({"detail": error.detail}, status_code=error.status_code, headers=error.headers)
        await answer(scope, receive, send)
