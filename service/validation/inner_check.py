"""Inner left-right check (MC-CNN, ADSM section 3): the right view's disparities come from the left costs.

No tower runs on the right view as reference: its costs are the left ones re-indexed,
``CR[y, x, d] = CL[y, x + d, d]``. By default (``MatchOptions.right_sgm``) they are aggregated by SGM in
the right view's own frame and ``DR`` is their winner-takes-all (service/cost/right_view.py, as MC-CNN's
``D^R``); with ``right_sgm`` off ``DR`` is read off the left view's aggregated volume in the same pass as
the left winners (:func:`service.disparity.left_right_winners`). A left pixel is valid
when ``|DL(x) - DR(x - round(DL(x)))| <= threshold``, :data:`LR_CHECK_THRESHOLD` (0.75 px) by default:
the right view's winner at the match is the left's disparity rounded, or the step beside it where the
sub-pixel disparity lies within 0.25 px of the half-way point. MC-CNN allows 1 px; the stricter check
also rejects the pixels at depth edges whose two views disagree by one step, mostly fattened foreground,
which the background-leaning fill then replaces. With right winners read off the left-aggregated volume
0.5 px was best (0.4-0.6 alike, 0.25 rejects good sub-pixel matches: docs/training.md, "A stricter
left-right check"); with the right view's own SGM pass, whose winners are more often right, 0.75 is
(0.5 / 0.75 / 1 / 1.5 px on the synthetic split: "The right view aggregated in its own frame").

An invalid pixel is classed by MC-CNN's rule: a *mismatch* when some disparity ``d`` would have been
consistent within :data:`CAUSE_TOLERANCE` (``|d - DR(x - d)| <= 1``), so the match was simply wrong; an
*occlusion* otherwise, since no right pixel claims it (it is hidden in the right view). The two causes are
filled differently. The cause keeps MC-CNN's 1 px whatever the threshold: with 0.5 px there the
synthetic split was level and Cones 0.13 point worse.
"""

from __future__ import annotations

import math

import numpy as np
from numba import prange

from service.jit import njit
from service.validation.codes import MISMATCH, OCCLUDED, VALID

LR_CHECK_THRESHOLD = 0.75  # px: largest |DL - DR| of a valid pixel (MatchOptions.lr_check_threshold)
CAUSE_TOLERANCE = 1  # px: a rejected pixel is a mismatch when some d has |d - DR(x - d)| <= this


@njit(parallel=True)
def _check_rows(left, right, min_disparity, disparities, threshold, validity):  # type: ignore[no-untyped-def]
    height, width = left.shape
    for y in prange(height):
        for x in range(width):
            left_disparity = left[y, x]
            # floor(d + 0.5) (round half up) also for negative disparities.
            matched = x - int(np.floor(left_disparity + np.float32(0.5)))
            if 0 <= matched < width and abs(left_disparity - right[y, matched]) <= threshold:
                validity[y, x] = VALID
                continue
            cause = OCCLUDED
            match = x - min_disparity
            for k in range(max(0, match - width + 1), min(disparities, match + 1)):
                if abs(min_disparity + k - right[y, match - k]) <= CAUSE_TOLERANCE:
                    cause = MISMATCH
                    break
            validity[y, x] = cause


def inner_check(left: np.ndarray, right: np.ndarray, max_disparity: int, *, min_disparity: int = 0,
                threshold: float = LR_CHECK_THRESHOLD) -> np.ndarray:
    """Validity map (uint8 :class:`Validity` codes VALID / OCCLUDED / MISMATCH) of a left disparity map.

    ``left``: float32 HxW left disparities (integer or sub-pixel, within the searched range); ``right``:
    int32 HxW disparities of the right view's winners from the same costs; the volume searched
    ``min_disparity .. min_disparity + max_disparity - 1``; ``threshold``: the largest ``|DL - DR|``
    of a valid pixel, in pixels (>= 0).

    >>> left = np.array([[1.0, 1.0, 1.4, 1.8]], np.float32)  # column 0's match lies left of the image
    >>> right = np.ones((1, 4), np.int32)
    >>> inner_check(left, right, 3).tolist()  # 0 VALID, 2 MISMATCH: 1.8 is 0.8 px from DR = 1
    [[2, 0, 0, 2]]
    >>> inner_check(left, right, 3, threshold=1.0).tolist()  # MC-CNN's tolerance
    [[2, 0, 0, 0]]
    """
    if left.ndim != 2 or left.shape != right.shape:
        raise ValueError(f"left/right disparities must be HxW of one shape, got {left.shape}, {right.shape}")
    if max_disparity < 1:
        raise ValueError(f"max_disparity must be >= 1, got {max_disparity}")
    if not (isinstance(threshold, int | float | np.number) and math.isfinite(threshold) and threshold >= 0):
        raise ValueError(f"threshold must be a finite number of pixels >= 0, got {threshold!r}")
    validity = np.empty(left.shape, np.uint8)
    _check_rows(
        np.ascontiguousarray(left, dtype=np.float32),
        np.ascontiguousarray(right, dtype=np.int32),
        int(min_disparity),
        int(max_disparity),
        np.float32(threshold),
        validity,
    )
    return validity
