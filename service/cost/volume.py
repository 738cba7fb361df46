"""Cost volume ``CL[y, x, d] = round(-scale * <FL[:, y, x], FR[:, y, x - d]>)`` as int16 (Numba).

Layout ``(H, W, D)`` with D contiguous, because SGM and winner-takes-all run over d innermost.

**int16, not float32**: SGM, winner-takes-all and the sub-pixel fit are memory-bound, and the volume is
the runtime's only large array, so half the bytes is about half the time and half the peak memory
(375x1242, D=192: 179 MB instead of 358 MB). With the shipped scale of 128 the rounding error (at most 0.5
of a range of 256) does not show in the results: Cones bad-2 13.89 -> 13.92 %, EPE 1.68 -> 1.69 px with
the default model, identical with the NCC baseline (docs/performance.md). Integer costs also make SGM
exact: with integer penalties every path cost is an integer well inside float32's exact range.

The features arrive channel-first ``(C, H, W)``; each row is transposed into a small thread-local
``(W, C)`` buffer so that the dot product over C reads contiguous memory and vectorises. That costs
``2 * W * C`` floats per thread instead of a full transposed copy of both feature maps. The buffers'
rows are zero-padded to a multiple of ``LANES`` channels, so that the vectorised loop over C has no
scalar remainder; the zeros add nothing to any dot product.

Disparities run from ``min_disparity`` (0 by default; negative allowed): cell ``k`` holds disparity
``min_disparity + k``, so every later stage works on indices ``0 .. D - 1`` and adds the offset back.
Cells whose match would lie outside the right image (``x - d < 0``, or ``x - d >= W`` for a negative
disparity) get ``+scale``, the largest cost unit-norm features can produce.
"""

from __future__ import annotations

import numpy as np
from numba import prange

from service.jit import njit

COST_DTYPE = np.int16
# Rows are zero-padded to a multiple of 8 float32 channels (one AVX2 register, half an AVX-512 one):
# 57 channels ran 1.04-1.06x faster padded to 64 on an AVX-512 host and up to 1.3x on an AVX2 one, while
# padding 40 to 48 (16 lanes) cost 1.1x (docs/performance.md).
LANES = 8
# Largest cost.scale: keeps |cost| + P2 summed over 4 SGM paths far inside int16 (see optimization.sgm).
MAX_COST_SCALE = 1024.0


@njit(inline="always")
def _to_cost(value, scale):  # type: ignore[no-untyped-def]
    # The clip keeps features that are not unit-norm from overflowing int16.
    return np.int16(np.rint(min(max(value, -scale), scale)))


@njit(parallel=True)
def _cost_rows(left, right, scale, min_disparity, out):  # type: ignore[no-untyped-def]
    channels, height, width = left.shape
    disparities = out.shape[2]
    outside = _to_cost(scale, scale)
    lanes = (channels + LANES - 1) // LANES * LANES
    for y in prange(height):
        # The minus sign and the scale are folded into the left row: one multiply per pixel, not per cell.
        left_row = np.empty((width, lanes), np.float32)
        right_row = np.empty((width, lanes), np.float32)
        left_row[:, channels:] = 0.0
        right_row[:, channels:] = 0.0
        for c in range(channels):
            for x in range(width):
                left_row[x, c] = -scale * left[c, y, x]
                right_row[x, c] = right[c, y, x]
        for x in range(width):
            # Cells k with 0 <= x - min_disparity - k < W; ``match`` is the right column of cell 0.
            match = x - min_disparity
            first = min(max(0, match - width + 1), disparities)
            in_range = max(first, min(disparities, match + 1))
            left_vector = left_row[x]
            for d in range(first):
                out[y, x, d] = outside
            # Four disparities per pass over C: each left value is loaded once for four products, which
            # cuts the loads per multiply-add from 2 to 1.25 (0.32 -> 0.23 CPU s at C=64, 375x1242, D=192).
            d = first
            while d + 4 <= in_range:
                r0, r1 = right_row[match - d], right_row[match - d - 1]
                r2, r3 = right_row[match - d - 2], right_row[match - d - 3]
                t0 = t1 = t2 = t3 = np.float32(0.0)
                for c in range(lanes):
                    value = left_vector[c]
                    t0 += value * r0[c]
                    t1 += value * r1[c]
                    t2 += value * r2[c]
                    t3 += value * r3[c]
                out[y, x, d] = _to_cost(t0, scale)
                out[y, x, d + 1] = _to_cost(t1, scale)
                out[y, x, d + 2] = _to_cost(t2, scale)
                out[y, x, d + 3] = _to_cost(t3, scale)
                d += 4
            for tail in range(d, in_range):
                total = np.float32(0.0)
                for c in range(lanes):
                    total += left_vector[c] * right_row[match - tail, c]
                out[y, x, tail] = _to_cost(total, scale)
            for d in range(in_range, disparities):
                out[y, x, d] = outside


def cost_volume(
    left: np.ndarray, right: np.ndarray, max_disparity: int, *, scale: float, min_disparity: int = 0,
    out: np.ndarray | None = None,
) -> np.ndarray:
    """int16 cost volume of two ``(C, H, W)`` feature maps for the ``max_disparity`` disparities
    ``min_disparity .. min_disparity + max_disparity - 1`` (cell ``k`` is disparity ``min_disparity + k``).

    ``scale`` is the manifest's ``cost.scale`` (at most ``MAX_COST_SCALE``); with unit-norm features the
    costs lie in ``[-scale, +scale]``, and the products of other features are clipped to that range.
    ``out`` may be a preallocated C-contiguous ``(H, W, max_disparity)`` int16 array.

    >>> features = np.ones((1, 2, 3), np.float32)
    >>> cost_volume(features, features, 2, scale=128.0)[0].tolist()
    [[-128, 128], [-128, -128], [-128, -128]]
    """
    if left.ndim != 3 or left.shape != right.shape:
        raise ValueError(
            f"features must be two (C, H, W) arrays of one shape, got {left.shape} and {right.shape}"
        )
    if max_disparity < 1:
        raise ValueError(f"max_disparity must be >= 1, got {max_disparity}")
    check_cost_settings(scale=scale, min_disparity=min_disparity)
    _, height, width = left.shape
    shape = (height, width, int(max_disparity))
    if out is None:
        out = np.empty(shape, COST_DTYPE)
    elif out.shape != shape or out.dtype != COST_DTYPE or not out.flags.c_contiguous:
        raise ValueError(f"out must be a C-contiguous int16 array of shape {shape}")
    # One compiled specialisation: contiguous float32 (a no-op for the towers' output).
    left = np.ascontiguousarray(left, dtype=np.float32)
    right = np.ascontiguousarray(right, dtype=np.float32)
    _cost_rows(left, right, np.float32(scale), int(min_disparity), out)
    return out


def check_cost_settings(*, scale: float, min_disparity: int) -> None:
    """ValueError unless ``scale`` is a cost scale in (0, MAX_COST_SCALE] and ``min_disparity`` an integer:
    what every function that writes a volume's cells needs of them."""
    if isinstance(min_disparity, bool) or not isinstance(min_disparity, int | np.integer):
        raise ValueError(f"min_disparity must be an integer, got {min_disparity!r}")
    if not np.isfinite(scale) or not 0 < scale <= MAX_COST_SCALE:
        raise ValueError(f"cost scale must be a number in (0, {MAX_COST_SCALE:g}], got {scale}")


def checked_volume(volume: np.ndarray) -> np.ndarray:
    """``volume`` as a C-contiguous array after checking that it is a non-empty int16 ``(H, W, D)`` cost
    volume: what every kernel that reads a whole volume needs first."""
    if volume.ndim != 3 or min(volume.shape) < 1:
        raise ValueError(f"cost volume must be a non-empty (H, W, D) array, got shape {volume.shape}")
    if volume.dtype != COST_DTYPE:
        raise ValueError(f"cost volume must be int16 (service.cost.cost_volume), got {volume.dtype}")
    return np.ascontiguousarray(volume)


def checked_winners(volume: np.ndarray, winners: np.ndarray) -> np.ndarray:
    """``winners`` as C-contiguous int32 after checking them against an int16 ``(H, W, D)`` cost volume
    (shape, dtype, cell range): what every kernel that reads a volume at its winners needs first."""
    if volume.ndim != 3 or winners.shape != volume.shape[:2]:
        raise ValueError(f"winners {winners.shape} do not match the cost volume {volume.shape}")
    if volume.dtype != COST_DTYPE:
        raise ValueError(f"cost volume must be int16 (service.cost.cost_volume), got {volume.dtype}")
    winners = np.ascontiguousarray(winners, dtype=np.int32)
    if winners.size and (winners.min() < 0 or winners.max() >= volume.shape[2]):
        raise ValueError(f"winners must lie in [0, {volume.shape[2] - 1}]")
    return winners
