"""The query parameters that describe the camera and the ``calib`` file, shared by the stereo routes.

``/depth`` and ``/pointcloud`` take :func:`metric_options` (the camera by hand, which depths to keep) and
every stereo route :func:`file_options` (how to read a ``calib`` file; the pair diagnostics);
:func:`camera_request` turns them into the :class:`~service.api.camera.CameraRequest` the service resolves
once the body is read.
"""

from __future__ import annotations

import dataclasses
from typing import Annotated, Literal

from fastapi import Depends, Query

from service.api.camera import CameraRequest
from service.api.pair_warnings import WARNING_HEADER

# Bounds of the float parameters: finite, and far beyond any real camera, so that no value overflows
# float32 on its way through depth (B f / d) or the point cloud.
MAX_FOCAL_PX = 1e6
MAX_BASELINE_M = 1e4
# Lower bounds: f x B of 1e-60 underflows float32 and made every depth 0 m (a point cloud at the origin).
# No camera has a focal length under a thousandth of a pixel or a baseline under a micrometre.
MIN_FOCAL_PX = 1e-3
MIN_BASELINE_M = 1e-6
MAX_PRINCIPAL_PX = 1e6
# doffs (cx_right - cx_left), a minimum disparity, a colour range: pixel quantities, bounded as cx and cy.
MAX_OFFSET_PX = 1e6
MAX_DEPTH_M = 1e6  # a max_depth beyond this drops nothing a float32 depth can hold meaningfully

@dataclasses.dataclass(frozen=True)
class FileOptions:
    """How to read a ``calib`` file (None: not given), and whether to look at the pair."""

    calib_units: str | None
    calib_rectified: bool | None
    diagnostics: bool


def file_options(
    calib_units: Annotated[Literal["m", "cm", "mm"] | None, Query(
        description="OpenCV calibration files: the unit of T and of P2's baseline term (default m).")] = None,
    calib_rectified: Annotated[bool | None, Query(
        description="The images are rectified already: ignore a calib file's K D R (default false).")] = None,
    diagnostics: Annotated[bool, Query(
        description="Look at the pair for signs of a swap or missing rectification, and a low share of "
        f"pixels passing the check; warnings in {WARNING_HEADER} headers.")] = True,
) -> FileOptions:
    return FileOptions(calib_units, calib_rectified, diagnostics)



@dataclasses.dataclass(frozen=True)
class MetricOptions:
    """The camera by hand (each None when not given) and which depths to keep."""

    focal_px: float | None
    baseline_m: float | None
    doffs: float | None
    max_depth: float | None
    drop_filled: bool


def metric_options(
    focal_px: Annotated[float | None, Query(ge=MIN_FOCAL_PX, le=MAX_FOCAL_PX, allow_inf_nan=False,
                                            description="Focal length in pixels (or a calib file).")] = None,
    baseline_m: Annotated[float | None, Query(
        ge=MIN_BASELINE_M, le=MAX_BASELINE_M, allow_inf_nan=False,
        description="Stereo baseline in metres (or a calib file).")] = None,
    doffs: Annotated[float | None, Query(ge=-MAX_OFFSET_PX, le=MAX_OFFSET_PX, allow_inf_nan=False,
                                         description="cx_right - cx_left in pixels (Middlebury's doffs): "
                                         "z = f B / (d + doffs); default 0.")] = None,
    max_depth: Annotated[float | None, Query(gt=0, le=MAX_DEPTH_M, allow_inf_nan=False,
                                             description="Drop depths beyond this many metres.")] = None,
    drop_filled: Annotated[bool, Query(description="Keep only pixels the left-right check accepted "
                                       "(no ray-filled pixels).")] = False,
) -> MetricOptions:
    return MetricOptions(focal_px, baseline_m, doffs, max_depth, drop_filled)



def camera_request(files: FileOptions, metric: MetricOptions | None = None, *, cx: float | None = None,
            cy: float | None = None) -> CameraRequest:
    """The route's camera request: /disparity (no ``metric``) takes only a file, for rectification."""
    return CameraRequest(
        required=metric is not None, calib_units=files.calib_units, calib_rectified=files.calib_rectified,
        focal_px=None if metric is None else metric.focal_px,
        baseline_m=None if metric is None else metric.baseline_m,
        doffs=None if metric is None else metric.doffs, cx=cx, cy=cy,
    )


Files = Annotated[FileOptions, Depends(file_options)]
Metric = Annotated[MetricOptions, Depends(metric_options)]
