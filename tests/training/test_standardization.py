"""In-graph input standardisation: the formula, gain/bias invariance, the receptive field, warm start."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from training.checkpoint import load_checkpoint, save_checkpoint
from training.networks import FeatureTower, build_tower_pair, dense_features, get_config
from training.networks.standardization import STANDARDIZATION_EPS, LocalStandardization
from training.train import main
from training.trainer.warm_start import warm_start

pytestmark = pytest.mark.torch


def _reference(image: np.ndarray, window: int, eps: float) -> np.ndarray:
    """The standardisation written out pixel by pixel over an edge-padded float64 image [C, H, W]."""
    r = window // 2
    padded = np.pad(image.astype(np.float64), ((0, 0), (r, r), (r, r)), mode="edge")
    out = np.empty_like(image, dtype=np.float64)
    for y in range(image.shape[1]):
        for x in range(image.shape[2]):
            patch = padded[:, y:y + window, x:x + window].reshape(image.shape[0], -1)
            out[:, y, x] = (image[:, y, x] - patch.mean(1)) / np.sqrt(patch.var(1) + eps * eps)
    return out


def test_standardization_is_the_windowed_formula_and_keeps_the_image() -> None:
    image = torch.rand(1, 3, 9, 13, generator=torch.Generator().manual_seed(0))
    out = LocalStandardization(5)(image)
    assert out.shape == (1, 6, 9, 13)
    torch.testing.assert_close(out[:, :3], image)
    expected = _reference(image[0].numpy(), 5, STANDARDIZATION_EPS)
    np.testing.assert_allclose(out[0, 3:].numpy(), expected, atol=2e-4)


def test_gain_and_bias_per_channel_leave_the_standardized_channels_unchanged() -> None:
    image = torch.rand(1, 3, 24, 32, generator=torch.Generator().manual_seed(1))
    gain = torch.tensor([0.8, 1.0, 1.2]).view(1, 3, 1, 1)
    bias = torch.tensor([0.05, -0.03, 0.0]).view(1, 3, 1, 1)
    exact = LocalStandardization(7, eps=1e-6)
    torch.testing.assert_close(exact(gain * image + bias)[:, 3:], exact(image)[:, 3:], atol=1e-3, rtol=1e-3)
    # With the default floor a flat window is not blown up: its noise stays below about 1.
    flat = 0.5 + 0.01 * torch.randn(1, 3, 24, 32, generator=torch.Generator().manual_seed(2))
    assert LocalStandardization(7)(flat)[:, 3:].abs().mean() < 0.6


def test_receptive_field_grows_by_the_window() -> None:
    torch.manual_seed(0)
    tower = FeatureTower(get_config("9-4conv"), channels=3, standardize_window=5).eval()
    assert tower.receptive_field == 9 + 4
    reach = tower.receptive_field // 2
    image = torch.rand(1, 3, 41, 41)
    with torch.no_grad():
        base = dense_features(tower, image)[0, :, 20, 20]
        for distance, changes in ((reach, True), (reach + 1, False)):
            moved = image.clone()
            moved[0, :, 20, 20 + distance] = 1 - moved[0, :, 20, 20 + distance]
            difference = (dense_features(tower, moved)[0, :, 20, 20] - base).abs().max()
            assert (difference > 1e-6) == changes, distance


def test_bad_windows_are_refused(capsys: pytest.CaptureFixture[str]) -> None:
    for window in (1, 4):
        with pytest.raises(ValueError, match="odd"):
            LocalStandardization(window)
    assert main(["--standardize-window", "4", "--iterations", "1"]) == 2
    assert "--standardize-window" in capsys.readouterr().err


def test_checkpoint_records_the_window_and_raw_checkpoints_warm_start_it(tmp_path) -> None:
    torch.manual_seed(0)
    raw = build_tower_pair("9-4conv", channels=4, shared=True)
    for module in raw.modules():             # non-trivial BN statistics, as after training
        if isinstance(module, torch.nn.BatchNorm2d):
            module.running_mean.uniform_(-0.1, 0.1)
            module.running_var.uniform_(0.5, 2.0)
    raw_path = save_checkpoint(tmp_path / "raw.pt", model=raw, step=1)
    standardized = build_tower_pair("9-4conv", channels=4, shared=True, standardize_window=7)
    warm_start(standardized, str(raw_path), generator=torch.Generator().manual_seed(0))
    image = torch.rand(1, 3, 30, 40)
    with torch.no_grad():
        before = dense_features(raw.eval().left, image)
        after = dense_features(standardized.eval().left, image)
    # The raw image's channels carry the old weights, the standardised ones start at 1 % of their spread
    # (a 4-channel unit vector amplifies that where its norm is small, hence a mean, not a maximum).
    first = standardized.left.layers[0].weight.detach()
    torch.testing.assert_close(first[:, :3], raw.left.layers[0].weight.detach())
    assert float(first[:, 3:].std()) < 0.02 * float(first[:, :3].std())
    assert float((before - after).abs().mean()) < 0.02
    path = save_checkpoint(tmp_path / "std.pt", model=standardized, step=2)
    rebuilt = load_checkpoint(path).build_model()
    assert rebuilt.spec()["standardize_window"] == 7 and rebuilt.receptive_field == 15
    with torch.no_grad():
        torch.testing.assert_close(dense_features(rebuilt.left, image), after)
    with pytest.raises(ValueError, match="standardisation window 7"):
        warm_start(build_tower_pair("9-4conv", channels=4, shared=True, standardize_window=5), str(path))
