"""Shiftable windows: each cost becomes the lowest cost of the same disparity within +-r pixels on its row.

A tower's feature is computed over a centred window (its receptive field), so next to a depth edge a
background pixel's window holds the foreground too, and the foreground's disparity can win there: the
depth edge bleeds onto the background ("foreground fattening"). The min filter of Scharstein and Szeliski
(2002, section 3.2: "shiftable windows") lets each cell take the cost of a window shifted along the row by
up to :data:`SHIFT_RADIUS` pixels, which at an edge can lie wholly on the pixel's own surface. Both views'
windows shift together (cell ``(y, x, d)`` compares left ``x`` with right ``x - d``), so the right view's
costs read from the same volume (the left-right check) are shifted windows too.

Along rows only, as the search runs: a vertical shift and a 3x3 square were measured worse on the
synthetic validation split, a radius of 2 no better than 1 after the penalties were tuned again
(docs/training.md, "Shiftable windows"). Cells left of the right image (``x - d < 0``, +scale) take a
neighbour's in-range cost where one lies within the radius, as a shifted window there is in range.
"""

from __future__ import annotations

import numpy as np
from numba import prange

from service.jit import njit

SHIFT_RADIUS = 1  # pixels each side: a 1x3 min filter along the row


@njit(parallel=True)
def _shift_rows(volume, radius):  # type: ignore[no-untyped-def]
    height, width, disparities = volume.shape
    for y in prange(height):
        # The row's original costs of x - radius .. x - 1, which the filter has overwritten (a ring).
        behind = np.empty((radius, disparities), volume.dtype)
        lowest = np.empty(disparities, volume.dtype)
        for x in range(width):
            cell = volume[y, x]
            lowest[:] = cell
            for neighbour in range(x + 1, min(width, x + radius + 1)):
                ahead = volume[y, neighbour]
                for d in range(disparities):
                    lowest[d] = min(lowest[d], ahead[d])
            for back in range(min(x, radius)):
                kept = behind[(x - 1 - back) % radius]
                for d in range(disparities):
                    lowest[d] = min(lowest[d], kept[d])
            behind[x % radius] = cell
            cell[:] = lowest


def shiftable_windows(volume: np.ndarray, *, radius: int = SHIFT_RADIUS) -> np.ndarray:
    """Min-filter an int16 ``(H, W, D)`` cost volume along its rows (x +- ``radius``), in place; returns it.

    >>> volume = np.array([[[5], [1], [7], [9]]], np.int16)
    >>> shiftable_windows(volume)[0, :, 0].tolist()
    [1, 1, 1, 7]
    """
    if volume.ndim != 3 or volume.dtype != np.int16 or not volume.flags.c_contiguous:
        raise ValueError(f"expected a C-contiguous int16 (H, W, D) volume, got {volume.dtype} {volume.shape}")
    if isinstance(radius, bool) or not isinstance(radius, int | np.integer) or radius < 0:
        raise ValueError(f"radius must be an integer >= 0, got {radius!r}")
    if radius and volume.size:
        _shift_rows(volume, int(radius))
    return volume
