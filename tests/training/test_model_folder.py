"""A TowerPair rebuilt from an exported model folder: eval-exact, near in training mode, refused where
the folder holds no trainable towers, and usable as ``--init-from``."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from export.quantize import quantize_folder
from export.to_onnx import export_folder
from training.checkpoint import save_checkpoint
from training.model_folder import checkpoint_from_folder, load_start
from training.networks import TowerPair, build_tower_pair, dense_features
from training.trainer.warm_start import warm_start

pytestmark = pytest.mark.torch

PROVENANCE = {"command": "python -m training.train --iterations 5", "data": "synthetic", "wall_time_s": 2.0,
              "iterations": 5}


def _random_statistics(pair: TowerPair) -> TowerPair:
    """BN statistics and affine terms far from the identity, so that unfolding them is really tested."""
    generator = torch.Generator().manual_seed(0)
    with torch.no_grad():
        for module in pair.modules():
            if isinstance(module, torch.nn.BatchNorm2d):
                module.running_mean.normal_(0.0, 0.3, generator=generator)
                module.running_var.uniform_(0.5, 2.0, generator=generator)
                module.weight.uniform_(0.5, 1.5, generator=generator)
                module.bias.uniform_(-0.2, 0.2, generator=generator)
    return pair.eval()


def _folder(tmp_path: Path, config: str, *, shared: bool, standardize_window: int = 0,
            adaptive_support: bool = False) -> tuple[Path, object]:
    pair = _random_statistics(build_tower_pair(config, channels=5, shared=shared,
                                               standardize_window=standardize_window,
                                               adaptive_support=adaptive_support))
    if adaptive_support:
        with torch.no_grad():
            pair.left.support_log_gain.copy_(torch.tensor([1.0, 2.0, 3.0, 2.5, 0.5]))
    checkpoint = save_checkpoint(tmp_path / "model.pt", model=pair, step=5, training=PROVENANCE,
                                 deploy={"trained_range": [0, 96]})
    return export_folder(checkpoint, tmp_path / "folder", command="test").parent, pair


@pytest.mark.parametrize(
    ("config", "shared", "window", "adaptive"),
    [("13-1deconv3-4conv", True, 0, False), ("11-5conv", False, 0, False), ("11-5conv", True, 5, False),
     ("11-5conv", True, 0, True)],
)
def test_rebuilt_towers_compute_the_folders_features(tmp_path: Path, config: str, shared: bool,
                                                     window: int, adaptive: bool) -> None:
    folder, original = _folder(tmp_path, config, shared=shared, standardize_window=window,
                               adaptive_support=adaptive)
    checkpoint = checkpoint_from_folder(folder)
    assert checkpoint.spec["config"] == config and checkpoint.spec["shared"] == shared
    assert checkpoint.spec["standardize_window"] == window and checkpoint.spec["channels"] == 5
    assert checkpoint.spec["adaptive_support"] == adaptive
    rebuilt = checkpoint.build_model()
    image = torch.rand(1, 3, 23, 41)
    with torch.no_grad():
        for mine, theirs in ((rebuilt.left, original.left), (rebuilt.right, original.right)):
            torch.testing.assert_close(dense_features(mine, image), dense_features(theirs, image),
                                       atol=2e-5, rtol=1e-4)
    # The BN scales are the calibration's standard deviations, not the identity left by unfolding.
    scales = [m.weight for m in rebuilt.left.layers if isinstance(m, torch.nn.BatchNorm2d)]
    assert all(not torch.allclose(scale, torch.ones_like(scale)) for scale in scales)
    temperature = float(checkpoint.state_dict["log_temperature"].exp())
    assert 0.999 <= temperature <= 200.01  # the fit's grid, through float32
    assert checkpoint.training["model_folder"]["path"] == str(folder)
    assert checkpoint.training["command"] == PROVENANCE["command"]


def test_training_mode_starts_near_the_folders_features(tmp_path: Path) -> None:
    """BN in training mode normalises by the batch: the calibrated statistics keep that close to eval on
    images like the calibration crops (an uncalibrated unfolding, BN = identity + bias, gives a median
    cosine of 0.73 here)."""
    from training.model_folder import _calibration_crops

    folder, _ = _folder(tmp_path, "11-5conv", shared=True)
    model = checkpoint_from_folder(folder).build_model()
    left, _, _ = _calibration_crops()
    with torch.no_grad():
        evaluated = dense_features(model.left, left)
        model.train()
        trained = dense_features(model.left, left)
    cosine = (evaluated * trained).sum(dim=1)
    assert float(cosine.median()) > 0.999


def test_folders_without_trainable_towers_are_refused(tmp_path: Path) -> None:
    folder, _ = _folder(tmp_path, "11-5conv", shared=True)
    int8 = quantize_folder(folder, tmp_path / "int8", calibration="skimage:brick").parent
    with pytest.raises(ValueError, match="int8 folder; start from its fp32 twin"):
        checkpoint_from_folder(int8)
    manifest = json.loads((folder / "manifest.json").read_text())
    with (folder / "left.onnx").open("ab") as stream:
        stream.write(b"tampered")
    with pytest.raises(ValueError, match="does not match its manifest"):
        checkpoint_from_folder(folder)
    with pytest.raises(ValueError, match="does not exist"):
        checkpoint_from_folder(tmp_path / "nowhere")
    assert manifest["onnx"]["precision"] == "fp32"


def test_ncc_baseline_is_not_a_tower_folder() -> None:
    with pytest.raises(ValueError, match="not an ADSM tower folder"):
        checkpoint_from_folder(Path("service/models/ncc-baseline"))


def test_warm_start_from_a_folder_copies_its_weights(tmp_path: Path) -> None:
    folder, _ = _folder(tmp_path, "11-5conv", shared=True)
    model = build_tower_pair("11-5conv", channels=5, shared=True)
    warm_start(model, str(folder))
    expected = load_start(folder).state_dict
    for name, value in model.state_dict().items():
        assert torch.equal(value, expected[name]), name
    # A wider model takes the folder's weights in its first channels, as from a checkpoint.
    wider = build_tower_pair("11-5conv", channels=8, shared=True)
    warm_start(wider, str(folder))
    first = wider.left.layers[0].weight.detach()[:5]
    assert np.allclose(first.numpy(), expected["left.layers.0.weight"].numpy())
