"""Operations routes: liveness, readiness, Prometheus metrics, the model manifest, the demo page."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from fastapi import APIRouter, Request
from fastapi.responses import FileResponse, JSONResponse, Response

from service.api.errors import error_responses
from service.api.inference import InferenceService
from service.api.metrics import CONTENT_TYPE

STATIC_DIR = Path(__file__).with_name("static")

router = APIRouter()


def _service(request: Request) -> InferenceService:
    return request.app.state.inference


@router.get("/healthz", tags=["operations"], summary="Liveness: the process answers and warm-up did not fail")
async def healthz(request: Request) -> JSONResponse:
    service = _service(request)
    if service.failure is not None:
        return JSONResponse({"status": "failed", "detail": service.failure}, status_code=503)
    return JSONResponse({"status": "ok"})


@router.get(
    "/readyz", tags=["operations"], summary="Readiness: model loaded, hashes verified, JIT warmed",
    responses=error_responses(503),
)
async def readyz(request: Request) -> JSONResponse:
    service = _service(request)
    if not service.ready or service.draining:
        detail = service.failure or "the model is warming up"
        if service.draining:
            detail = "the server is shutting down"
        return JSONResponse({"status": "not ready", "detail": detail}, status_code=503,
                            headers={"Retry-After": "5"})
    return JSONResponse({"status": "ready", "model": service.manifest.get("name")})


@router.get("/metrics", tags=["operations"], summary="Prometheus metrics (text exposition format)",
            response_class=Response)
async def metrics(request: Request) -> Response:
    return Response(_service(request).metrics.exposition(), media_type=CONTENT_TYPE)


@router.get(
    "/v1/model", tags=["model"], summary="The served model's manifest", responses=error_responses(503)
)
async def model(request: Request) -> dict[str, Any]:
    return _service(request).manifest


@router.get("/", include_in_schema=False)
async def demo_page() -> FileResponse:
    return FileResponse(STATIC_DIR / "index.html", media_type="text/html")
