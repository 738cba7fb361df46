"""The FastAPI application: wiring only (settings, lifespan, middleware, routes, static files).

What it wires lives beside it: the service object (inference.py, with queue.py and refusals.py), the
error table (errors.py), the routes (routes/: stereo, ops, docs) and the ASGI middleware (middleware/),
listed below from the outermost in.

Start-up: the model folder is loaded and its hashes verified before the server accepts connections
(a bad model fails the start, loudly); the JIT warm-up then runs in a thread while the server already
answers /healthz, and /readyz turns 200 when it is done. SIGTERM drains (service/api/draining.py).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import AsyncIterator

from fastapi import FastAPI
from starlette.concurrency import run_in_threadpool
from starlette.middleware import Middleware
from starlette.staticfiles import StaticFiles

import service
from service.api.allocator import pin_mmap_threshold
from service.api.draining import install_sigterm_drain
from service.api.errors import install_error_handlers
from service.api.inference import InferenceService
from service.api.middleware.body_size import BodySizeLimit
from service.api.middleware.body_timeout import BodyDeadline
from service.api.middleware.delivery import AnswerDelivery
from service.api.middleware.framing import RequestFraming
from service.api.middleware.metrics import MetricsMiddleware
from service.api.middleware.request_id import RequestIdMiddleware
from service.api.routes import docs, ops, stereo
from service.api.routes.ops import STATIC_DIR
from service.api.settings import Settings
from service.protocols import StereoMatcher

logger = logging.getLogger("service.api")

DESCRIPTION = """Dense disparity, depth and point clouds from a rectified stereo pair (ADSM towers + SGM).

Bad input never yields a 500: 400 for bad parameters or fields (FastAPI's 422 is folded into 400),
408 for a body that takes longer than ADSM_BODY_TIMEOUT_S to arrive, 413 for a body or image over the
limits, 415 for a part that is not an image, 503 + Retry-After when the queue is full. Every response
has an X-Request-ID header; stereo responses a Server-Timing header."""


def create_app(settings: Settings | None = None, *, matcher: StereoMatcher | None = None) -> FastAPI:
    """Build the app. ``settings`` default to ``Settings.from_env()``; ``matcher`` (anything that satisfies
    :class:`service.protocols.StereoMatcher`) replaces loading ``settings.model_dir`` (for embedding and
    tests)."""
    settings = Settings.from_env() if settings is None else settings
    inference = InferenceService(settings, matcher=matcher)

    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        pin_mmap_threshold()  # freed answers go back to the system (service/api/allocator.py)
        await run_in_threadpool(inference.load)
        warmup = asyncio.create_task(_warm(inference))
        restore_sigterm = install_sigterm_drain(inference)
        try:
            yield
        finally:
            restore_sigterm()
            warmup.cancel()

    app = FastAPI(
        title="ADSM stereo service",
        version=service.__version__,
        description=DESCRIPTION,
        lifespan=lifespan,
        docs_url=None,  # served from vendored files instead of a CDN (service/api/routes/docs.py)
        redoc_url=None,
        middleware=[
            # Outermost, so that its send is the server's: every answer leaves in bounded pieces.
            Middleware(AnswerDelivery, write_timeout_s=settings.write_timeout_s, unsent=inference.unsent),
            Middleware(RequestIdMiddleware),  # every response, even a crash, gets its ID
            Middleware(MetricsMiddleware, metrics=inference.metrics),
            Middleware(RequestFraming),
            Middleware(BodySizeLimit, max_body_bytes=settings.max_body_bytes),
            Middleware(BodyDeadline, timeout_s=settings.body_timeout_s),
        ],
    )
    app.state.inference = inference
    install_error_handlers(app)
    app.include_router(stereo.router)
    app.include_router(ops.router)
    app.include_router(docs.router)
    app.mount("/static", StaticFiles(directory=STATIC_DIR), name="static")
    return app


async def _warm(inference: InferenceService) -> None:
    try:
        await run_in_threadpool(inference.warm)
    except Exception as error:  # /healthz turns 503 so that an orchestrator restarts the process
        inference.failure = f"warm-up failed: {type(error).__name__}: {error}"
        logger.exception("model warm-up failed")
