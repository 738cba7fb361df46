"""POST /disparity, /depth and /pointcloud: a rectified pair in, a map or a point cloud out."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Annotated, Any, Literal

from fastapi import APIRouter, Depends, HTTPException, Query, Request
from fastapi.dependencies.models import Dependant
from fastapi.responses import Response
from starlette.concurrency import run_in_threadpool

from service.api.errors import error_responses
from service.api.inference import InferenceService, StereoMatch
from service.api.routes import geometry
from service.api.routes.encoding import (
    FILE_EXTENSIONS,
    multipart_mixed,
    negotiate_format,
    server_timing,
    validity_png,
)
from service.io import encode_disparity, media_type
from service.matcher import MatchOptions
from service.optimization import MAX_PENALTY


def _query_names(dependant: Dependant) -> set[str]:
    names = {param.alias for param in dependant.query_params}
    for dependency in dependant.dependencies:
        names |= _query_names(dependency)
    return names


def reject_unknown_query(request: Request) -> None:
    """A misspelt parameter is refused rather than ignored (which would silently apply the default), and
    so is a repeated one (the last would silently win)."""
    known = _query_names(request.scope["route"].dependant)
    if unknown := sorted(set(request.query_params) - known):
        raise HTTPException(
            400, f"unknown query parameter '{unknown[0]}'; this route takes {', '.join(sorted(known))}"
        )
    names = [name for name, _ in request.query_params.multi_items()]
    if repeated := sorted({name for name in names if names.count(name) > 1}):
        raise HTTPException(400, f"query parameter '{repeated[0]}' is given more than once; give it once")


router = APIRouter(tags=["stereo"], dependencies=[Depends(reject_unknown_query)])

# The request body is parsed by the service itself (admission comes before reading it), so its
# schema is declared here for the OpenAPI page.
_PAIR_BODY: dict[str, Any] = {
    "requestBody": {
        "required": True,
        "content": {
            "multipart/form-data": {
                "schema": {
                    "type": "object",
                    "required": ["left", "right"],
                    "additionalProperties": False,
                    "properties": {
                        "left": {"type": "string", "format": "binary", "description": "left image"},
                        "right": {"type": "string", "format": "binary", "description": "right image"},
                    },
                }
            }
        },
    }
}
_ERRORS = error_responses(400, 408, 413, 415, 503)

Encoded = tuple[bytes, str, dict[str, str]]  # body, media type, extra headers

# Bounds of the float parameters: finite, and far beyond any real camera, so that no value overflows
# float32 on its way through depth (B f / d) or the point cloud. The SGM penalties' bound is SGM's own
# (service.optimization.MAX_PENALTY, 4096 cost units: 32 times the shipped cost scale).
MAX_FOCAL_PX = 1e6
MAX_BASELINE_M = 1e4
# Lower bounds: f x B of 1e-60 underflows float32 and made every depth 0 m (a point cloud at the origin).
# No camera has a focal length under a thousandth of a pixel or a baseline under a micrometre.
MIN_FOCAL_PX = 1e-3
MIN_BASELINE_M = 1e-6
MAX_PRINCIPAL_PX = 1e6


def stereo_options(
    max_disparity: Annotated[
        int | None, Query(ge=1, description="Disparities searched: 0..max_disparity-1 (default: model's).")
    ] = None,
    lr_check: Annotated[bool, Query(description="Inner left-right check (occlusion/mismatch).")] = True,
    fill: Annotated[bool | None, Query(description="Fill invalid pixels along rays (needs lr_check; "
                                       "default: lr_check).")] = None,
    subpixel: Annotated[bool, Query(description="Quadratic sub-pixel refinement.")] = True,
    adaptive_p2: Annotated[bool, Query(description="Lower SGM's jump penalty across image edges, so depth "
                                       "edges follow image edges.")] = True,
    border: Annotated[bool, Query(description="Give the left border band (pixels whose match lies left of "
                                  "the right image) the disparity of the surface they continue.")] = True,
    weighted_median: Annotated[bool, Query(description="Image-guided weighted median at depth edges, so "
                                           "depth edges follow image edges.")] = True,
    p1: Annotated[float | None, Query(ge=0, le=MAX_PENALTY, allow_inf_nan=False,
                                      description="SGM small-jump penalty (default: model's).")] = None,
    p2: Annotated[float | None, Query(ge=0, le=MAX_PENALTY, allow_inf_nan=False,
                                      description="SGM large-jump penalty (default: model's).")] = None,
) -> MatchOptions:
    if fill and not lr_check:
        # Filling fills what the check rejected: without the check it would silently do nothing.
        raise HTTPException(400, "fill=true needs lr_check=true (filling fills the pixels the check rejects)")
    try:
        return MatchOptions(
            max_disparity=max_disparity, lr_check=lr_check, fill=lr_check if fill is None else fill,
            subpixel=subpixel, border=border, weighted_median=weighted_median, adaptive_p2=adaptive_p2,
            p1=p1, p2=p2,
        )
    except ValueError as error:  # raised in a dependency it would otherwise end as a 500
        raise HTTPException(400, str(error)) from None


Options = Annotated[MatchOptions, Depends(stereo_options)]


def _service(request: Request) -> InferenceService:
    return request.app.state.inference


def _binary(media: str, description: str) -> dict[str, Any]:
    schema = {"type": "string", "format": "binary"}
    return {"content": {media: {"schema": schema}}, "description": description}


@router.post(
    "/disparity",
    summary="Disparity map of a rectified pair",
    openapi_extra=_PAIR_BODY,
    response_class=Response,
    responses={
        200: {
            "description": "png16 (uint16 = d x 256, 0 invalid), npy (float32, NaN invalid), pfm (inf "
            "invalid) or color (RGB PNG). With validity=true: multipart/mixed with the parts "
            "'disparity' and 'validity' (8-bit PNG of validity codes).",
            "content": {
                "image/png": {},
                "application/x-npy": {},
                "image/x-portable-floatmap": {},
                "multipart/mixed": {},
            },
        },
        **_ERRORS,
    },
)
async def disparity(
    request: Request,
    options: Options,
    format: Annotated[
        Literal["png16", "npy", "pfm", "color"] | None,
        Query(description="Output format; default from the Accept header, else png16."),
    ] = None,
    validity: Annotated[bool, Query(description="Also return the validity map (multipart/mixed).")] = False,
) -> Response:
    service = _service(request)
    chosen = negotiate_format(format, request.headers.get("accept"), offered=("png16", "npy", "pfm", "color"))
    match = await service.match(request, options)

    def encode() -> Encoded:
        body = encode_disparity(match.result.disparity, chosen)
        headers = {"X-Disparity-Format": chosen}
        if not validity:
            return body, media_type(chosen), headers
        return *multipart_mixed([
            ("disparity", f"disparity.{FILE_EXTENSIONS[chosen]}", media_type(chosen), body),
            ("validity", "validity.png", "image/png", validity_png(match.result.validity)),
        ]), headers

    return await _respond(service, match, encode)


@router.post(
    "/depth",
    summary="Depth map (z = baseline x focal / disparity)",
    openapi_extra=_PAIR_BODY,
    response_class=Response,
    responses={
        200: {
            "description": "npy: float32 metres, NaN invalid; png16 (image/png): uint16 millimetres, 0 "
            "invalid or beyond 65.535 m.",
            "content": {"application/x-npy": {}, "image/png": {}},
        },
        **_ERRORS,
    },
)
async def depth(
    request: Request,
    options: Options,
    focal_px: Annotated[float, Query(ge=MIN_FOCAL_PX, le=MAX_FOCAL_PX, allow_inf_nan=False,
                                     description="Focal length in pixels.")],
    baseline_m: Annotated[float, Query(ge=MIN_BASELINE_M, le=MAX_BASELINE_M, allow_inf_nan=False,
                                       description="Stereo baseline in metres.")],
    format: Annotated[
        Literal["npy", "png16"] | None, Query(description="Output format; default from Accept, else npy.")
    ] = None,
) -> Response:
    service = _service(request)
    chosen = negotiate_format(format, request.headers.get("accept"), offered=("npy", "png16"))
    match = await service.match(request, options)

    def encode() -> Encoded:
        disparity = match.result.disparity
        depth = geometry.depth_from_disparity(disparity, focal_px=focal_px, baseline_m=baseline_m)
        if chosen == "png16":
            return geometry.depth_png16(depth), "image/png", {"X-Depth-Format": chosen}
        return geometry.depth_npy(depth), "application/x-npy", {"X-Depth-Format": chosen}

    return await _respond(service, match, encode)


@router.post(
    "/pointcloud",
    summary="Coloured point cloud (binary little-endian PLY, metres, left camera frame)",
    openapi_extra=_PAIR_BODY,
    response_class=Response,
    responses={200: _binary("application/x-ply", "PLY; pixels without depth are dropped."), **_ERRORS},
)
async def pointcloud(
    request: Request,
    options: Options,
    focal_px: Annotated[float, Query(ge=MIN_FOCAL_PX, le=MAX_FOCAL_PX, allow_inf_nan=False,
                                     description="Focal length in pixels.")],
    baseline_m: Annotated[float, Query(ge=MIN_BASELINE_M, le=MAX_BASELINE_M, allow_inf_nan=False,
                                       description="Stereo baseline in metres.")],
    cx: Annotated[float | None, Query(ge=-MAX_PRINCIPAL_PX, le=MAX_PRINCIPAL_PX, allow_inf_nan=False,
                                      description="Principal point x in pixels (default: centre).")] = None,
    cy: Annotated[float | None, Query(ge=-MAX_PRINCIPAL_PX, le=MAX_PRINCIPAL_PX, allow_inf_nan=False,
                                      description="Principal point y in pixels (default: centre).")] = None,
) -> Response:
    service = _service(request)
    match = await service.match(request, options)

    def encode() -> Encoded:
        disparity = match.result.disparity
        depth = geometry.depth_from_disparity(disparity, focal_px=focal_px, baseline_m=baseline_m)
        body, count = geometry.point_cloud_ply(depth, match.left, focal_px=focal_px, cx=cx, cy=cy)
        return body, "application/x-ply", {"X-Point-Count": str(count)}

    return await _respond(service, match, encode)


async def _respond(service: InferenceService, match: StereoMatch, encode: Callable[[], Encoded]) -> Response:
    """Encode off the event loop, then attach the stage timings (also recorded as metrics)."""
    started = time.perf_counter()
    body, media, headers = await run_in_threadpool(encode)
    finished = time.perf_counter()
    timings = {**match.timings, "encode": finished - started, "total": finished - match.started}
    service.metrics.observe_stages(timings)
    return Response(body, media_type=media, headers={**headers, "Server-Timing": server_timing(timings)})
