"""Semi-global matching over the 4 paths on the GPU: one block per scan line, one thread per disparity.

The recursion of eq. (20) is sequential along a path and parallel across disparities, so a block walks
one row (or column) and its threads hold the disparities of the current pixel: each step reads the
previous pixel's ``L`` from shared memory, writes the new one beside it, and the block reduces
``min_d L`` before the next step. Every path of the CPU kernels (service/optimization/sgm.py) is
reproduced exactly: the same float32 arithmetic on integers, the same saturating int16 sum, the same
image-adaptive P2, so the equality tests compare the volumes bit for bit.

A launch runs one direction of one axis over every line; the four launches run in order on one stream,
so no two threads ever add into the same cell at once. At most ``MAX_DISPARITIES`` per volume: the
previous and current ``L`` live in fixed shared arrays (the CPU path has no such cap).
"""

from __future__ import annotations

import numpy as np
from numba import cuda, float32, int16, int32

from service.cuda.volume import DeviceArray
from service.optimization.sgm import MAX_PENALTY

MAX_DISPARITIES = 1024
_SLOTS = MAX_DISPARITIES + 2  # L with one sentinel cell each side
_MAX_THREADS = 256
_DEFAULT_MAX_THREADS = 128
_OUTSIDE = float32(1e30)
_NO_MINIMUM = int32(2**30)


THREAD_CHOICES = (32, 64, 128, 256)  # powers of two (the min-reduction's tree), one warp to _MAX_THREADS


def threads_for(disparities: int) -> int:
    """Threads of a line's block by default: the power of two covering the disparities, from one warp up
    to 128; more disparities are looped over. The cap is measured: at KITTI size, D = 192, on an H100
    (`python -m bench gpu --sgm-threads 32 64 128 256 --sizes kitti`, docs/gpu.md), 128 threads took
    8.7 ms per view against 9.4 with 256 (the tree's eighth level and 64 idle threads cost more than
    the second pass) and 9.9 with 64."""
    threads = 32
    while threads < min(disparities, _DEFAULT_MAX_THREADS):
        threads *= 2
    return threads


@cuda.jit(device=True)
def _block_min(value, scratch):  # type: ignore[no-untyped-def]
    """The block's smallest ``value`` (int32), returned to every thread."""
    tid = cuda.threadIdx.x
    scratch[tid] = value
    cuda.syncthreads()
    half = cuda.blockDim.x // 2
    while half > 0:
        if tid < half:
            scratch[tid] = min(scratch[tid], scratch[tid + half])
        cuda.syncthreads()
        half //= 2
    smallest = scratch[0]
    cuda.syncthreads()  # scratch[0] is read by all before the next reduction writes it
    return smallest


@cuda.jit(device=True)
def _add(total, y, x, d, value, assign):  # type: ignore[no-untyped-def]
    if not assign:
        value += float32(total[y, x, d])
    total[y, x, d] = int16(min(max(value, float32(-32768.0)), float32(32767.0)))


@cuda.jit(device=True)
def _jump_penalty(guide, y, x, y_before, x_before, p1, p2, edge):  # type: ignore[no-untyped-def]
    if edge <= 0.0:
        return p2
    step = abs(guide[y, x] - guide[y_before, x_before])
    return max(p1, float32(round(p2 / (float32(1.0) + step / edge))))


@cuda.jit
def _path(cost, p1, p2, guide, edge, horizontal, forward, assign, total):  # type: ignore[no-untyped-def]
    """One direction of one axis: block b walks row b (horizontal) or column b, forwards or backwards."""
    height, width, disparities = cost.shape
    line = cuda.blockIdx.x
    tid = cuda.threadIdx.x
    threads = cuda.blockDim.x
    previous = cuda.shared.array(_SLOTS, float32)
    current = cuda.shared.array(_SLOTS, float32)
    scratch = cuda.shared.array(_MAX_THREADS, int32)
    length = width if horizontal else height
    step = 1 if forward else -1
    position = 0 if forward else length - 1
    y = line if horizontal else position
    x = position if horizontal else line
    if tid == 0:
        previous[0] = _OUTSIDE
        previous[disparities + 1] = _OUTSIDE
        current[0] = _OUTSIDE
        current[disparities + 1] = _OUTSIDE
    lowest = _NO_MINIMUM
    for d in range(tid, disparities, threads):
        value = float32(cost[y, x, d])
        previous[d + 1] = value
        _add(total, y, x, d, value, assign)
        lowest = min(lowest, int32(value))
    previous_min = float32(_block_min(lowest, scratch))
    for _ in range(length - 1):
        y_before, x_before = y, x
        if horizontal:
            x += step
        else:
            y += step
        jump = _jump_penalty(guide, y, x, y_before, x_before, p1, p2, edge)
        lowest = _NO_MINIMUM
        for d in range(tid, disparities, threads):
            best = min(previous[d + 1], previous[d] + p1, previous[d + 2] + p1, previous_min + jump)
            value = float32(cost[y, x, d]) + best - previous_min
            current[d + 1] = value
            _add(total, y, x, d, value, assign)
            lowest = min(lowest, int32(value))
        previous_min = float32(_block_min(lowest, scratch))
        previous, current = current, previous


def aggregate(cost: DeviceArray, *, p1: float, p2: float, out: DeviceArray, guide: DeviceArray | None = None,
              edge: float = 0.0, threads: int | None = None) -> None:
    """Sum of the 4 SGM path costs of a device int16 ``(H, W, D)`` volume into the device array ``out``
    (service.optimization.aggregate's arithmetic); ``guide``: a device float32 ``(H, W)`` grey image for
    the image-adaptive P2 with ``edge`` > 0, else None; ``threads`` per line's block, one of
    ``THREAD_CHOICES`` (None: :func:`threads_for`)."""
    height, width, disparities = cost.shape
    if disparities > MAX_DISPARITIES:
        raise ValueError(f"the GPU path searches at most {MAX_DISPARITIES} disparities, got {disparities}")
    for name, value in (("p1", p1), ("p2", p2)):
        if not np.isfinite(value) or not 0 <= value <= MAX_PENALTY:
            raise ValueError(f"SGM penalty {name} must be a number in [0, {MAX_PENALTY:g}], got {value}")
    if guide is None or edge <= 0:
        guide, edge = cuda.to_device(np.zeros((1, 1), np.float32)), 0.0
    whole_p1, whole_p2, edge32 = np.float32(np.rint(p1)), np.float32(np.rint(p2)), np.float32(edge)
    if threads is None:
        threads = threads_for(disparities)
    elif threads not in THREAD_CHOICES:
        raise ValueError(f"threads per SGM line must be one of {THREAD_CHOICES}, got {threads}")
    # Left->right assigns the sum; the other three add to it, each launch after the one before.
    for horizontal, forward, lines in ((True, True, height), (True, False, height),
                                       (False, True, width), (False, False, width)):
        _path[lines, threads](cost, whole_p1, whole_p2, guide, edge32, horizontal, forward,
                              horizontal and forward, out)
