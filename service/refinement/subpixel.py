"""Quadratic sub-pixel fit: the vertex of the parabola through the costs at ``d - 1``, ``d``, ``d + 1``.

    d* = d + (C[d-1] - C[d+1]) / (2 (C[d-1] - 2 C[d] + C[d+1]))

Applied only where both neighbours exist and the parabola opens upwards (denominator > 0); the offset is
clamped to +-0.5 so a refined value never leaves its winner's pixel.
"""

from __future__ import annotations

import numpy as np
from numba import prange

from service.cost import checked_winners
from service.jit import njit


@njit(parallel=True)
def _refine_rows(volume, winners, refined):  # type: ignore[no-untyped-def]
    height, width, disparities = volume.shape
    for y in prange(height):
        for x in range(width):
            d = winners[y, x]
            refined[y, x] = d
            if 0 < d < disparities - 1:
                before = np.float32(volume[y, x, d - 1])
                after = np.float32(volume[y, x, d + 1])
                curvature = before - np.float32(2.0) * np.float32(volume[y, x, d]) + after
                if curvature > 0.0:
                    offset = (before - after) / (np.float32(2.0) * curvature)
                    refined[y, x] = d + min(np.float32(0.5), max(np.float32(-0.5), offset))


def refine_subpixel(volume: np.ndarray, winners: np.ndarray) -> np.ndarray:
    """float32 HxW sub-pixel disparities from an int16 ``(H, W, D)`` cost volume and its int HxW winners."""
    winners = checked_winners(volume, winners)
    refined = np.empty(winners.shape, np.float32)
    _refine_rows(np.ascontiguousarray(volume), winners, refined)
    return refined
