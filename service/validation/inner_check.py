"""Inner left-right check (MC-CNN, ADSM section 3): the right view's disparities come from the left volume.

The right volume is never computed: ``CR[y, x, d] = CL[y, x + d, d]``, and its winners ``DR`` are found
in the same pass as the left ones (:func:`service.disparity.left_right_winners`). A left pixel is valid
when ``|DL(x) - DR(x - round(DL(x)))| <= 1``.

An invalid pixel is classed by MC-CNN's rule: a *mismatch* when some disparity ``d`` would have been
consistent (``|d - DR(x - d)| <= 1``), so the match was simply wrong; an *occlusion* otherwise, since no
right pixel claims it (it is hidden in the right view). The two causes are filled differently.
"""

from __future__ import annotations

import numpy as np
from numba import prange

from service.jit import njit
from service.validation.codes import MISMATCH, OCCLUDED, VALID


@njit(parallel=True)
def _check_rows(left, right, disparities, validity):
    height, width = left.shape
    for y in prange(height):
        for x in range(width):
            left_disparity = left[y, x]
            matched = x - int(left_disparity + 0.5)
            if 0 <= matched < width and abs(left_disparity - right[y, matched]) <= 1.0:
                validity[y, x] = VALID
                continue
            cause = OCCLUDED
            for d in range(min(disparities, x + 1)):
                if abs(d - right[y, x - d]) <= 1:
                    cause = MISMATCH
                    break
            validity[y, x] = cause


def inner_check(left: np.ndarray, right: np.ndarray, max_disparity: int) -> np.ndarray:
    """Validity map (uint8 :class:`Validity` codes VALID / OCCLUDED / MISMATCH) of a left disparity map.

    ``left``: float32 HxW left disparities (integer or sub-pixel, all >= 0); ``right``: int32 HxW
    winners of the right view from the same volume; ``max_disparity``: D of that volume.
    """
    if left.ndim != 2 or left.shape != right.shape:
        raise ValueError(f"left/right disparities must be HxW of one shape, got {left.shape}, {right.shape}")
    if max_disparity < 1:
        raise ValueError(f"max_disparity must be >= 1, got {max_disparity}")
    validity = np.empty(left.shape, np.uint8)
    _check_rows(
        np.ascontiguousarray(left, dtype=np.float32),
        np.ascontiguousarray(right, dtype=np.int32),
        int(max_disparity),
        validity,
    )
    return validity
