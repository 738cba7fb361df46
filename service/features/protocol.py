"""Towers: what the Matcher needs of feature towers, whichever runtime computes the features.

:class:`~service.features.FeatureTowers` (ONNX Runtime, the product) satisfies it, and so does the
trainer's ``training.evaluation.TorchTowers`` (PyTorch, validation through the runtime's own Matcher):
the Matcher is written against this protocol, not against either class.
"""

from __future__ import annotations

from typing import Any, Protocol, runtime_checkable

import numpy as np


@runtime_checkable
class Towers(Protocol):
    """Left and right feature towers of one model.

    ``manifest`` holds at least the keys the runtime reads (docs/architecture.md, "Manifest"):
    ``name``, ``channels``, ``receptive_field``, ``input``, ``cost.scale``, ``sgm.p1``, ``sgm.p2`` and
    ``disparity.default_max``.
    """

    manifest: dict[str, Any]

    def __call__(self, left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Features of both views of a uint8 (H, W, 3) pair: two float32 (C, H, W) arrays, unit L2 norm
        over C, the same H and W (padding is the towers' own business)."""
        ...

    def warmup(self) -> None:
        """Make the first real call fast (sessions initialised, kernels loaded); may check the towers
        against the manifest and raise :class:`~service.features.ModelError`."""
        ...
