"""A trainable :class:`TowerPair` rebuilt from a shipped fp32 model folder, so training can start from it.

``python -m training.train --init-from service/models/adsm-rf11 ...`` fine-tunes a shipped model (on the
synthetic data or on a user's own KITTI copy) without the checkpoint it was exported from, which the
folder does not ship. The folder's ONNX towers hold the deploy-time network: each BN folded into the conv
before it, deconvs rewritten as convs (:func:`export.to_onnx.fold_tower`). Unfolding puts each weight back
in its conv (a deconv's flipped and transposed back) and picks each BN so that

- in eval mode the rebuilt tower computes exactly the folder's features (tested against ONNX Runtime),
- in training mode it starts close to them: BN then normalises by the batch's statistics, so its running
  statistics are those of the conv's outputs on a few synthetic training crops (seeds below the
  validation split's), its scale their standard deviation and its shift the folded bias plus their mean.

The learned softmax temperature is not part of the ONNX graph; it is fitted again on the same crops (the
lowest matching loss over a log grid), so the first steps do not spend themselves rescaling the logits.

>>> checkpoint = checkpoint_from_folder(Path(__file__).parents[1] / "service" / "models" / "adsm-rf11")
>>> checkpoint.spec["config"], checkpoint.spec["channels"], checkpoint.training["model_folder"]["name"]
('11-5conv', 32, 'adsm-rf11')
"""

from __future__ import annotations

import functools
import math
from pathlib import Path
from typing import Any

import numpy as np
import onnx
import torch
from onnx import numpy_helper
from torch import nn

from export.folder import read_graph
from service.features.manifest import ModelError, load_manifest, verify_files
from training.checkpoint import Checkpoint, load_checkpoint
from training.data.samples import random_crop
from training.data.synthetic import SyntheticConfig, generate
from training.losses import dense_candidates, matching_loss
from training.networks import FeatureTower, TowerPair, build_tower_pair, dense_features

# Crops that set the BN statistics and the temperature: the trainer's own crop size and disparity range,
# generator seeds far below the validation split's (which starts at 1e9).
CALIBRATION_SEEDS = (7_000, 7_001, 7_002, 7_003)
CALIBRATION_CROP = (128, 256)
TEMPERATURE_GRID = tuple(float(t) for t in np.geomspace(1.0, 200.0, 41))
TEMPERATURE_PIXELS = 8192
# What the trainer feeds the towers: RGB in [0, 1], no mean or scale (a folder expecting other input
# would be fine-tuned on inputs it was never given).
TRAINER_INPUT = {"color": "rgb", "range": [0.0, 1.0], "mean": [0.0, 0.0, 0.0], "std": [1.0, 1.0, 1.0]}


def load_start(path: str | Path) -> Checkpoint:
    """The weights a training run starts from: a checkpoint file, or a model folder (fp32 ONNX towers).

    A folder is rebuilt once per process (seconds of calibration): the warm start and the provenance of
    every checkpoint the run saves read the same one. Callers copy what they keep.
    """
    return _folder_checkpoint(str(path)) if Path(path).is_dir() else load_checkpoint(path)


@functools.lru_cache(maxsize=2)
def _folder_checkpoint(folder: str) -> Checkpoint:
    return checkpoint_from_folder(folder)


def checkpoint_from_folder(folder: str | Path) -> Checkpoint:
    """A :class:`Checkpoint` (eval-exact weights, calibrated BN, fitted temperature) of a model folder.

    Raises ``ValueError`` for a folder that holds no trainable ADSM towers: an int8 folder (its weights
    are quantised: start from the fp32 twin), an NCC baseline or hybrid, or files that fail the
    manifest's sha256.
    """
    folder = Path(folder)
    try:
        manifest = load_manifest(folder)
        verify_files(folder, manifest)
    except ModelError as error:
        raise ValueError(str(error)) from None
    name = manifest.get("name", folder.name)
    if manifest["onnx"].get("precision") != "fp32":
        raise ValueError(f"{folder}: {name} is a {manifest['onnx'].get('precision')} folder; start from its "
                         "fp32 twin (quantised weights are not the trained ones)")
    if {key: manifest["input"].get(key) for key in TRAINER_INPUT} != TRAINER_INPUT:
        raise ValueError(f"{folder}: input normalisation {manifest['input']} is not the trainer's "
                         f"{TRAINER_INPUT}")
    left_graph = read_graph(folder / "left.onnx")
    window = _standardize_window(left_graph)
    adaptive = any(name.startswith("support") for name in _initializers(left_graph))
    try:
        model = build_tower_pair(manifest["config"], channels=int(manifest["channels"]),
                                 shared=bool(manifest["shared_towers"]), standardize_window=window,
                                 adaptive_support=adaptive)
    except (KeyError, ValueError) as error:
        raise ValueError(f"{folder}: {name} is not an ADSM tower folder ({error})") from None
    _unfold(model.left, left_graph, folder / "left.onnx")
    if not model.shared:
        _unfold(model.right, read_graph(folder / "right.onnx"), folder / "right.onnx")
    left, right, disparity = _calibration_crops()
    model.eval()
    with torch.no_grad():
        views = [(model.left, torch.cat([left, right]))] if model.shared else [(model.left, left),
                                                                               (model.right, right)]
        for tower, images in views:
            _calibrate_batch_norms(tower, images)
        model.log_temperature.copy_(torch.tensor(math.log(_fit_temperature(model, left, right, disparity))))
    training = dict(manifest.get("training") or {})
    digests = {file: entry["sha256"] for file, entry in manifest["files"].items()}
    training["model_folder"] = {"name": name, "path": str(folder), "sha256": digests}
    return Checkpoint(spec=model.spec(), state_dict={k: v.clone() for k, v in model.state_dict().items()},
                      step=int(training.get("iterations", 0)), metrics=dict(manifest.get("metrics") or {}),
                      training=training, config={}, deploy={})


def _initializers(graph: onnx.ModelProto) -> dict[str, np.ndarray]:
    return {tensor.name: numpy_helper.to_array(tensor) for tensor in graph.graph.initializer}


def _standardize_window(graph: onnx.ModelProto) -> int:
    """The in-graph standardisation window (export.to_onnx's ``std_mean`` pool), 0 without one."""
    for node in graph.graph.node:
        if node.name == "std_mean":
            return int(onnx.helper.get_attribute_value(
                next(a for a in node.attribute if a.name == "kernel_shape"))[0])
    return 0


def _unfold(tower: FeatureTower, graph: onnx.ModelProto, path: Path) -> None:
    """Folded weights back into the tower; each BN the identity plus the folded bias (for now)."""
    weights = _initializers(graph)
    modules = list(tower.layers)
    convs = [i for i, m in enumerate(modules) if isinstance(m, nn.Conv2d | nn.ConvTranspose2d)]
    if sum(1 for key in weights if key.startswith("w") and key[1:].isdigit()) != len(convs):
        raise ValueError(f"{path}: the graph's convs do not match the {tower.config.name} tower "
                         "(not an export.to_onnx graph?)")
    for index, position in enumerate(convs):
        conv = modules[position]
        weight = torch.from_numpy(weights[f"w{index}"].astype(np.float32))
        if isinstance(conv, nn.ConvTranspose2d):  # export: transpose(0, 1).flip(2, 3); undo it
            weight = weight.flip(2, 3).transpose(0, 1)
        gain = weights.get(f"support{index}_neg_gain")
        if gain is not None:  # adaptive support: the taps stacked for a 1 x 1 conv; unstack them
            out_channels, (kh, kw) = conv.weight.shape[0], conv.kernel_size
            if weight.numel() != conv.weight.numel():
                raise ValueError(f"{path}: w{index} {tuple(weight.shape)} does not fit the "
                                 f"{tower.config.name} tower's {tuple(conv.weight.shape)} (other channels?)")
            weight = weight.reshape(out_channels, kh, kw, -1).permute(0, 3, 1, 2)
            tower.support_log_gain.data[index] = math.log(-float(gain[0]))
        if tuple(weight.shape) != tuple(conv.weight.shape):
            raise ValueError(f"{path}: w{index} {tuple(weight.shape)} does not fit the {tower.config.name} "
                             f"tower's {tuple(conv.weight.shape)} (other channels?)")
        conv.weight.data.copy_(weight)
        following = modules[position + 1] if position + 1 < len(modules) else None
        bias = weights.get(f"b{index}")
        if isinstance(following, nn.BatchNorm2d):
            if bias is None:
                raise ValueError(f"{path}: conv {index} has no folded bias but its BN does")
            following.weight.data.fill_(1.0)
            following.bias.data.copy_(torch.from_numpy(bias.astype(np.float32)))
            following.running_mean.zero_()
            following.running_var.fill_(1.0 - following.eps)   # sqrt(var + eps) = 1: BN = x + bias
        elif bias is not None:
            raise ValueError(f"{path}: conv {index} has a bias the {tower.config.name} tower cannot hold")


@functools.lru_cache(maxsize=1)
def _calibration_crops() -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    # Deterministic (fixed seeds), and read-only for every caller: generated once per process.
    height, width = CALIBRATION_CROP
    config = SyntheticConfig(height=height * 2, width=width * 2, max_disparity=96)
    crops = [random_crop(generate(seed, config), np.random.default_rng(seed), height=height, width=width,
                         nonoccluded_only=True) for seed in CALIBRATION_SEEDS]
    return (torch.stack([c.left for c in crops]), torch.stack([c.right for c in crops]),
            torch.stack([c.disparity for c in crops]))


def _calibrate_batch_norms(tower: FeatureTower, images: torch.Tensor) -> None:
    """Eval-exact re-parametrisation of every BN (input x, folded bias b): statistics (m, v) of x on
    ``images``; running (m, v), scale sqrt(v + eps), shift b + m, so eval mode still gives x + b."""
    statistics: dict[nn.BatchNorm2d, tuple[torch.Tensor, torch.Tensor]] = {}

    def record(module: nn.Module, inputs: tuple[torch.Tensor, ...], _: Any) -> None:
        x = inputs[0].double()
        statistics[module] = (x.mean(dim=(0, 2, 3)), x.var(dim=(0, 2, 3), unbiased=False))

    norms = [m for m in tower.layers if isinstance(m, nn.BatchNorm2d)]
    hooks = [norm.register_forward_hook(record) for norm in norms]
    try:
        dense_features(tower, images)
    finally:
        for hook in hooks:
            hook.remove()
    for norm in norms:
        mean, variance = statistics[norm]
        norm.running_mean.copy_(mean.float())
        norm.running_var.copy_(variance.float())
        norm.weight.data.copy_(torch.sqrt(variance + norm.eps).float())
        norm.bias.data.add_(mean.float())


def _fit_temperature(model: TowerPair, left: torch.Tensor, right: torch.Tensor,
                     disparity: torch.Tensor) -> float:
    """The grid temperature with the lowest matching loss (eq. 18, the paper's label) on the crops."""
    features_left = dense_features(model.left, left)
    features_right = dense_features(model.right, right)
    logits, inside, _, _ = dense_candidates(features_left, features_right, disparity, temperature=1.0)
    every = max(1, logits.shape[0] // TEMPERATURE_PIXELS)   # the loss is a mean: a sample of pixels fits it
    logits, inside = logits[::every], inside[::every]
    losses = [float(matching_loss(logits * t, inside)) for t in TEMPERATURE_GRID]
    return TEMPERATURE_GRID[int(np.argmin(losses))]
