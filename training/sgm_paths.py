"""Four-path SGM as a differentiable torch operation, for the loss after aggregation (training.sgm_loss).

The forward pass is the runtime's recursion (``service.optimization.sgm``, eq. (20)) in float32 with
constant penalties, over a batch of volumes. Each path's minima are piecewise linear in the costs, so the
gradient of ``L(p, d)`` follows the candidate that won at every step (SGM-Net's backward): the forward
pass records, per cell, which disparity of the previous pixel it took (``d``, ``d +- 1`` or the previous
minimum's) and, per pixel, where the previous minimum lay; the backward pass walks each path in reverse
and routes the gradient along those choices. Written as Numba kernels because a torch loop over 768 scan
steps of a 128 x 256 crop costs a minute a batch on one core, these a fraction of a second.
"""

from __future__ import annotations

import numpy as np
import torch
from numba import prange

from service.jit import njit

PATHS = 4  # left-right, right-left, top-down, bottom-up, summed as the runtime sums them


@njit(parallel=True)
def _scan_forward(cost, p1, p2, reverse, out, taken, low_at):  # type: ignore[no-untyped-def]
    """Add the paths along axis 2 of ``cost`` [N, H, W, D] (reverse: from the last column) into ``out``;
    record each cell's chosen previous disparity in ``taken`` and each pixel's previous minimum in
    ``low_at``."""
    n_volumes, height, width, disparities = cost.shape
    for row in prange(n_volumes * height):
        n, y = row // height, row % height
        previous = np.empty(disparities, np.float32)
        current = np.empty(disparities, np.float32)
        x = width - 1 if reverse else 0
        for d in range(disparities):
            previous[d] = cost[n, y, x, d]
            out[n, y, x, d] += previous[d]
        for i in range(1, width):
            x = width - 1 - i if reverse else i
            low, low_d = previous[0], 0
            for d in range(1, disparities):
                if previous[d] < low:
                    low, low_d = previous[d], d
            low_at[n, y, x] = low_d
            for d in range(disparities):
                best, source = previous[d], d
                if d > 0 and previous[d - 1] + p1 < best:
                    best, source = previous[d - 1] + p1, d - 1
                if d + 1 < disparities and previous[d + 1] + p1 < best:
                    best, source = previous[d + 1] + p1, d + 1
                if low + p2 < best:
                    best, source = low + p2, low_d
                taken[n, y, x, d] = source
                current[d] = cost[n, y, x, d] + best - low
                out[n, y, x, d] += current[d]
            previous, current = current, previous


@njit(parallel=True)
def _scan_backward(grad_out, taken, low_at, reverse, grad_cost):  # type: ignore[no-untyped-def]
    """Add into ``grad_cost`` the gradient that the paths of :func:`_scan_forward` pass to the costs."""
    n_volumes, height, width, disparities = grad_out.shape
    for row in prange(n_volumes * height):
        n, y = row // height, row % height
        grad = np.zeros(disparities, np.float32)
        earlier = np.empty(disparities, np.float32)
        for i in range(width - 1, -1, -1):
            x = width - 1 - i if reverse else i
            total = np.float32(0.0)
            for d in range(disparities):
                grad[d] += grad_out[n, y, x, d]
                grad_cost[n, y, x, d] += grad[d]
                total += grad[d]
            if i == 0:
                break
            earlier[:] = 0.0
            for d in range(disparities):
                earlier[taken[n, y, x, d]] += grad[d]
            earlier[low_at[n, y, x]] -= total        # the "- min_k L(p - r, k)" of every cell
            grad, earlier = earlier, grad


def _paths(cost: np.ndarray, p1: float, p2: float) -> tuple[np.ndarray, list[tuple[np.ndarray, ...]]]:
    out = np.zeros_like(cost)
    records = []
    for volume, axis_swapped in ((cost, False), (np.ascontiguousarray(cost.transpose(0, 2, 1, 3)), True)):
        summed = np.zeros_like(volume)
        for reverse in (False, True):
            taken = np.empty(volume.shape, np.int16)
            low_at = np.empty(volume.shape[:3], np.int16)
            _scan_forward(volume, np.float32(p1), np.float32(p2), reverse, summed, taken, low_at)
            records.append((taken, low_at, reverse, axis_swapped))
        out += summed.transpose(0, 2, 1, 3) if axis_swapped else summed
    return out, records


class _SGM(torch.autograd.Function):
    @staticmethod
    def forward(ctx, cost: torch.Tensor, p1: float, p2: float) -> torch.Tensor:  # type: ignore[override]
        out, ctx.records = _paths(np.ascontiguousarray(cost.detach().cpu().numpy(), np.float32), p1, p2)
        return torch.from_numpy(out).to(cost.device)

    @staticmethod
    def backward(ctx, grad_out: torch.Tensor) -> tuple[torch.Tensor, None, None]:  # type: ignore[override]
        grad = np.ascontiguousarray(grad_out.detach().cpu().numpy(), np.float32)
        grad_swapped = np.ascontiguousarray(grad.transpose(0, 2, 1, 3))
        grad_cost = np.zeros_like(grad)
        grad_cost_swapped = np.zeros_like(grad_swapped)
        for taken, low_at, reverse, axis_swapped in ctx.records:
            if axis_swapped:
                _scan_backward(grad_swapped, taken, low_at, reverse, grad_cost_swapped)
            else:
                _scan_backward(grad, taken, low_at, reverse, grad_cost)
        grad_cost += grad_cost_swapped.transpose(0, 2, 1, 3)
        return torch.from_numpy(grad_cost).to(grad_out.device), None, None


def sgm_paths(cost: torch.Tensor, *, p1: float, p2: float) -> torch.Tensor:
    """The sum of the four SGM paths over ``cost`` [N, H, W, D] (float32; left-right, right-left,
    top-down, bottom-up), differentiable in ``cost``; constant penalties ``0 <= p1 <= p2``.

    >>> cost = torch.tensor([[[[0.0, 9.0], [9.0, 0.0]]]], requires_grad=True)   # one row, two pixels
    >>> sgm_paths(cost, p1=1.0, p2=5.0).tolist()
    [[[[1.0, 36.0], [36.0, 1.0]]]]
    """
    if cost.ndim != 4:
        raise ValueError(f"cost must be [N, H, W, D], got {tuple(cost.shape)}")
    if not 0 <= p1 <= p2:
        raise ValueError(f"SGM penalties need 0 <= P1 <= P2, got {p1} and {p2}")
    if cost.shape[3] > np.iinfo(np.int16).max:
        raise ValueError(f"at most {np.iinfo(np.int16).max} disparities, got {cost.shape[3]}")
    return _SGM.apply(cost.float(), float(p1), float(p2))
