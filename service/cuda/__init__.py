"""The GPU path (``device="cuda"``): the stages after the towers on an NVIDIA GPU through Numba CUDA.

The towers run where ONNX Runtime's providers put them (CUDA / TensorRT with ``onnxruntime-gpu``, the
``gpu`` extra; the CPU otherwise); the cost volume, shiftable windows, SGM, winner-takes-all, sub-pixel
fit, confidence, the right view's SGM, the inner check and the fill run on the GPU (service/cuda/
pipeline.py), each kernel the twin of its CPU kernel and tested equal to it (tests/service/cuda/). The
CPU path stays the default and never imports this package's kernels: importing ``numba.cuda`` costs a
one-off process time that a CPU user should not pay.
"""

from __future__ import annotations

import os

DEVICES = ("cpu", "cuda")
DEVICE_ENVIRONMENT = "ADSM_DEVICE"
DEVICE_HELP = ("where the stages after the towers run (default: $ADSM_DEVICE, else cpu; cuda: an NVIDIA GPU "
               "and the gpu extra, docs/gpu.md)")


class CudaUnavailableError(ValueError):
    """``device="cuda"`` was asked for where Numba finds no usable CUDA GPU (a ValueError: a setting this
    machine cannot honour, reported in one line like every bad setting)."""


def check_device(device: str | None) -> str:
    """The device a matcher runs on: ``device``, else ``$ADSM_DEVICE``, else ``"cpu"``; ValueError for a
    name other than ``DEVICES``."""
    chosen = device if device is not None else os.environ.get(DEVICE_ENVIRONMENT) or "cpu"
    if chosen not in DEVICES:
        source = "device" if device is not None else f"${DEVICE_ENVIRONMENT}"
        raise ValueError(f"{source} must be one of {', '.join(DEVICES)}, got {chosen!r}")
    return chosen


def require_cuda() -> None:
    """Raise :class:`CudaUnavailableError`, with Numba's reason, unless a CUDA GPU is usable."""
    from numba import cuda

    if not cuda.is_available():
        raise CudaUnavailableError(
            "device 'cuda' needs an NVIDIA GPU with its driver, and Numba's CUDA support "
            "(pip install 'adsm-stereo[gpu]'); none is usable here: run with device 'cpu'"
        )
