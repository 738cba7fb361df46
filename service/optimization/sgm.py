"""Semi-global matching over 4 paths (left->right, right->left, top->bottom, bottom->top), summed (Numba).

Each path follows eq. (20) of the ADSM paper (Hirschmüller's SGM) exactly:

    L(p, d) = C(p, d) + min(L(p-r, d), L(p-r, d-1) + P1, L(p-r, d+1) + P1, min_k L(p-r, k) + P2)
              - min_k L(p-r, k)

with ``L = C`` at the first pixel of a path. Subtracting the previous minimum keeps every ``L`` within
``[min C, max C + P2]``.

Integer arithmetic, exactly: the cost volume is int16 (``service.cost``), the penalties are rounded to
whole cost units, so every ``L`` is an integer, computed in float32 registers (exact below 2^24, and
float32 vectorises where Numba would widen int16 arithmetic to int64) and summed into an int16 result. With
``|C| <= MAX_COST_SCALE`` (1024) and ``P2 <= MAX_PENALTY`` (4096) the sum of 4 paths stays below
4 * (1024 + 4096) = 20480 < 32767; the store saturates anyway, so no input can wrap around.

Memory: the result is the only volume-sized allocation. A path never stores its own volume; it keeps the
previous pixel's ``L`` (one D vector, or one ``(block, D)`` slab for the vertical paths) and adds the new
``L`` straight into the output. Horizontal paths run one row per task; vertical paths run one block of
columns per task, walking the rows in order, so both read the ``(H, W, D)`` volume row-major.
"""

from __future__ import annotations

import numpy as np
from numba import prange

from service.cost import COST_DTYPE
from service.jit import njit

# Stands in for L(p-r, -1) and L(p-r, D): finite (fastmath kernels assume no inf) and far above any cost.
_OUTSIDE = np.float32(1e30)
# The running min_d L is kept as an int32: LLVM vectorises an integer min reduction but not Numba's float
# one (its float compares carry no no-NaN flag), and every L is an exact integer anyway. Vectorising this
# loop took the 4 paths at 375x1242x192, 2 threads, from 0.25 s to 0.07 s.
_NO_MINIMUM = np.int32(2**30)
MAX_PENALTY = 4096.0
PATHS = 4  # summed into the result: every aggregated cost lies in [PATHS x min C, PATHS x (max C + P2)]
_INT16_MIN, _INT16_MAX = np.float32(-32768.0), np.float32(32767.0)
# Grey-level step at which the image-adaptive P2 halves (see :func:`aggregate`). Measured with the
# 13-1deconv3-4conv 32-channel towers at P1/P2 45/360 (border step on): Cones bad-2 10.08 -> 8.94 %,
# accepted-pixel bad-2 4.29 -> 3.83 %; docs/training.md, "Post-processing".
P2_EDGE = 8.0


@njit(inline="always")
def _add(total, d, value, assign):  # type: ignore[no-untyped-def]
    if not assign:
        value += np.float32(total[d])
    total[d] = np.int16(min(max(value, _INT16_MIN), _INT16_MAX))
# Columns per vertical task: a (block, D) slab of L stays in L1/L2 while the rows stream past.
_COLUMN_BLOCK = 32


@njit(inline="always")
def _path_step(cost, previous, current, total, p1, p2, previous_min, assign):  # type: ignore[no-untyped-def]
    """One step of eq. (20); ``previous``/``current`` are padded by one sentinel cell on each side.

    Adds (or, with ``assign``, writes) the new ``L`` into ``total`` and returns ``min_d L``.
    """
    jump = previous_min + p2
    new_min = _NO_MINIMUM
    for d in range(cost.shape[0]):
        best = min(previous[d + 1], previous[d] + p1, previous[d + 2] + p1, jump)
        value = np.float32(cost[d]) + best - previous_min
        current[d + 1] = value
        _add(total, d, value, assign)
        new_min = min(new_min, np.int32(value))
    return np.float32(new_min)


@njit(inline="always")
def _jump_penalty(guide, y, x, y_before, x_before, p1, p2, edge):  # type: ignore[no-untyped-def]
    """P2 of the step from (y_before, x_before) to (y, x): lower across an image edge when edge > 0."""
    if edge <= 0.0:
        return p2
    step = abs(guide[y, x] - guide[y_before, x_before])
    return max(p1, np.float32(np.rint(p2 / (np.float32(1.0) + step / edge))))


@njit(inline="always")
def _path_start(cost, current, total, assign):  # type: ignore[no-untyped-def]
    """First pixel of a path: ``L = C``; returns ``min_d L``."""
    new_min = _NO_MINIMUM
    for d in range(cost.shape[0]):
        value = np.float32(cost[d])
        current[d + 1] = value
        _add(total, d, value, assign)
        new_min = min(new_min, np.int32(value))
    return np.float32(new_min)


@njit(parallel=True)
def _horizontal_paths(cost, p1, p2, guide, edge, total):  # type: ignore[no-untyped-def]
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
                jump = _jump_penalty(guide, y, x, y, x - step, p1, p2, edge)
                previous_min = _path_step(
                    cost[y, x], previous, current, total[y, x], p1, jump, previous_min, assign
                )
                previous, current = current, previous
                x += step


@njit(parallel=True)
def _vertical_paths(cost, p1, p2, guide, edge, total):  # type: ignore[no-untyped-def]
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
                    jump = _jump_penalty(guide, y, x, y - step, x, p1, p2, edge)
                    previous_min[i] = _path_step(
                        cost[y, x], previous[i], current[i], total[y, x], p1, jump, previous_min[i], False
                    )
                previous, current = current, previous
                y += step


def aggregate(cost: np.ndarray, *, p1: float, p2: float, out: np.ndarray | None = None,
              guide: np.ndarray | None = None, edge: float = P2_EDGE) -> np.ndarray:
    """Sum of the 4 SGM path costs of an ``(H, W, D)`` int16 cost volume, as an int16 ``(H, W, D)`` volume.

    ``p1`` penalises a disparity change of 1 between neighbours, ``p2`` any larger jump; both are in the
    cost's units (see the manifest's ``cost.scale``), rounded to whole units, at most ``MAX_PENALTY``.
    ``out`` may be a preallocated C-contiguous int16 result array.

    With a ``guide`` (float32 ``(H, W)`` grey levels of the left image, 0..255) and ``edge`` > 0, the jump
    penalty of a step between neighbours p and q is ``max(P1, round(P2 / (1 + |I(p) - I(q)| / edge)))``
    (Hirschmueller's image-adaptive P2): depth may jump where the image has an edge, so the nearer
    surface no longer bleeds over the farther one. ``guide=None`` keeps P2 constant.

    >>> cost = np.array([[[0, 9], [9, 0]]], np.int16)  # one row, two pixels, two disparities
    >>> aggregate(cost, p1=1, p2=5).tolist()
    [[[1, 36], [36, 1]]]
    """
    if cost.ndim != 3 or min(cost.shape) < 1:
        raise ValueError(f"cost volume must be a non-empty (H, W, D) array, got shape {cost.shape}")
    for name, value in (("p1", p1), ("p2", p2)):
        if not np.isfinite(value) or not 0 <= value <= MAX_PENALTY:
            raise ValueError(f"SGM penalty {name} must be a number in [0, {MAX_PENALTY:g}], got {value}")
    if cost.dtype != COST_DTYPE:
        raise ValueError(f"cost volume must be int16 (service.cost.cost_volume), got {cost.dtype}")
    if out is None:
        out = np.empty(cost.shape, COST_DTYPE)
    elif out.shape != cost.shape or out.dtype != COST_DTYPE or not out.flags.c_contiguous:
        raise ValueError(f"out must be a C-contiguous int16 array of shape {cost.shape}")
    if not np.isfinite(edge):
        raise ValueError(f"edge must be finite, got {edge}")
    if guide is None or edge <= 0:
        guide, edge = np.zeros((1, 1), np.float32), 0.0     # never read: the kernels keep P2 constant
    elif guide.shape != cost.shape[:2]:
        raise ValueError(f"guide {guide.shape} must be the cost volume's H x W {cost.shape[:2]}")
    cost = np.ascontiguousarray(cost)
    guide = np.ascontiguousarray(guide, dtype=np.float32)
    whole_p1, whole_p2, edge32 = np.float32(np.rint(p1)), np.float32(np.rint(p2)), np.float32(edge)
    _horizontal_paths(cost, whole_p1, whole_p2, guide, edge32, out)
    _vertical_paths(cost, whole_p1, whole_p2, guide, edge32, out)
    return out
