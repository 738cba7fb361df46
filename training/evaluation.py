"""Validation through the runtime: the PyTorch towers inside the same Matcher the service deploys.

:class:`TorchTowers` satisfies :class:`service.features.Towers`, the protocol the Matcher is written
against, so cost volume, SGM, sub-pixel fit, inner check and ray filling are the runtime's own code; only
the towers run in PyTorch. The trainer validates with :func:`runtime_metrics`; :func:`tune_sgm`
grids P1/P2 on the synthetic validation split (never on a real evaluation pair), running the towers once
per pair. The command line over both is ``python -m training.validate``.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np
import torch

from export.baseline import ncc_channels
from service.datasets import StereoSample
from service.evaluation.evaluate import evaluate
from service.evaluation.tuning import P1_GRID, P2_GRID, tune_penalties
from service.features import CachedTowers, Towers
from service.features.defaults import RUNTIME_DEFAULTS
from service.features.towers import FeatureTowers
from service.matcher import Matcher
from training.networks import TowerPair, dense_features
from training.networks.gate import NCCWindow, TextureGate, gated_features


class TorchTowers(Towers):
    """PyTorch towers as the Matcher's :class:`~service.features.Towers` (wrap them in
    :class:`~service.features.CachedTowers` to run a P1/P2 grid's network once per pair)."""

    def __init__(self, model: TowerPair, deploy: Mapping[str, Any] | None = None) -> None:
        deploy = RUNTIME_DEFAULTS.deploy(deploy)
        self.model = model
        self.manifest: dict[str, Any] = {
            "name": f"torch-{model.config.name}-{model.channels}", "channels": model.channels,
            "receptive_field": model.receptive_field, "input": deploy["input"],
            "cost": {"scale": float(deploy["cost_scale"])},
            "sgm": {"p1": float(deploy["p1"]), "p2": float(deploy["p2"])},
            "disparity": {"default_max": int(deploy["default_max"])},
        }
        self._mean = torch.tensor(deploy["input"]["mean"], dtype=torch.float32)[:, None, None]
        self._std = torch.tensor(deploy["input"]["std"], dtype=torch.float32)[:, None, None]

    def _features(self, tower: torch.nn.Module, image: np.ndarray) -> np.ndarray:
        tensor = torch.from_numpy(np.ascontiguousarray(image.transpose(2, 0, 1))).float().div_(255.0)
        tensor = (tensor - self._mean) / self._std
        device = next(tower.parameters()).device
        return dense_features(tower, tensor[None].to(device))[0].cpu().numpy()

    @torch.no_grad()
    def __call__(self, left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        was_training = self.model.training
        self.model.eval()
        try:
            return self._features(self.model.left, left), self._features(self.model.right, right)
        finally:
            self.model.train(was_training)

    def warmup(self) -> None:
        image = np.zeros((48, 48, 3), np.uint8)
        self(image, image)


class GatedTowers(Towers):
    """A folder's ONNX towers with the NCC window and the gate applied: the Matcher's towers in validation."""

    def __init__(self, learned: FeatureTowers, gate: TextureGate) -> None:
        self.learned, self.gate = learned, gate
        self.ncc = NCCWindow(gate.window)
        self.manifest: dict[str, Any] = dict(learned.manifest)
        self.manifest["channels"] = int(learned.manifest["channels"]) + ncc_channels(gate.window)
        self.manifest["receptive_field"] = max(int(learned.manifest["receptive_field"]), gate.window)

    def image(self, image: np.ndarray) -> torch.Tensor:
        """uint8 (H, W, 3) -> the graph's input [1, 3, H, W] (the folder's input normalisation)."""
        return torch.from_numpy(self.learned.input_batch(image))

    @torch.no_grad()
    def __call__(self, left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        learned = self.learned(left, right)
        return tuple(self.gated(torch.from_numpy(features)[None], self.image(image))[0].numpy()  # type: ignore[return-value]
                     for features, image in zip(learned, (left, right), strict=True))

    def gated(self, learned: torch.Tensor, image: torch.Tensor) -> torch.Tensor:
        ncc, energy = self.ncc(image)
        return gated_features(learned, ncc, self.gate(learned, ncc, energy))

    def warmup(self) -> None:
        self.learned.warmup()


def runtime_metrics(model: TowerPair, dataset: Sequence[StereoSample], *,
                    deploy: Mapping[str, Any] | None = None, max_disparity: int | None = None,
                    towers: TorchTowers | None = None) -> dict[str, Any]:
    """bad-1..5, D1, EPE, density over every ground-truth pixel (dense output: check + fill on)."""
    matcher = Matcher(towers or TorchTowers(model, deploy))
    report = evaluate(matcher, dataset, max_disparity=max_disparity)
    return {**report["all"], "pairs": report["pairs"], "seconds_per_pair": report["seconds_per_pair"]}


def tune_sgm(model: TowerPair, dataset: Sequence[StereoSample], *, deploy: Mapping[str, Any] | None = None,
             p1_grid: Sequence[float] = P1_GRID, p2_grid: Sequence[float] = P2_GRID,
             log: Callable[[str], Any] | None = None) -> tuple[dict[str, float], list[dict[str, Any]]]:
    """:func:`service.evaluation.tuning.tune_penalties` with the PyTorch towers, run once per pair."""
    towers = CachedTowers(TorchTowers(model, deploy), pairs=len(dataset))
    return tune_penalties(Matcher(towers), dataset, p1_grid=p1_grid, p2_grid=p2_grid, log=log)
