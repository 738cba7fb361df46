"""POST /disparity, /depth and /pointcloud: a rectified pair in (or a raw one and its calibration), a map or
a point cloud out."""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from typing import Annotated, Any, Literal

import numpy as np
from fastapi import APIRouter, Depends, Query, Request
from fastapi.responses import Response
from starlette.concurrency import run_in_threadpool

from service.api.camera import CALIBRATION_FIELD, calibration_header
from service.api.errors import error_responses
from service.api.inference import InferenceService, StereoMatch
from service.api.pair_warnings import WARNING_HEADER
from service.api.routes import geometry
from service.api.routes.camera_query import (
    MAX_PRINCIPAL_PX,
    Files,
    Metric,
    MetricOptions,
    camera_request,
)
from service.api.routes.encoding import (
    FILE_EXTENSIONS,
    multipart_mixed,
    negotiate_format,
    server_timing,
    validity_png,
)
from service.api.routes.stereo_query import Options, color_range, reject_unknown_query
from service.io import encode_disparity, media_type
from service.io.confidence import MEDIA_TYPES as CONFIDENCE_MEDIA_TYPES
from service.io.confidence import encode_confidence

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
                        CALIBRATION_FIELD: {
                            "type": "string", "format": "binary",
                            "description": "optional calibration file: Middlebury calib.txt, KITTI "
                            "calib_cam_to_cam.txt or OpenCV .yml/.yaml/.xml/.json (format told by the file "
                            "name, then the content). Instead of focal_px/baseline_m/cx/cy/doffs; a raw rig "
                            "(K D R T, or K D R1 R2 P1 P2) is rectified before matching.",
                        },
                    },
                }
            }
        },
    }
}
_ERRORS = error_responses(400, 408, 413, 415, 503)

Encoded = tuple[bytes, str, dict[str, str]]  # body, media type, extra headers

# Answer headers every stereo route may send (declared in the schema).
_ANSWER_HEADERS: dict[str, Any] = {
    WARNING_HEADER: {
        "description": "One per warning about the pair, '<kind>: <sentence>' with kind swapped, unrectified "
        "or few-valid (the answer is still computed; diagnostics=false skips the look).",
        "schema": {"type": "string"},
    },
    "X-ADSM-Calibration": {
        "description": "The camera used, when one was given: focal_px, focal_y_px, baseline_m, cx, cy, "
        "doffs, rectified (the pair was rectified first) and source (the calibration file) as "
        "'key=value; ...'.",
        "schema": {"type": "string"},
    },
}


def _service(request: Request) -> InferenceService:
    return request.app.state.inference


def _binary(media: str, description: str) -> dict[str, Any]:
    schema = {"type": "string", "format": "binary"}
    return {"content": {media: {"schema": schema}}, "description": description}


def _ok(description: str, content: dict[str, Any]) -> dict[int | str, dict[str, Any]]:
    return {200: {"description": description, "content": content, "headers": _ANSWER_HEADERS}, **_ERRORS}


@router.post(
    "/disparity",
    summary="Disparity map of a rectified pair",
    openapi_extra=_PAIR_BODY,
    response_class=Response,
    responses=_ok(
        "png16 (uint16 = d x 256, 0 invalid), npy (float32, NaN invalid), pfm (inf invalid) or color (RGB "
        "PNG). With validity=true and/or confidence=true: multipart/mixed with the parts 'disparity', "
        "'validity' (8-bit PNG of validity codes) and 'confidence' (npy float32 in [0, 1] for npy and pfm; "
        "8-bit PNG = confidence x 255 for png16 and color).",
        {"image/png": {}, "application/x-npy": {}, "image/x-portable-floatmap": {}, "multipart/mixed": {}},
    ),
)
async def disparity(
    request: Request,
    options: Options,
    files: Files,
    format: Annotated[
        Literal["png16", "npy", "pfm", "color"] | None,
        Query(description="Output format; default from the Accept header, else png16."),
    ] = None,
    validity: Annotated[bool, Query(description="Also return the validity map (multipart/mixed).")] = False,
    confidence: Annotated[bool, Query(description="Also return the per-pixel confidence in [0, 1] "
                                      "(multipart/mixed; one more pass over the cost volume).")] = False,
    colormap_range: Annotated[str | None, Query(
        max_length=64, pattern=r"^[-+]?(\d+\.?\d*|\.\d+),[-+]?(\d+\.?\d*|\.\d+)$",
        description="format=color only: 'low,high' disparities at the two ends of the colour map (default: "
        "each map's own minimum and maximum), so that maps compare.")] = None,
) -> Response:
    service = _service(request)
    chosen = negotiate_format(format, request.headers.get("accept"), offered=("png16", "npy", "pfm", "color"))
    ends = color_range(colormap_range, chosen)
    options = dataclasses.replace(options, confidence=confidence)
    match = await service.match(request, options, camera=camera_request(files), diagnostics=files.diagnostics)

    def encode() -> Encoded:
        body = encode_disparity(match.result.disparity, chosen, color_range=ends)
        headers = {"X-Disparity-Format": chosen}
        if not (validity or confidence):
            return body, media_type(chosen), headers
        parts = [("disparity", f"disparity.{FILE_EXTENSIONS[chosen]}", media_type(chosen), body)]
        if validity:
            parts.append(("validity", "validity.png", "image/png", validity_png(match.result.validity)))
        if confidence:
            assert match.result.confidence is not None  # asked for in the options
            kind = "npy" if chosen in ("npy", "pfm") else "png"  # float formats keep floats
            parts.append(("confidence", f"confidence.{kind}", CONFIDENCE_MEDIA_TYPES[kind],
                          encode_confidence(match.result.confidence, kind)))
        return *multipart_mixed(parts), headers

    return await _respond(service, match, encode)


@router.post(
    "/depth",
    summary="Depth map (z = baseline x focal / (disparity + doffs))",
    openapi_extra=_PAIR_BODY,
    response_class=Response,
    responses=_ok(
        "npy: float32 metres, NaN invalid; png16 (image/png): uint16 millimetres, 0 invalid or beyond "
        "65.535 m; pfm: float32 metres, inf invalid.",
        {"application/x-npy": {}, "image/png": {}, "image/x-portable-floatmap": {}},
    ),
)
async def depth(
    request: Request,
    options: Options,
    files: Files,
    metric: Metric,
    format: Annotated[
        Literal["npy", "png16", "pfm"] | None,
        Query(description="Output format; default from Accept, else npy."),
    ] = None,
) -> Response:
    service = _service(request)
    chosen = negotiate_format(format, request.headers.get("accept"), offered=("npy", "png16", "pfm"))
    camera = camera_request(files, metric)
    match = await service.match(request, options, camera=camera, diagnostics=files.diagnostics)

    def encode() -> Encoded:
        depth = _depth(match, metric)
        return geometry.encode_depth(depth, chosen), media_type(chosen), {"X-Depth-Format": chosen}

    return await _respond(service, match, encode)


@router.post(
    "/pointcloud",
    summary="Coloured point cloud (binary little-endian PLY, metres, left camera frame)",
    openapi_extra=_PAIR_BODY,
    response_class=Response,
    responses=_ok("PLY; pixels without depth (and beyond max_depth, or filled with drop_filled) are dropped.",
                  {"application/x-ply": {"schema": {"type": "string", "format": "binary"}}}),
)
async def pointcloud(
    request: Request,
    options: Options,
    files: Files,
    metric: Metric,
    cx: Annotated[float | None, Query(ge=-MAX_PRINCIPAL_PX, le=MAX_PRINCIPAL_PX, allow_inf_nan=False,
                                      description="Principal point x in pixels (default: centre).")] = None,
    cy: Annotated[float | None, Query(ge=-MAX_PRINCIPAL_PX, le=MAX_PRINCIPAL_PX, allow_inf_nan=False,
                                      description="Principal point y in pixels (default: centre).")] = None,
) -> Response:
    service = _service(request)
    camera = camera_request(files, metric, cx=cx, cy=cy)
    match = await service.match(request, options, camera=camera, diagnostics=files.diagnostics)

    def encode() -> Encoded:
        calibration = match.calibration
        assert calibration is not None  # the route requires a camera
        body, count = geometry.point_cloud_ply(
            _depth(match, metric), match.left, focal_px=calibration.focal_px, cx=calibration.cx,
            cy=calibration.cy, focal_y_px=calibration.focal_y_px,
        )
        return body, "application/x-ply", {"X-Point-Count": str(count)}

    return await _respond(service, match, encode)


def _depth(match: StereoMatch, metric: MetricOptions) -> np.ndarray:
    """The depth map of a metric route: the camera's z = f B / (d + doffs), max_depth and drop_filled."""
    calibration = match.calibration
    assert calibration is not None  # the metric routes require a camera
    keep = geometry.measured(match.result.validity) if metric.drop_filled else None
    return geometry.depth_from_disparity(
        match.result.disparity, focal_px=calibration.focal_px, baseline_m=calibration.baseline_m,
        doffs=calibration.doffs, max_depth=metric.max_depth, keep=keep,
    )


async def _respond(service: InferenceService, match: StereoMatch, encode: Callable[[], Encoded]) -> Response:
    """Encode off the event loop, then attach the stage timings (also recorded as metrics), the camera
    used and the pair's warnings."""
    started = time.perf_counter()
    body, media, headers = await run_in_threadpool(encode)
    finished = time.perf_counter()
    timings = {**match.timings, "encode": finished - started, "total": finished - match.started}
    service.metrics.observe_stages(timings)
    if match.calibration is not None:
        headers["X-ADSM-Calibration"] = calibration_header(match.calibration, rectified=match.rectified)
    response = Response(body, media_type=media, headers={**headers, "Server-Timing": server_timing(timings)})
    for warning in match.warnings:  # one header each: a sentence may hold commas
        response.headers.append(WARNING_HEADER, warning.encode("ascii", "replace").decode("ascii"))
    return response
