"""Semi-global matching over 4 paths (left->right, right->left, top->bottom, bottom->top), summed (Numba).

Each path follows eq. (20) of the ADSM paper (Hirschmüller's SGM) exactly:

    L(p, d) = C(p, d) + min(L(p-r, d), L(p-r, d-1) + P1, L(p-r, d+1) + P1, min_k L(p-r, k) + P2)
              - min_k L(p-r, k)

with ``L = C`` at the first pixel of a path. Subtracting the previous minimum keeps every ``L`` within
``[min C, max C + P2]``, so float32 is exact enough for any image size.

Memory: the result is the only volume-sized allocation. A path never stores its own volume; it keeps the
previous pixel's ``L`` (one D vector, or one ``(block, D)`` slab for the vertical paths) and adds the new
``L`` straight into the output. Horizontal paths run one row per task; vertical paths run one block of
columns per task, walking the rows in order, so both read the ``(H, W, D)`` volume row-major.
"""

from __future__ import annotations

import numpy as np
from numba import prange

from service.jit import njit

# Stands in for L(p-r, -1) and L(p-r, D): finite (fastmath kernels assume no inf) and far above any cost.
_OUTSIDE = np.float32(1e30)
# Columns per vertical task: a (block, D) slab of L stays in L1/L2 while the rows stream past.
_COLUMN_BLOCK = 32


@njit(inline="always")
def _path_step(cost, previous, current, total, p1, p2, previous_min, assign):
    """One step of eq. (20); ``previous``/``current`` are padded by one sentinel cell on each side.

    Adds (or, with ``assign``, writes) the new ``L`` into ``total`` and returns ``min_d L``.
    """
    jump = previous_min + p2
    new_min = _OUTSIDE
    for d in range(cost.shape[0]):
        best = min(previous[d + 1], previous[d] + p1, previous[d + 2] + p1, jump)
        value = cost[d] + best - previous_min
        current[d + 1] = value
        if assign:
            total[d] = value
        else:
            total[d] += value
        new_min = min(new_min, value)
    return new_min


@njit(inline="always")
def _path_start(cost, current, total, assign):
    """First pixel of a path: ``L = C``; returns ``min_d L``."""
    new_min = _OUTSIDE
    for d in range(cost.shape[0]):
        value = cost[d]
        current[d + 1] = value
        if assign:
            total[d] = value
        else:
            total[d] += value
        new_min = min(new_min, value)
    return new_min


@njit(parallel=True)
def _horizontal_paths(cost, p1, p2, total):
    """left->right (writes ``total``) and right->left (adds to it), one row per task."""
    height, width, disparities = cost.shape
    for y in prange(height):
        previous = np.full(disparities + 2, _OUTSIDE, np.float32)
        current = np.full(disparities + 2, _OUTSIDE, np.float32)
        for direction in range(2):
            assign = direction == 0
            start = 0 if direction == 0 else width - 1
            step = 1 if direction == 0 else -1
            previous_min = _path_start(cost[y, start], previous, total[y, start], assign)
            x = start + step
            for _ in range(width - 1):
                previous_min = _path_step(
                    cost[y, x], previous, current, total[y, x], p1, p2, previous_min, assign
                )
                previous, current = current, previous
                x += step


@njit(parallel=True)
def _vertical_paths(cost, p1, p2, total):
    """top->bottom and bottom->top, both added to ``total``; one block of columns per task."""
    height, width, disparities = cost.shape
    blocks = (width + _COLUMN_BLOCK - 1) // _COLUMN_BLOCK
    for block in prange(blocks):
        x0 = block * _COLUMN_BLOCK
        x1 = min(x0 + _COLUMN_BLOCK, width)
        previous = np.full((x1 - x0, disparities + 2), _OUTSIDE, np.float32)
        current = np.full((x1 - x0, disparities + 2), _OUTSIDE, np.float32)
        previous_min = np.empty(x1 - x0, np.float32)
        for direction in range(2):
            start = 0 if direction == 0 else height - 1
            step = 1 if direction == 0 else -1
            for x in range(x0, x1):
                previous_min[x - x0] = _path_start(cost[start, x], previous[x - x0], total[start, x], False)
            y = start + step
            for _ in range(height - 1):
                for x in range(x0, x1):
                    i = x - x0
                    previous_min[i] = _path_step(
                        cost[y, x], previous[i], current[i], total[y, x], p1, p2, previous_min[i], False
                    )
                previous, current = current, previous
                y += step


def aggregate(cost: np.ndarray, *, p1: float, p2: float, out: np.ndarray | None = None) -> np.ndarray:
    """Sum of the 4 SGM path costs of an ``(H, W, D)`` float32 cost volume, as a new ``(H, W, D)`` volume.

    ``p1`` penalises a disparity change of 1 between neighbours, ``p2`` any larger jump; both are in the
    cost's units (see the manifest's ``cost.scale``). ``out`` may be a preallocated result array.
    """
    if cost.ndim != 3 or min(cost.shape) < 1:
        raise ValueError(f"cost volume must be a non-empty (H, W, D) array, got shape {cost.shape}")
    for name, value in (("p1", p1), ("p2", p2)):
        if not np.isfinite(value) or value < 0:
            raise ValueError(f"SGM penalty {name} must be a finite number >= 0, got {value}")
    if out is None:
        out = np.empty(cost.shape, np.float32)
    elif out.shape != cost.shape or out.dtype != np.float32 or not out.flags.c_contiguous:
        raise ValueError(f"out must be a C-contiguous float32 array of shape {cost.shape}")
    cost = np.ascontiguousarray(cost, dtype=np.float32)
    _horizontal_paths(cost, np.float32(p1), np.float32(p2), out)
    _vertical_paths(cost, np.float32(p1), np.float32(p2), out)
    return out
