"""Winner-takes-all: the disparity of least cost per pixel (ties go to the smaller disparity, as argmin).

:func:`left_right_winners` also finds the right view's winners from the *left* volume in the same pass
(``CR[y, x, d] = CL[y, x + d, d]``, the inner check of MC-CNN): each cell ``(x, d)`` read for the left
argmin is the cell ``(x - d, d)`` of the right view, so one row-major sweep serves both and the volume is
read once.
"""

from __future__ import annotations

import numpy as np
from numba import prange

from service.cost import checked_volume
from service.jit import njit


@njit(inline="always")
def _argmin(costs):  # type: ignore[no-untyped-def]
    """Index of the smallest cost; the smallest index on ties (strict <)."""
    best = 0
    best_cost = costs[0]
    for d in range(1, costs.shape[0]):
        if costs[d] < best_cost:
            best_cost = costs[d]
            best = d
    return best


@njit(parallel=True)
def _winners(volume, left):  # type: ignore[no-untyped-def]
    height, width, _ = volume.shape
    for y in prange(height):
        for x in range(width):
            left[y, x] = _argmin(volume[y, x])


_UNSEEN = np.int32(2**30)  # above any int16 cost: the first cell that reaches a right pixel wins


@njit(parallel=True)
def _left_right_winners(volume, min_disparity, left, right):  # type: ignore[no-untyped-def]
    height, width, disparities = volume.shape
    for y in prange(height):
        right_best = np.full(width, _UNSEEN, np.int32)
        for x in range(width):
            right[y, x] = 0  # kept by a right pixel no cell reaches (its match lies outside the left view)
        for x in range(width):
            costs = volume[y, x]
            left[y, x] = _argmin(costs)
            # Cell k of left pixel x is cell k of right pixel x - min_disparity - k. Later x reach a right
            # pixel with growing k, so a strict < keeps the smallest k on ties.
            match = x - min_disparity
            for d in range(max(0, match - width + 1), min(disparities, match + 1)):
                if costs[d] < right_best[match - d]:
                    right_best[match - d] = costs[d]
                    right[y, match - d] = d


def winner_takes_all(volume: np.ndarray) -> np.ndarray:
    """int32 HxW argmin over d of an ``(H, W, D)`` cost volume."""
    volume = checked_volume(volume)
    left = np.empty(volume.shape[:2], np.int32)
    _winners(volume, left)
    return left


def left_right_winners(volume: np.ndarray, *, min_disparity: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """int32 HxW winners (cell indices) of the left view and of the right view, both from the left
    ``(H, W, D)`` volume whose cell ``k`` is disparity ``min_disparity + k``.

    ``right[y, x] = argmin_k volume[y, x + min_disparity + k, k]`` over the cells whose left pixel lies in
    the image; 0 where there is none.
    """
    volume = checked_volume(volume)
    left = np.empty(volume.shape[:2], np.int32)
    right = np.empty(volume.shape[:2], np.int32)
    _left_right_winners(volume, int(min_disparity), left, right)
    return left, right
