"""The runtime settings a model folder's manifest carries when training and export chose none.

One frozen record, so the exporter (``export/to_onnx.py``), the NCC baseline (``export/baseline.py``),
validation through the runtime (``training/evaluation.py``) and a checkpoint's ``deploy`` settings
(``training.checkpoint.Checkpoint.deploy_settings``) agree on every value. The manifest keys they fill are
in ``manifest.schema.json``; the meaning of the cost scale and the penalties is in docs/architecture.md.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any


@dataclasses.dataclass(frozen=True, kw_only=True)
class RuntimeDefaults:
    """Manifest settings by default: ``cost.scale``, ``sgm.p1``, ``sgm.p2``, ``disparity.default_max``,
    ``input``."""

    cost_scale: float = 128.0     # features' cosine 1 -> cost -128, stored as int16
    p1: float = 30.0              # the paper's SGM penalties, meaningful at that scale
    p2: float = 160.0
    default_max: int = 128        # the range size D a call searches when it names none
    # The towers' input: uint8 RGB scaled to `value_range`, then (x - mean) / std per channel.
    color: str = "rgb"
    value_range: tuple[float, float] = (0.0, 1.0)
    mean: tuple[float, float, float] = (0.0, 0.0, 0.0)
    std: tuple[float, float, float] = (1.0, 1.0, 1.0)

    def input(self) -> dict[str, Any]:
        """The manifest's ``input`` object."""
        return {"color": self.color, "range": list(self.value_range), "mean": list(self.mean),
                "std": list(self.std)}

    def deploy(self, chosen: Mapping[str, Any] | None = None) -> dict[str, Any]:
        """Deployment settings in a checkpoint's ``deploy`` keys, ``chosen`` ones over these defaults."""
        return {"cost_scale": self.cost_scale, "p1": self.p1, "p2": self.p2, "default_max": self.default_max,
                "input": self.input(), **(chosen or {})}


RUNTIME_DEFAULTS = RuntimeDefaults()
