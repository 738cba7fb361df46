"""Request body deadline: 408 when a client takes longer than ``ADSM_BODY_TIMEOUT_S`` to send its body.

A stereo request holds a queue place from admission to its end, and it is admitted before its body is
read (so a full queue costs the client nothing, and at most queue-size + 1 bodies are in memory).
Without a deadline, ``ADSM_QUEUE_SIZE + 1`` clients trickling their uploads could hold every place
forever. The clock starts when the app first reads the body and covers every chunk up to the last;
reads after that (Starlette polls for a disconnect while a request waits for the inference slot) pass
through untouched, so a long queue wait is never mistaken for a slow upload.

The 408 is raised inside the route's body read, like the streaming 413 of ``body_size.py``: the route's
admission block ends (the place is given back) and the app's exception handlers answer with the usual
JSON ``detail``. The rest of the body is still on the connection, so the answer asks to close it.
"""

from __future__ import annotations

import anyio
from starlette.exceptions import HTTPException
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from service.api.middleware.body_guard import run_guarded


class BodyTimedOut(HTTPException):
    def __init__(self, timeout_s: float) -> None:
        super().__init__(
            status_code=408,
            detail=f"the request body took longer than {timeout_s:g} s to arrive (this server's limit, "
            "ADSM_BODY_TIMEOUT_S)",
            headers={"Connection": "close"},
        )


class BodyDeadline:
    """ASGI middleware: every HTTP request body must be complete within ``timeout_s`` of its first read."""

    def __init__(self, app: ASGIApp, *, timeout_s: float) -> None:
        self.app = app
        self.timeout_s = timeout_s

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        deadline: float | None = None
        complete = False  # the last body chunk (or a disconnect) has been received

        async def timed_receive() -> Message:
            nonlocal deadline, complete
            if complete:
                return await receive()
            if deadline is None:
                deadline = anyio.current_time() + self.timeout_s
            # A cancel scope of our own: an outer cancellation (Starlette's disconnect poll, shutdown)
            # still propagates as a cancellation, and only our deadline turns into the 408.
            with anyio.CancelScope(deadline=deadline) as timer:
                message = await receive()
            if timer.cancelled_caught:
                # The body is abandoned; a later read can only be a disconnect listener's, which must
                # reach the server rather than time out again.
                complete = True
                raise BodyTimedOut(self.timeout_s)
            complete = message["type"] != "http.request" or not message.get("more_body", False)
            return message

        await run_guarded(self.app, scope, receive, send, guarded_receive=timed_receive,
                          error_type=BodyTimedOut)
