"""The per-pixel stages on the GPU: winner-takes-all, the right view's winners, the sub-pixel fit, the
inner left-right check, ray filling and the peak-ratio confidence; one thread per pixel.

Each kernel is its CPU twin's loop body (service/disparity/wta.py, service/refinement/subpixel.py,
service/validation/inner_check.py, service/filling/rays.py, service/validation/confidence.py) with the
pixel taken from the thread index, so the rules (ties to the smaller disparity, the 0.5-px clamp, MC-CNN's
cause of a rejection, the background run and the mismatch fraction) are the same lines of arithmetic and
the equality tests compare the maps exactly (the sub-pixel offsets to float32 rounding).
"""

from __future__ import annotations

import math

from numba import cuda, float32, int32

from service.validation.codes import FILLED, MISMATCH, NO_DATA, OCCLUDED, VALID

THREADS = 128
_UNSEEN = int32(2**30)
_NO_RIVAL = int32(2**30)
_RAYS = 16


def blocks(pixels: int) -> int:
    """Blocks of ``THREADS`` that cover ``pixels`` threads."""
    return max(1, math.ceil(pixels / THREADS))


@cuda.jit
def winners(volume, left):  # type: ignore[no-untyped-def]
    """``left[y, x]``: the cell of least cost (the smallest on ties)."""
    height, width, disparities = volume.shape
    pixel = cuda.grid(1)
    if pixel >= height * width:
        return
    y, x = pixel // width, pixel % width
    best, best_cost = 0, volume[y, x, 0]
    for d in range(1, disparities):
        if volume[y, x, d] < best_cost:
            best_cost = volume[y, x, d]
            best = d
    left[y, x] = best


@cuda.jit
def right_winners(volume, min_disparity, right):  # type: ignore[no-untyped-def]
    """``right[y, x]``: argmin_k ``volume[y, x + min_disparity + k, k]`` over the cells in the image (the
    smallest k on ties), 0 where none is."""
    height, width, disparities = volume.shape
    pixel = cuda.grid(1)
    if pixel >= height * width:
        return
    y, x = pixel // width, pixel % width
    best, best_cost = 0, _UNSEEN
    for k in range(disparities):
        match = x + min_disparity + k
        if 0 <= match < width and volume[y, match, k] < best_cost:
            best_cost = int32(volume[y, match, k])
            best = k
    right[y, x] = best


@cuda.jit
def refine(volume, winners, refined):  # type: ignore[no-untyped-def]
    """Parabola vertex through the winner's neighbours, clamped to +-0.5 (refinement.refine_subpixel)."""
    height, width, disparities = volume.shape
    pixel = cuda.grid(1)
    if pixel >= height * width:
        return
    y, x = pixel // width, pixel % width
    d = winners[y, x]
    refined[y, x] = d
    if 0 < d < disparities - 1:
        before = float32(volume[y, x, d - 1])
        after = float32(volume[y, x, d + 1])
        curvature = before - float32(2.0) * float32(volume[y, x, d]) + after
        if curvature > 0.0:
            offset = (before - after) / (float32(2.0) * curvature)
            refined[y, x] = d + min(float32(0.5), max(float32(-0.5), offset))


@cuda.jit
def check(left, right, min_disparity, disparities, threshold, validity):  # type: ignore[no-untyped-def]
    """VALID / OCCLUDED / MISMATCH of each left pixel (validation.inner_check)."""
    height, width = left.shape
    pixel = cuda.grid(1)
    if pixel >= height * width:
        return
    y, x = pixel // width, pixel % width
    left_disparity = left[y, x]
    matched = x - int32(math.floor(left_disparity + float32(0.5)))
    if 0 <= matched < width and abs(left_disparity - right[y, matched]) <= threshold:
        validity[y, x] = VALID
        return
    cause = OCCLUDED
    match = x - min_disparity
    for k in range(max(0, match - width + 1), min(disparities, match + 1)):
        if abs(min_disparity + k - right[y, match - k]) <= 1:
            cause = MISMATCH
            break
    validity[y, x] = cause


@cuda.jit
def fill(disparity, validity, directions, background_run, numerator, denominator,  # type: ignore[no-untyped-def]
         filled, filled_validity):
    """Ray filling of the OCCLUDED and MISMATCH pixels (filling.fill_invalid); others are copied."""
    height, width = disparity.shape
    pixel = cuda.grid(1)
    if pixel >= height * width:
        return
    y, x = pixel // width, pixel % width
    cause = validity[y, x]
    filled[y, x] = disparity[y, x]
    filled_validity[y, x] = cause
    if cause == OCCLUDED:
        seen = 0
        value = float32(0.0)
        xx = x - 1
        while xx >= 0 and seen < background_run:
            if validity[y, xx] == VALID:
                if seen == 0 or disparity[y, xx] < value:
                    value = disparity[y, xx]
                seen += 1
            xx -= 1
        found = seen > 0
        xx = x + 1
        while not found and xx < width:
            if validity[y, xx] == VALID:
                found = True
                value = disparity[y, xx]
            xx += 1
        if found:
            filled[y, x] = value
            filled_validity[y, x] = cause | FILLED
        else:
            filled[y, x] = math.nan
            filled_validity[y, x] = NO_DATA
        return
    if cause != MISMATCH:
        return
    found_values = cuda.local.array(_RAYS, float32)
    count = 0
    for ray in range(directions.shape[0]):
        dx = directions[ray, 0]
        dy = directions[ray, 1]
        step = 1
        while True:
            xx = x + int32(math.floor(step * dx + float32(0.5)))
            yy = y + int32(math.floor(step * dy + float32(0.5)))
            if xx < 0 or xx >= width or yy < 0 or yy >= height:
                break
            if validity[yy, xx] == VALID:
                value = disparity[yy, xx]
                slot = count
                while slot > 0 and found_values[slot - 1] > value:
                    found_values[slot] = found_values[slot - 1]
                    slot -= 1
                found_values[slot] = value
                count += 1
                break
            step += 1
    if count == 0:
        filled[y, x] = math.nan
        filled_validity[y, x] = NO_DATA
        return
    filled[y, x] = found_values[min(count * numerator // denominator, count - 1)]
    filled_validity[y, x] = cause | FILLED


@cuda.jit
def confidence(volume, winners, lowest, out):  # type: ignore[no-untyped-def]
    """Peak ratio ``(C2 - C1) / (C2 - lowest)`` with the non-adjacent runner-up (validation.confidence)."""
    height, width, disparities = volume.shape
    pixel = cuda.grid(1)
    if pixel >= height * width:
        return
    y, x = pixel // width, pixel % width
    winner = winners[y, x]
    best = int32(volume[y, x, winner])
    rival = _NO_RIVAL
    for d in range(0, max(winner - 1, 0)):
        rival = min(rival, int32(volume[y, x, d]))
    for d in range(winner + 2, disparities):
        rival = min(rival, int32(volume[y, x, d]))
    if rival == _NO_RIVAL:
        out[y, x] = 1.0
        return
    spread = max(rival - lowest, 1)
    out[y, x] = min(max(float32(rival - best) / float32(spread), float32(0.0)), float32(1.0))


@cuda.jit
def add_offset(disparity, right, offset):  # type: ignore[no-untyped-def]
    """Cell indices -> disparities: ``offset`` (min_disparity) added to both views' maps."""
    height, width = disparity.shape
    pixel = cuda.grid(1)
    if pixel >= height * width:
        return
    y, x = pixel // width, pixel % width
    disparity[y, x] += offset
    right[y, x] += offset
