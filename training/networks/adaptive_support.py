"""Adaptive support inside the towers: each conv's taps weighted by their colour likeness to the centre.

A tower's feature sees its whole receptive field, so next to a depth edge a background pixel's feature
also describes the foreground's texture, matches it, and the foreground fattens over the background
(docs/training.md, "Where the default still loses to the 3x3 NCC on Cones"). Yoon and Kweon's adaptive
support weights (2006) answer this for window costs: a neighbour votes by its colour likeness to the
centre. Here the same weights modulate every conv of the tower (a pixel-adaptive convolution, Su et al.,
2019): tap ``q`` of the window centred on ``c`` is multiplied by

    w(q) = K * softmax_q(-gain * |I(q) - I(c)|^2)        (K taps, so w = 1 everywhere in a flat region)

before the conv's weights apply, with ``I`` the tower's input image (RGB in [0, 1]) and one learned
``gain`` per layer. Stacked, the layers spread support along paths of like colour: a large window where
the image is flat (noise averages out) and one that stops at image edges (no fattening). ``gain`` 0 is
the plain conv. The weights depend on the image only, so the siamese towers and the tiled dense runtime
are unchanged, and the ONNX export writes the same arithmetic with standard ops (export.to_onnx).

    >>> guide = torch.zeros(1, 3, 3, 3)
    >>> support_weights(guide, (3, 3), torch.tensor(10.0)).shape
    torch.Size([1, 9, 1, 1])
"""

from __future__ import annotations

import math

import numba
import numpy as np
import torch
import torch.nn.functional as F
from numba import prange

from service.jit import njit

INITIAL_GAIN = 10.0  # a 50-grey-level step weighs e^-1.15 = 0.32 of a like pixel at the start (RGB in [0, 1])


def initial_log_gain() -> float:
    """The log-parametrised gain every adaptive layer starts from (positive, gradient scales with it)."""
    return math.log(INITIAL_GAIN)


def taps(kernel: tuple[int, int]) -> list[tuple[int, int]]:
    """(row, column) offsets of a kernel's taps, row-major: the order of the support weights' channels."""
    return [(row, column) for row in range(kernel[0]) for column in range(kernel[1])]


def support_weights(guide: torch.Tensor, kernel: tuple[int, int], gain: torch.Tensor) -> torch.Tensor:
    """``[N, kh * kw, H - kh + 1, W - kw + 1]`` tap weights of a valid ``kernel`` conv over ``guide``
    ``[N, 3, H, W]`` (the input image aligned with the conv's input); they sum to ``kh * kw`` per pixel."""
    kh, kw = kernel
    height, width = guide.shape[2] - kh + 1, guide.shape[3] - kw + 1
    centre = guide[:, :, kh // 2:kh // 2 + height, kw // 2:kw // 2 + width]
    distances = torch.cat([(guide[:, :, row:row + height, column:column + width] - centre)
                           .square().sum(dim=1, keepdim=True) for row, column in taps(kernel)], dim=1)
    return torch.softmax(-gain * distances, dim=1) * (kh * kw)


def adaptive_conv(features: torch.Tensor, weight: torch.Tensor, support: torch.Tensor) -> torch.Tensor:
    """A valid, bias-free conv of ``features`` ``[N, C, H, W]`` with ``weight`` ``[O, C, kh, kw]`` whose
    taps are scaled by ``support`` (:func:`support_weights`).

    On the CPU each tap's channel mix is one 1 x 1 conv over the unshifted features and a Numba
    kernel sums the shifted products times their weights (2.5x a plain conv's time, forward and backward;
    PyTorch's own ops took 10x, :func:`stacked_adaptive_conv`, which other devices use)."""
    if features.device.type != "cpu":
        return stacked_adaptive_conv(features, weight, support)
    out_channels, in_channels, kh, kw = weight.shape
    batch, _, height, width = features.shape
    mixed = F.conv2d(features, weight.permute(2, 3, 0, 1).reshape(kh * kw * out_channels, in_channels, 1, 1))
    mixed = mixed.view(batch, kh * kw, out_channels, height, width)
    return _ShiftedSum.apply(mixed, support.contiguous().float(), kw)


def stacked_adaptive_conv(features: torch.Tensor, weight: torch.Tensor,
                          support: torch.Tensor) -> torch.Tensor:
    """:func:`adaptive_conv` in PyTorch ops: the weighted taps stacked along channels, then one 1 x 1 conv
    (the export writes the same graph)."""
    kh, kw = weight.shape[2:]
    height, width = features.shape[2] - kh + 1, features.shape[3] - kw + 1
    stacked = torch.cat([features[:, :, row:row + height, column:column + width] * support[:, tap:tap + 1]
                         for tap, (row, column) in enumerate(taps((kh, kw)))], dim=1)
    return F.conv2d(stacked, stacked_weight(weight))


def stacked_weight(weight: torch.Tensor) -> torch.Tensor:
    """``[O, C, kh, kw]`` -> ``[O, kh * kw * C, 1, 1]`` in the taps' order (tap-major, then channel)."""
    out_channels, in_channels, kh, kw = weight.shape
    return weight.permute(0, 2, 3, 1).reshape(out_channels, kh * kw * in_channels, 1, 1)


class _ShiftedSum(torch.autograd.Function):
    """``out[n, o, y, x] = sum_t support[n, t, y, x] * mixed[n, t, o, y + row_t, x + column_t]``.

    With one torch thread the serial kernels run: two trainers on one thread each, as the CPU A/Bs run,
    were 2.3x slower with Numba's OpenMP pool beside torch's (its idle threads spin between regions)."""

    @staticmethod
    def forward(ctx, mixed: torch.Tensor, support: torch.Tensor, kernel_width: int) -> torch.Tensor:  # type: ignore[override]
        ctx.save_for_backward(mixed, support)
        ctx.kernel_width = kernel_width
        out = torch.empty(mixed.shape[0], mixed.shape[2], support.shape[2], support.shape[3])
        kernel = _shifted_sum if _threads() > 1 else _shifted_sum_serial
        kernel(mixed.detach().numpy(), support.detach().numpy(), kernel_width, out.numpy())
        return out

    @staticmethod
    def backward(ctx, grad: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, None]:  # type: ignore[override]
        mixed, support = ctx.saved_tensors
        grad_mixed, grad_support = torch.empty_like(mixed), torch.empty_like(support)
        kernel = _shifted_sum_backward if _threads() > 1 else _shifted_sum_backward_serial
        kernel(mixed.numpy(), support.numpy(), ctx.kernel_width, grad.contiguous().float().numpy(),
               grad_mixed.numpy(), grad_support.numpy())
        return grad_mixed, grad_support, None


def _threads() -> int:
    """torch's thread count, which the parallel kernels follow (at most Numba's pool)."""
    threads = min(torch.get_num_threads(), numba.config.NUMBA_NUM_THREADS)
    if threads > 1:
        numba.set_num_threads(threads)
    return threads


@njit(inline="always")
def _shifted_sum_row(mixed, support, kernel_width, out, job):  # type: ignore[no-untyped-def]
    height = out.shape[2]
    n, y = job // height, job % height
    for o in range(mixed.shape[2]):
        for x in range(out.shape[3]):
            out[n, o, y, x] = np.float32(0.0)
        for t in range(mixed.shape[1]):
            row, column = t // kernel_width, t % kernel_width
            for x in range(out.shape[3]):
                out[n, o, y, x] += support[n, t, y, x] * mixed[n, t, o, y + row, x + column]


@njit(inline="always")
def _shifted_sum_backward_tap(mixed, support, kernel_width, grad, grad_mixed, grad_support,  # type: ignore[no-untyped-def]
                              job):
    tap_count = mixed.shape[1]
    n, t = job // tap_count, job % tap_count
    row, column = t // kernel_width, t % kernel_width
    grad_mixed[n, t] = np.float32(0.0)  # the rows and columns no output reads stay 0
    for y in range(grad.shape[2]):
        for x in range(grad.shape[3]):
            grad_support[n, t, y, x] = np.float32(0.0)
        for o in range(mixed.shape[2]):
            for x in range(grad.shape[3]):
                grad_support[n, t, y, x] += grad[n, o, y, x] * mixed[n, t, o, y + row, x + column]
                grad_mixed[n, t, o, y + row, x + column] = grad[n, o, y, x] * support[n, t, y, x]


@njit(parallel=True)
def _shifted_sum(mixed, support, kernel_width, out):  # type: ignore[no-untyped-def]
    for job in prange(out.shape[0] * out.shape[2]):
        _shifted_sum_row(mixed, support, kernel_width, out, job)


@njit
def _shifted_sum_serial(mixed, support, kernel_width, out):  # type: ignore[no-untyped-def]
    for job in range(out.shape[0] * out.shape[2]):
        _shifted_sum_row(mixed, support, kernel_width, out, job)


@njit(parallel=True)
def _shifted_sum_backward(mixed, support, kernel_width, grad, grad_mixed, grad_support):  # type: ignore[no-untyped-def]
    for job in prange(mixed.shape[0] * mixed.shape[1]):
        _shifted_sum_backward_tap(mixed, support, kernel_width, grad, grad_mixed, grad_support, job)


@njit
def _shifted_sum_backward_serial(mixed, support, kernel_width, grad, grad_mixed, grad_support):  # type: ignore[no-untyped-def]
    for job in range(mixed.shape[0] * mixed.shape[1]):
        _shifted_sum_backward_tap(mixed, support, kernel_width, grad, grad_mixed, grad_support, job)
