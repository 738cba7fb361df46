"""Ray filling of invalid pixels (MC-CNN's post-processing, used by ADSM).

From every invalid pixel, 16 rays go out at multiples of 22.5 degrees; each ray steps one pixel along its
major axis (directions as in MC-CNN: components in {0, +-0.5, +-1}) until it meets a pixel that passed the
left-right check. Only checked-valid pixels are read, never freshly filled ones, so the result does not
depend on the order of the pixels.

- Occlusion: the smallest disparity (the farthest surface) among the first ``BACKGROUND_RUN`` valid pixels
  on the horizontal ray to the left. A pixel hidden in the right view lies just right of the background it
  belongs to, so the left ray reaches the background; but the matcher fattens the occluding foreground
  over the first background pixels, and MC-CNN's rule (the first valid pixel, ``background_run=1``) then
  copies the foreground into the hole (a third of the filled occlusions were bad-2 by being too large).
  Longer runs help the synthetic split more and more while Cones' filled occlusions get worse beyond 2:
  2 is the longest run that Cones does not contradict (docs/training.md, "What the check rejects"; swept
  again with the 0.5 px check, "A stricter left-right check": the same reading).
  Where the left ray leaves the image (the band x < d along the left border, which the right camera
  never sees) the first valid pixel on the ray to the right is used instead.
  Measured on Cones with the NCC baseline (P1=30, P2=160, bad-2 over all ground-truth pixels): 13.19 %
  for the first pixel to the left against 16.18 % for the smallest value among the 16 rays, which trusts
  the single lowest, often wrong, neighbour in every direction.
- Mismatch: the value at ``MISMATCH_FRACTION`` of the sorted first valid pixels of the rays (MC-CNN's
  median, the upper one for an even count, is ``mismatch_fraction=(1, 2)``). Mismatches sit at depth
  edges too, where the foreground is fattened, so the lower tercile leans the same way as the occlusion
  rule. Measured on adsm-fast-int8 with the background run 2 and the 1 px check then (`python -m bench
  background_fill`):
  synthetic:20 bad-2 18.42 / 18.29 / 18.30 / 18.33 % at the fractions 1/2, 1/3, 1/4, 1/5 (the rule's
  choice, 1/3), Cones 8.32 / 8.03 / 7.96 / 7.91 % (it confirms).
- No ray finds a valid pixel: NaN and ``Validity.NO_DATA``.
"""

from __future__ import annotations

import numpy as np
from numba import prange

from service.jit import njit
from service.validation.codes import FILLED, MISMATCH, NO_DATA, OCCLUDED, VALID

BACKGROUND_RUN = 2  # valid pixels to the left of an occlusion whose farthest disparity fills it (above)
MISMATCH_FRACTION = (1, 3)  # a mismatch takes the sorted rays' value at count * 1 // 3 (above)
MC_CNN_RUN, MC_CNN_FRACTION = 1, (1, 2)  # MC-CNN's rules: the first valid pixel, the (upper) median

_DIRECTIONS = np.array(
    [
        [1.0, 0.0], [1.0, 0.5], [1.0, 1.0], [0.5, 1.0],
        [0.0, 1.0], [-0.5, 1.0], [-1.0, 1.0], [-1.0, 0.5],
        [-1.0, 0.0], [-1.0, -0.5], [-1.0, -1.0], [-0.5, -1.0],
        [0.0, -1.0], [0.5, -1.0], [1.0, -1.0], [1.0, -0.5],
    ],
    np.float32,
)  # (dx, dy)


@njit(inline="always")
def _horizontal_ray(disparity, validity, y, x, step):  # type: ignore[no-untyped-def]
    """(found, disparity) of the first VALID pixel from (y, x) along the row in direction ``step``.

    A flag, not a NaN or negative sentinel: the kernels are compiled with fastmath, under which isnan is
    folded away, and a search range with a negative minimum has negative disparities.
    """
    xx = x + step
    while 0 <= xx < disparity.shape[1]:
        if validity[y, xx] == VALID:
            return True, disparity[y, xx]
        xx += step
    return False, np.float32(0.0)


@njit(inline="always")
def _background_to_the_left(disparity, validity, y, x, run):  # type: ignore[no-untyped-def]
    """(found, smallest disparity) among the first ``run`` VALID pixels left of (y, x) in its row."""
    seen = 0
    value = np.float32(0.0)
    xx = x - 1
    while xx >= 0 and seen < run:
        if validity[y, xx] == VALID:
            if seen == 0 or disparity[y, xx] < value:
                value = disparity[y, xx]
            seen += 1
        xx -= 1
    return seen > 0, value


@njit(parallel=True)
def _fill_rows(disparity, validity, directions, background_run,  # type: ignore[no-untyped-def]
               fraction_numerator, fraction_denominator, filled, filled_validity):
    height, width = disparity.shape
    rays = directions.shape[0]
    for y in prange(height):
        found = np.empty(rays, np.float32)
        for x in range(width):
            cause = validity[y, x]
            if cause == OCCLUDED:
                found_left, value = _background_to_the_left(disparity, validity, y, x, background_run)
                found_right = False
                if not found_left:
                    found_right, value = _horizontal_ray(disparity, validity, y, x, 1)
                if not (found_left or found_right):
                    filled[y, x] = np.nan
                    filled_validity[y, x] = NO_DATA
                else:
                    filled[y, x] = value
                    filled_validity[y, x] = cause | FILLED
                continue
            if cause != MISMATCH:
                continue
            count = 0
            for ray in range(rays):
                dx = directions[ray, 0]
                dy = directions[ray, 1]
                step = 1
                while True:
                    # floor(t + 0.5): round half up, so half-slope rays advance on every other step.
                    xx = x + int(np.floor(step * dx + 0.5))
                    yy = y + int(np.floor(step * dy + 0.5))
                    if xx < 0 or xx >= width or yy < 0 or yy >= height:
                        break
                    if validity[yy, xx] == VALID:
                        # Insertion into the sorted prefix: at most 16 values, and no np.sort allocation per
                        # pixel (that allocation was most of this kernel's time on mismatch-heavy maps).
                        value = disparity[yy, xx]
                        slot = count
                        while slot > 0 and found[slot - 1] > value:
                            found[slot] = found[slot - 1]
                            slot -= 1
                        found[slot] = value
                        count += 1
                        break
                    step += 1
            if count == 0:
                filled[y, x] = np.nan
                filled_validity[y, x] = NO_DATA
                continue
            filled[y, x] = found[min(count * fraction_numerator // fraction_denominator, count - 1)]
            filled_validity[y, x] = cause | FILLED


def fill_invalid(disparity: np.ndarray, validity: np.ndarray, *, background_run: int = BACKGROUND_RUN,
                 mismatch_fraction: tuple[int, int] = MISMATCH_FRACTION) -> tuple[np.ndarray, np.ndarray]:
    """Fill the OCCLUDED and MISMATCH pixels of a float32 HxW disparity; returns new (disparity, validity).

    Filled pixels get ``FILLED_OCCLUSION`` / ``FILLED_MISMATCH``, unfillable ones NaN and ``NO_DATA``;
    every other pixel is copied unchanged. An occlusion takes the smallest disparity among the first
    ``background_run`` valid pixels to its left, a mismatch the value at ``mismatch_fraction`` (n, d) of
    its rays' sorted values (index count * n // d); ``MC_CNN_RUN`` and ``MC_CNN_FRACTION`` give MC-CNN's
    rules.
    """
    if disparity.ndim != 2 or disparity.shape != validity.shape:
        raise ValueError(f"disparity {disparity.shape} and validity {validity.shape} must be HxW, same shape")
    if background_run < 1:
        raise ValueError(f"background_run must be >= 1, got {background_run}")
    numerator, denominator = mismatch_fraction
    if not 0 <= numerator < denominator:
        raise ValueError(f"mismatch_fraction must be (n, d) with 0 <= n < d, got {mismatch_fraction}")
    disparity = np.ascontiguousarray(disparity, dtype=np.float32)
    validity = np.ascontiguousarray(validity, dtype=np.uint8)
    filled = disparity.copy()
    filled_validity = validity.copy()
    if np.any(validity == VALID):
        _fill_rows(disparity, validity, _DIRECTIONS, background_run, numerator, denominator, filled,
                   filled_validity)
    else:  # nothing to fill from: skip 16 rays to the border from every pixel
        invalid = (validity == OCCLUDED) | (validity == MISMATCH)
        filled[invalid] = np.nan
        filled_validity[invalid] = NO_DATA
    return filled, filled_validity
