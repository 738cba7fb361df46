"""Operations routes: liveness, readiness, Prometheus metrics, the model manifest, the demo page."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

from fastapi import APIRouter, Request
from fastapi.responses import FileResponse, JSONResponse, Response

from service.api.errors import error_responses
from service.api.inference import InferenceService, warming_headers
from service.api.metrics import CONTENT_TYPE
from service.features.card import model_card

STATIC_DIR = Path(__file__).resolve().parent.parent / "static"  # service/api/static

router = APIRouter()

# An absolute POSIX, home-relative or Windows path inside a manifest string (a training command's
# --out /home/alice/runs/x): the public copy keeps its last component only, the build machine's layout
# is nobody's business. A "/" after a word character (1/4, w/o) is not a path.
_ABSOLUTE_PATH = re.compile(r"""(?<![\w.])(?:~|[A-Za-z]:)?[/\\][^\s'"`,;()\[\]{}]*""")


def _redact_path(match: re.Match[str]) -> str:
    name = re.split(r"[/\\]", match.group(0).rstrip("/\\"))[-1]
    return f"<path>/{name}" if name else "<path>"


def public_manifest(value: Any) -> Any:
    """The manifest as ``/v1/model`` shows it: every absolute path reduced to its last component."""
    if isinstance(value, str):
        return _ABSOLUTE_PATH.sub(_redact_path, value)
    if isinstance(value, dict):
        return {key: public_manifest(item) for key, item in value.items()}
    if isinstance(value, list):
        return [public_manifest(item) for item in value]
    return value


def _service(request: Request) -> InferenceService:
    return request.app.state.inference


@router.get("/healthz", tags=["operations"], summary="Liveness: the process answers and warm-up did not fail")
async def healthz(request: Request) -> JSONResponse:
    service = _service(request)
    if service.failure is not None:  # absolute paths cut as in /v1/model: a probe is no place for them
        return JSONResponse({"status": "failed", "detail": public_manifest(service.failure)}, status_code=503)
    return JSONResponse({"status": "ok"})


@router.get(
    "/readyz", tags=["operations"], summary="Readiness: model loaded, hashes verified, JIT warmed",
    responses=error_responses(503),
)
async def readyz(request: Request) -> JSONResponse:
    service = _service(request)
    if not service.ready or service.draining:
        detail = public_manifest(service.failure) if service.failure else "the model is warming up"
        if service.draining:
            detail = "the server is shutting down"
        return JSONResponse({"status": "not ready", "detail": detail}, status_code=503,
                            headers=warming_headers())
    return JSONResponse({"status": "ready", "model": service.manifest.get("name")})


@router.get("/metrics", tags=["operations"], summary="Prometheus metrics (text exposition format)",
            response_class=Response)
async def metrics(request: Request) -> Response:
    return Response(_service(request).metrics.exposition(), media_type=CONTENT_TYPE)


@router.get(
    "/v1/model", tags=["model"], summary="The served model's manifest", responses=error_responses(503)
)
async def model(request: Request) -> dict[str, Any]:
    return public_manifest(_service(request).manifest)


@router.get(
    "/v1/model/card", tags=["model"], response_class=Response,
    summary="The served model's card: intended use, training data and its limits, metrics, speed, licence",
    responses={200: {"content": {"text/markdown": {}}, "description": "Markdown, generated from the "
                     "manifest (the model folder's README.md)"}, **error_responses(503)},
)
async def card(request: Request) -> Response:
    # From the manifest the service verified and serves, as /v1/model shows it (paths cut), so the card
    # and /v1/model never disagree; the folder's README.md is the same text
    # (tests/service/features/test_model_card.py).
    text = model_card(public_manifest(_service(request).manifest))
    return Response(text, media_type="text/markdown; charset=utf-8")


@router.get("/", include_in_schema=False)
async def demo_page() -> FileResponse:
    return FileResponse(STATIC_DIR / "index.html", media_type="text/html")


@router.get("/favicon.ico", include_in_schema=False)
async def favicon() -> FileResponse:
    # Browsers ask for /favicon.ico on any page that names no icon (/metrics, /v1/model, ...): the demo
    # page's own icon (a PNG, which every browser takes at this path) instead of a 404.
    return FileResponse(STATIC_DIR / "favicon.png", media_type="image/png")
