"""Cost volume, the right view's volume and shiftable windows on the GPU: one thread per cell.

The same cells as the CPU kernels (service/cost/volume.py, service/cost/right_view.py,
service/aggregation/shiftable_windows.py), in the same ``(H, W, D)`` int16 layout with D contiguous, so
consecutive threads of a warp touch consecutive disparities of one pixel and every access coalesces.

The cost sums the C products in order, from ``c = 0``, as the CPU kernel's scalar code does; the CPU
kernel's compiler may reassociate that sum (fastmath), so a cell can differ by one cost unit after
rounding where a sum lands on .5. The equality tests use features whose products and sums are exact in
float32, where both must agree to the bit, and random features, where they may differ by one unit.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numba import cuda, float32, int16

DeviceArray = Any  # numba.cuda's DeviceNDArray, which its stubs leave untyped
THREADS = 256  # per block of the cell kernels: whole warps, and enough blocks at 375 x 1242 x 192


@cuda.jit(device=True)
def _to_cost(value, scale):  # type: ignore[no-untyped-def]
    return int16(round(min(max(value, -scale), scale)))


@cuda.jit
def _cost_cells(left, right, scale, min_disparity, out):  # type: ignore[no-untyped-def]
    height, width, disparities = out.shape
    cell = cuda.grid(1)
    if cell >= height * width * disparities:
        return
    d = cell % disparities
    x = (cell // disparities) % width
    y = cell // (disparities * width)
    match = x - min_disparity - d
    if match < 0 or match >= width:
        out[y, x, d] = _to_cost(scale, scale)
        return
    total = float32(0.0)
    for c in range(left.shape[0]):
        total += (-scale * left[c, y, x]) * right[c, y, match]
    out[y, x, d] = _to_cost(total, scale)


@cuda.jit
def _right_view_cells(volume, min_disparity, scale, out):  # type: ignore[no-untyped-def]
    height, width, disparities = out.shape
    cell = cuda.grid(1)
    if cell >= height * width * disparities:
        return
    k = cell % disparities
    x = (cell // disparities) % width
    y = cell // (disparities * width)
    match = x + min_disparity + k
    out[y, x, k] = volume[y, match, k] if 0 <= match < width else _to_cost(scale, scale)


@cuda.jit
def _shift_cells(volume, radius, out):  # type: ignore[no-untyped-def]
    height, width, disparities = out.shape
    cell = cuda.grid(1)
    if cell >= height * width * disparities:
        return
    d = cell % disparities
    x = (cell // disparities) % width
    y = cell // (disparities * width)
    lowest = volume[y, x, d]
    for neighbour in range(max(0, x - radius), min(width, x + radius + 1)):
        lowest = min(lowest, volume[y, neighbour, d])
    out[y, x, d] = lowest


def blocks(cells: int, threads: int = THREADS) -> int:
    """Blocks of ``threads`` that cover ``cells`` threads."""
    return max(1, math.ceil(cells / threads))


def cost_volume(left: DeviceArray, right: DeviceArray, disparities: int, *, scale: float, min_disparity: int,
                out: DeviceArray) -> None:
    """``out[y, x, k]``: the int16 cost of disparity ``min_disparity + k`` (service.cost.cost_volume),
    from float32 ``(C, H, W)`` device feature maps into a device ``(H, W, disparities)`` array."""
    _cost_cells[blocks(out.size), THREADS](left, right, np.float32(scale), int(min_disparity), out)


def right_view_volume(volume: DeviceArray, *, scale: float, min_disparity: int, out: DeviceArray) -> None:
    """The right view's volume (service.cost.right_view_volume) into ``out``, a device array other than
    ``volume``: the threads of a launch run in no order, so the re-indexing cannot be in place."""
    _right_view_cells[blocks(out.size), THREADS](volume, int(min_disparity), np.float32(scale), out)


def shiftable_windows(volume: DeviceArray, *, radius: int, out: DeviceArray) -> None:
    """Row min filter of +-``radius`` (service.aggregation.shiftable_windows) from ``volume`` into ``out``."""
    _shift_cells[blocks(out.size), THREADS](volume, int(radius), out)
