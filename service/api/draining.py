"""SIGTERM drains the process: admitted requests finish, new ones get 503, then the server shuts down.

Uvicorn's own SIGTERM handling closes the listening socket at once, so a request sent during the
shutdown is refused at the TCP level, which a client or proxy cannot tell from a crash. Draining keeps
accepting connections while the admitted requests (running, queued or still uploading) finish: new
stereo requests and /readyz answer 503 + Retry-After (a load balancer takes the instance out, a client
retries elsewhere), and once none is left, or after ``DRAIN_TIMEOUT_S``, the signal goes on to the
server's own handler for its graceful shutdown. A second SIGTERM skips the wait.

The handler only wraps a server's Python-level SIGTERM handler (uvicorn's), from the main thread; an
app embedded without one (tests, another host) leaves the process's signal handling alone.
"""

from __future__ import annotations

import asyncio
import signal
import threading
from collections.abc import Callable
from types import FrameType
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from service.api.inference import InferenceService

# Below Kubernetes' default grace period of 30 s; uvicorn's own graceful timeout follows it.
DRAIN_TIMEOUT_S = 20.0
_POLL_S = 0.05


def install_sigterm_drain(inference: InferenceService) -> Callable[[], None]:
    """Wrap the current SIGTERM handler with draining; returns a function that puts it back."""
    previous = signal.getsignal(signal.SIGTERM)
    if threading.current_thread() is not threading.main_thread() or not callable(previous):
        return lambda: None
    loop = asyncio.get_running_loop()
    pending: set[asyncio.Task] = set()  # keeps the hand-over task referenced until it ends

    def hand_over(signum: int, frame: FrameType | None) -> None:
        previous(signum, frame)

    async def drain_then_hand_over(signum: int, frame: FrameType | None) -> None:
        deadline = loop.time() + DRAIN_TIMEOUT_S
        slot = inference.slot
        while (slot.waiting or slot.running) and loop.time() < deadline:
            await asyncio.sleep(_POLL_S)
        hand_over(signum, frame)

    def on_sigterm(signum: int, frame: FrameType | None) -> None:
        if inference.draining:  # asked twice: stop waiting
            loop.call_soon_threadsafe(hand_over, signum, frame)
            return
        inference.start_draining()

        def start() -> None:
            task = loop.create_task(drain_then_hand_over(signum, frame))
            pending.add(task)
            task.add_done_callback(pending.discard)

        loop.call_soon_threadsafe(start)

    signal.signal(signal.SIGTERM, on_sigterm)

    def restore() -> None:
        if signal.getsignal(signal.SIGTERM) is on_sigterm:
            signal.signal(signal.SIGTERM, previous)

    return restore
