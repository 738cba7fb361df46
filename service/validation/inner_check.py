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
def _check_rows(left, right, min_disparity, disparities, validity):  # type: ignore[no-untyped-def]
    height, width = left.shape
    for y in prange(height):
        for x in range(width):
            left_disparity = left[y, x]
            # floor(d + 0.5) (round half up) also for negative disparities.
            matched = x - int(np.floor(left_disparity + np.float32(0.5)))
            if 0 <= matched < width and abs(left_disparity - right[y, matched]) <= 1.0:
                validity[y, x] = VALID
                continue
            cause = OCCLUDED
            match = x - min_disparity
            for k in range(max(0, match - width + 1), min(disparities, match + 1)):
                if abs(min_disparity + k - right[y, match - k]) <= 1:
                    cause = MISMATCH
                    break
            validity[y, x] = cause


def inner_check(left: np.ndarray, right: np.ndarray, max_disparity: int, *, min_disparity: int = 0
                ) -> np.ndarray:
    """Validity map (uint8 :class:`Validity` codes VALID / OCCLUDED / MISMATCH) of a left disparity map.

    ``left``: float32 HxW left disparities (integer or sub-pixel, within the searched range); ``right``:
    int32 HxW disparities of the right view's winners from the same volume; the volume searched
    ``min_disparity .. min_disparity + max_disparity - 1``.
    """
    if left.ndim != 2 or left.shape != right.shape:
        raise ValueError(f"left/right disparities must be HxW of one shape, got {left.shape}, {right.shape}")
    if max_disparity < 1:
        raise ValueError(f"max_disparity must be >= 1, got {max_disparity}")
    validity = np.empty(left.shape, np.uint8)
    _check_rows(
        np.ascontiguousarray(left, dtype=np.float32),
        np.ascontiguousarray(right, dtype=np.int32),
        int(min_disparity),
        int(max_disparity),
        validity,
    )
    return validity
