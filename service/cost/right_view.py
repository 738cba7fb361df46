"""The right view's cost volume, re-indexed from the left one: ``CR[y, x, k] = CL[y, x + m + k, k]``.

With ``m`` = ``min_disparity``, both volumes hold the same matching costs (cell ``k`` of right pixel
``x`` compares it with left pixel ``x + m + k``, the cell ``(x + m + k, k)`` of the left volume), so no
tower runs again. What differs is the frame SGM aggregates in: in the left frame a near surface's costs
spread over the farther surface left of it, which the left camera sees and the right one does not; in
the right frame they spread to its right. MC-CNN computes its right disparity map ``D^R`` this way, with
the whole aggregation run again on the right view, and its left-right check then catches what either
frame fattened (right winners read off the left-aggregated volume inherit the left frame's fattening,
and the check passes it). Measured in docs/training.md ("The right view aggregated in its own frame").

Cells whose left match lies outside the left image get ``+scale``, the largest cost, as in
:func:`service.cost.cost_volume`.
"""

from __future__ import annotations

import numpy as np
from numba import prange

from service.cost.volume import COST_DTYPE, _to_cost, check_cost_settings, checked_volume
from service.jit import njit


@njit(parallel=True)
def _right_view_rows(volume, min_disparity, scale, out):  # type: ignore[no-untyped-def]
    height, width, disparities = volume.shape
    outside = _to_cost(scale, scale)
    for y in prange(height):
        # A copy of the row first: ``out`` may be ``volume`` itself, and with a negative min_disparity a
        # cell reads a column left of the one it writes.
        row = volume[y].copy()
        for x in range(width):
            for k in range(disparities):
                match = x + min_disparity + k
                out[y, x, k] = row[match, k] if 0 <= match < width else outside


def right_view_volume(volume: np.ndarray, *, scale: float, min_disparity: int = 0,
                      out: np.ndarray | None = None) -> np.ndarray:
    """int16 ``(H, W, D)`` cost volume of the right view from the left view's ``volume`` (cell ``k``:
    disparity ``min_disparity + k`` in both). ``out`` may be a preallocated C-contiguous array of the same
    shape, ``volume`` itself included (the re-indexing then happens in place).

    >>> left = np.array([[[1, 2], [3, 4], [5, 6]]], np.int16)  # one row, three pixels, two disparities
    >>> right_view_volume(left, scale=128.0)[0].tolist()  # right pixel x, cell k <- left pixel x + k
    [[1, 4], [3, 6], [5, 128]]
    """
    volume = checked_volume(volume)
    check_cost_settings(scale=scale, min_disparity=min_disparity)
    if out is None:
        out = np.empty(volume.shape, COST_DTYPE)
    elif out.shape != volume.shape or out.dtype != COST_DTYPE or not out.flags.c_contiguous:
        raise ValueError(f"out must be a C-contiguous int16 array of shape {volume.shape}")
    _right_view_rows(volume, int(min_disparity), np.float32(scale), out)
    return out
