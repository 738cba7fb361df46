"""The stereo routes' query: the options of a match (:func:`stereo_options` -> MatchOptions), the colour
map's range, and the refusal of unknown or repeated parameters (every stereo route depends on it)."""

from __future__ import annotations

import math
from collections import Counter
from typing import Annotated

from fastapi import Depends, HTTPException, Query, Request
from fastapi.dependencies.models import Dependant

from service.api.routes.camera_query import MAX_OFFSET_PX
from service.features.scale import MAX_TOWER_SCALE
from service.filling import BACKGROUND_RUN, SURFACE_RUN
from service.match_options import MatchOptions
from service.optimization import MAX_PENALTY
from service.validation import LR_CHECK_THRESHOLD


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
    # Counted in one pass: a query of thousands of repeats (names.count per name) cost seconds of CPU.
    counts = Counter(name for name, _ in request.query_params.multi_items())
    if repeated := sorted(name for name, count in counts.items() if count > 1):
        raise HTTPException(400, f"query parameter '{repeated[0]}' is given more than once; give it once")


# p1, p2: finite and at most SGM's own bound (service.optimization.MAX_PENALTY, 4096 cost units: 32 times
# the shipped cost scale), so that no sum of int16 costs overflows.
def stereo_options(
    max_disparity: Annotated[
        int | None, Query(ge=1, description="Size of the search range: disparities min_disparity .. "
                          "min_disparity + max_disparity - 1 (default: the model's, clipped to the width).")
    ] = None,
    min_disparity: Annotated[
        int, Query(ge=-int(MAX_OFFSET_PX), le=int(MAX_OFFSET_PX),
                   description="Start of the search range (as OpenCV's minDisparity; negative allowed). "
                   "|min_disparity| < width and min_disparity + max_disparity <= width.")
    ] = 0,
    lr_check: Annotated[bool, Query(description="Inner left-right check (occlusion/mismatch).")] = True,
    lr_check_threshold: Annotated[float, Query(
        ge=0, le=MAX_OFFSET_PX, allow_inf_nan=False,
        description="Largest |DL - DR| in pixels of a pixel the left-right check keeps (the default, "
        f"{LR_CHECK_THRESHOLD:g}, keeps a pixel when the right view's winner is its own rounded disparity "
        "or, near the half-way point, the step beside it; MC-CNN's 1 keeps more pixels at depth "
        "edges).")] = LR_CHECK_THRESHOLD,
    fill: Annotated[bool | None, Query(description="Fill invalid pixels along rays (needs lr_check; "
                                       "default: lr_check).")] = None,
    background_fill: Annotated[bool, Query(description="Fill rejected pixels leaning to the background: an "
                                           f"occlusion from the farthest of the first {BACKGROUND_RUN} valid "
                                           "pixels to its left, a mismatch from the lower tercile of its 16 "
                                           "rays (false: MC-CNN's first pixel and median).")] = True,
    subpixel: Annotated[bool, Query(description="Quadratic sub-pixel refinement.")] = True,
    shiftable_windows: Annotated[bool | None, Query(description="Before SGM, each cost the lowest of its "
                                                    "row neighbours' (x +- 1) at the same disparity: windows "
                                                    "that can shift off a depth edge (default: the model's "
                                                    "sgm.shiftable_windows).")] = None,
    tower_scale: Annotated[int, Query(ge=1, le=MAX_TOWER_SCALE, description="Run the feature towers on the "
                                      "pair upsampled by this factor: sharper depth edges on clean, densely "
                                      "textured images, worse on noisy or compressed ones; about "
                                      "tower_scale^2 times the towers' time.")] = 1,
    adaptive_p2: Annotated[bool, Query(description="Lower SGM's jump penalty across image edges, so depth "
                                       "edges follow image edges.")] = True,
    right_sgm: Annotated[bool, Query(description="The left-right check's right-view disparities from the "
                                     "right view's own SGM pass (false: read off the left view's aggregated "
                                     "costs, one SGM pass fewer; needs lr_check).")] = True,
    border: Annotated[bool | None, Query(description="Give the left border band (pixels whose match lies "
                                         "left of the right image) the disparity of the surface they "
                                         "continue (default: the model's filling.border_band).")] = None,
    border_surface_run: Annotated[int, Query(
        ge=0, le=int(MAX_OFFSET_PX),
        description="The border band ends at a run of this many accepted pixels at one disparity that "
        "match inside the right image (a farther surface the right camera saw); 0 carries every band to "
        "the border.")] = SURFACE_RUN,
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
            max_disparity=max_disparity, min_disparity=min_disparity, lr_check=lr_check,
            fill=lr_check if fill is None else fill, background_fill=background_fill,
            subpixel=subpixel, shiftable_windows=shiftable_windows, tower_scale=tower_scale, border=border,
            weighted_median=weighted_median, adaptive_p2=adaptive_p2, right_sgm=right_sgm,
            lr_check_threshold=lr_check_threshold, border_surface_run=border_surface_run, p1=p1, p2=p2,
        )
    except ValueError as error:  # raised in a dependency it would otherwise end as a 500
        raise HTTPException(400, str(error)) from None


Options = Annotated[MatchOptions, Depends(stereo_options)]


def color_range(text: str | None, format: str) -> tuple[float, float] | None:
    """``colormap_range=low,high`` as two floats; HTTPException 400 unless it fits format=color."""
    if text is None:
        return None
    if format != "color":
        raise HTTPException(400, f"colormap_range applies to format=color only, not {format}")
    low, high = (float(value) for value in text.split(","))  # the schema's pattern made them numbers
    if not (math.isfinite(low) and math.isfinite(high) and max(abs(low), abs(high)) <= MAX_OFFSET_PX):
        raise HTTPException(400, f"colormap_range {text}: both ends must be finite and within "
                            f"+-{MAX_OFFSET_PX:g} pixels")
    if not low < high:
        raise HTTPException(400, f"colormap_range {text}: the low end must be below the high end")
    return low, high
