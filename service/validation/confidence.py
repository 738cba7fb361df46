"""Per-pixel confidence in [0, 1]: how clearly the aggregated costs single out the winner, weighed by the
left-right check.

    peak ratio = (C2 - C1) / (C2 - C_low)
    confidence = peak ratio                  where the left-right check accepted the pixel
               = REJECTED_WEIGHT x peak ratio where it rejected it and filling gave it a value
               = 0                           where the pixel has no disparity (NaN)

``C1`` is the winner's aggregated cost, ``C2`` the lowest cost at least two cells away from it (the
second-best *non-adjacent* minimum: the winner's neighbours belong to the same valley, a sub-pixel
matter), and ``C_low`` the lowest cost the volume can hold (``-PATHS x cost.scale`` after SGM), so the
ratio is the peak-ratio measure (PKRN, Hu & Mordohai 2012) of costs shifted to be positive: 0 when another
disparity is as good, towards 1 when the winner's cost is far below every rival. A pixel with no
non-adjacent rival (D <= 3) has a peak ratio of 1.

The check (left-right distance ``|DL(x) - DR(x - DL(x))| <= 1``) splits the pixels: half of the rejected
ones are bad-2 after filling against 8 % of the accepted ones (synthetic:20), so every rejected pixel
ranks below an accepted one of the same peak ratio, by the factor ``REJECTED_WEIGHT``; among themselves the
rejected ones keep the order of their peak ratio, which still ranks them better than chance. Chosen on the
synthetic validation split (``synthetic:20``, default model, the pipeline before the weighted median) by
the mean bad-2 of the sparsification curve
at 10 %, 20 % .. 100 % (lower is better; ties count as in a random order; oracle 2.98, random 19.42):

    peak ratio, 0.1 x on rejected (chosen)   5.53    peak ratio x (1 - lr / 2), 0 on rejected   5.77
    peak ratio, 0.25 / 0.5 x on rejected     5.53 / 5.60    peak ratio on every pixel, no check   6.27
    peak ratio, 0 on rejected                5.67    1 - exp(-margin / P2), 0 on rejected       5.98
    the check alone (1 / 0)                  9.90    peak ratio with the adjacent runner-up     6.52

A continuous term in the left-right distance (``1 - lr / 2``) lost, so the distance enters through the
check. Cones is reported only (docs/service.md, "Confidence"). Computed only when asked
(``MatchOptions(confidence=True)``): one more pass over the aggregated volume.
"""

from __future__ import annotations

import numpy as np
from numba import prange

from service.cost import checked_winners
from service.jit import njit
from service.validation.codes import VALID

_NO_RIVAL = np.int32(2**30)
# Factor on the peak ratio of the pixels the left-right check rejected (module docstring: synthetic:20).
REJECTED_WEIGHT = 0.1


@njit(parallel=True)
def _confidence_rows(volume, winners, lowest, confidence):  # type: ignore[no-untyped-def]
    height, width, disparities = volume.shape
    for y in prange(height):
        for x in range(width):
            costs = volume[y, x]
            winner = winners[y, x]
            best = np.int32(costs[winner])
            rival = _NO_RIVAL
            for d in range(0, max(winner - 1, 0)):
                rival = min(rival, np.int32(costs[d]))
            for d in range(winner + 2, disparities):
                rival = min(rival, np.int32(costs[d]))
            if rival == _NO_RIVAL:
                confidence[y, x] = 1.0
                continue
            spread = max(rival - lowest, 1)
            confidence[y, x] = min(max(np.float32(rival - best) / np.float32(spread), np.float32(0.0)),
                                   np.float32(1.0))


def cost_confidence(volume: np.ndarray, winners: np.ndarray, *, lowest: float) -> np.ndarray:
    """float32 HxW peak ratio ``(C2 - C1) / (C2 - lowest)`` of an int16 ``(H, W, D)`` volume and its int
    HxW winners (cell indices); ``lowest`` is the smallest cost the volume can hold."""
    winners = checked_winners(volume, winners)
    confidence = np.empty(winners.shape, np.float32)
    _confidence_rows(np.ascontiguousarray(volume), winners, np.int32(np.floor(lowest)), confidence)
    return confidence


def weigh_by_check(confidence: np.ndarray, validity: np.ndarray, disparity: np.ndarray) -> np.ndarray:
    """The confidence map: the peak ratio where the check accepted the pixel (``Validity.VALID``),
    ``REJECTED_WEIGHT`` x the peak ratio where it did not, 0 where the disparity is missing (NaN)."""
    if not confidence.shape == validity.shape == disparity.shape:
        raise ValueError(f"confidence {confidence.shape}, validity {validity.shape} and disparity "
                         f"{disparity.shape} differ in shape")
    weight = np.where(validity == VALID, np.float32(1.0), np.float32(REJECTED_WEIGHT))
    weight[np.isnan(disparity)] = 0.0
    return (confidence * weight).astype(np.float32, copy=False)
