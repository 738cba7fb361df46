"""Matching loss (eq. 18, 19), patch pairs and dense crops; patch and dense modes agree pixel by pixel."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from tests.helpers import require_module
from training.data.samples import patch_pairs, random_crop, random_patch_pairs, usable_pixels
from training.data.synthetic import SyntheticConfig, generate
from training.losses import (
    LABELS,
    dense_candidates,
    dense_matching_loss,
    labelled_pixels,
    matching_loss,
    pixel_candidates,
    pixel_losses,
    soft_label,
)

pytestmark = pytest.mark.torch


@pytest.fixture(scope="module")
def pair():
    return generate(5, SyntheticConfig(height=40, width=72, max_disparity=20))


class TinyTower(torch.nn.Module):
    """Valid 3x3 convs (5x5 receptive field) ending in L2 normalisation, like the zoo's towers."""

    patch = 5

    def __init__(self, seed: int):
        super().__init__()
        torch.manual_seed(seed)
        self.layers = torch.nn.Sequential(torch.nn.Conv2d(3, 8, 3), torch.nn.ReLU(), torch.nn.Conv2d(8, 6, 3))

    def forward(self, image: torch.Tensor) -> torch.Tensor:
        return F.normalize(self.layers(image), dim=1)


def test_soft_label_is_eq_19():
    label = soft_label(candidates=201)
    assert label[100] == 0.5 and label[99] == label[101] == pytest.approx(0.2)
    assert label[98] == label[102] == pytest.approx(0.05)
    assert float(label.sum()) == pytest.approx(1.0) and int((label > 0).sum()) == 5
    with pytest.raises(ValueError):
        soft_label(candidates=4)


def test_matching_loss_is_cross_entropy_with_the_soft_label():
    logits = torch.randn(3, 201, generator=torch.Generator().manual_seed(0))
    expected = -(soft_label() * torch.log_softmax(logits, dim=1)).sum(dim=1)
    torch.testing.assert_close(matching_loss(logits, reduction="none"), expected)
    assert float(matching_loss(torch.zeros(2, 201))) == pytest.approx(math.log(201), rel=1e-6)
    # The minimum is the label's own entropy, reached when the softmax equals the label.
    label = soft_label()
    best = torch.where(label > 0, torch.log(label.clamp_min(1e-30)), torch.tensor(-60.0))[None]
    entropy = float(-(label[label > 0] * label[label > 0].log()).sum())
    assert float(matching_loss(best)) == pytest.approx(entropy, rel=1e-5)
    noise = 0.3 * torch.randn(1, 201, generator=torch.Generator().manual_seed(4))
    assert float(matching_loss(best + noise)) > entropy


def test_candidates_outside_the_image_are_excluded_and_the_label_renormalised():
    logits = torch.randn(2, 11, generator=torch.Generator().manual_seed(1), requires_grad=True)
    inside = torch.ones(2, 11, dtype=torch.bool)
    inside[0, :4] = False                        # left edge: candidates 0..3 (one labelled 0.05) cut off
    loss = matching_loss(logits, inside, reduction="none")
    kept = logits[0, 4:]
    label = soft_label(candidates=11)[4:] / soft_label(candidates=11)[4:].sum()
    torch.testing.assert_close(loss[0], -(label * torch.log_softmax(kept, dim=0)).sum())
    loss.sum().backward()
    assert torch.isfinite(logits.grad).all() and (logits.grad[0, :4] == 0).all()
    inside[1, 5] = False                         # the truth itself outside: a sampling bug, refused
    with pytest.raises(ValueError, match="true match"):
        matching_loss(logits, inside)


@pytest.mark.parametrize("half_range", [3, 100])
def test_patch_and_dense_modes_give_the_same_loss_and_gradient(pair, half_range):
    tower = TinyTower(seed=2)
    temperature = torch.tensor(7.0)
    left = torch.from_numpy(pair.left).permute(2, 0, 1)[None].float() / 255
    right = torch.from_numpy(pair.right).permute(2, 0, 1)[None].float() / 255
    pad = (2, 2, 2, 2)  # (P - 1) / 2 replicate padding, as training.networks.dense_features
    features_left = tower(F.pad(left, pad, mode="replicate"))
    features_right = tower(F.pad(right, pad, mode="replicate"))
    truth = torch.from_numpy(pair.disparity)[None]
    logits, inside, where, _ = dense_candidates(features_left, features_right, truth, temperature=temperature,
                                             half_range=half_range)
    assert where.shape[0] == int(usable_pixels(pair).sum())
    chosen = torch.from_numpy(np.random.default_rng(0).choice(where.shape[0], 40, replace=False))
    dense = matching_loss(logits[chosen], inside[chosen], reduction="none")

    patches = patch_pairs(pair, where[chosen, 1:].numpy(), patch=tower.patch, half_range=half_range)
    assert patches.left.shape == (40, 3, 5, 5) and patches.right.shape == (40, 3, 5, 5 + 2 * half_range)
    patch_logits = temperature * (tower(patches.left) * tower(patches.right)).sum(dim=1)[:, 0, :]
    patch = matching_loss(patch_logits, patches.inside, reduction="none")

    torch.testing.assert_close(patches.inside, inside[chosen])
    torch.testing.assert_close(patch, dense, rtol=1e-5, atol=1e-5)
    dense_gradient = torch.autograd.grad(dense.mean(), list(tower.parameters()))
    patch_gradient = torch.autograd.grad(patch.mean(), list(tower.parameters()))
    for a, b in zip(dense_gradient, patch_gradient, strict=True):
        torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-6)


def test_patch_and_dense_modes_agree_for_a_conv_tower_of_the_zoo(pair):
    networks = require_module("training.networks")
    towers = networks.build_tower_pair("29-3conv", channels=8).eval()
    truth = torch.from_numpy(pair.disparity)[None]
    images = [torch.from_numpy(v).permute(2, 0, 1)[None].float() / 255 for v in (pair.left, pair.right)]
    with torch.no_grad():
        features = [networks.dense_features(t, i) for t, i in zip((towers.left, towers.right), images,
                                                                   strict=True)]
        temperature = towers.log_temperature.exp()
        logits, inside, where, _ = dense_candidates(*features, truth, temperature=temperature)
        chosen = where[:: max(1, where.shape[0] // 12)]
        patches = patch_pairs(pair, chosen[:, 1:].numpy(), patch=towers.patch)
        patch = matching_loss(towers(patches.left, patches.right), patches.inside, reduction="none")
    dense = matching_loss(logits[:: max(1, where.shape[0] // 12)], inside[:: max(1, where.shape[0] // 12)],
                          reduction="none")
    torch.testing.assert_close(patch, dense, rtol=1e-4, atol=1e-4)


def test_dense_loss_uses_only_pixels_with_truth_and_a_match_in_the_crop():
    features = F.normalize(torch.randn(1, 4, 3, 8, generator=torch.Generator().manual_seed(3)), dim=1)
    truth = torch.tensor([[[0.4, 1.6, 2.5, float("nan"), 7.0, 9.0, 2.0, 3.0]] * 3])
    _, inside, where, _ = dense_candidates(features, features, truth, temperature=1.0, half_range=2)
    # x=0: d 0.4 -> 0 (match 0) ok; x=1: 1.6 -> 2 (match -1) out; x=2: 2.5 -> 3 (half up, match -1) out;
    # x=3 unknown; x=4: d 7 -> match -3 out; x=5: 9 -> out; x=6: 2 -> 4 ok; x=7: 3 -> 4 ok.
    assert sorted(set(where[:, 2].tolist())) == [0, 6, 7] and where.shape[0] == 9
    assert inside.shape == (9, 5)
    loss = dense_matching_loss(features, features, truth, temperature=5.0)
    assert torch.isfinite(loss)
    with pytest.raises(ValueError, match="no pixel"):
        dense_matching_loss(features, features, torch.full_like(truth, float("nan")), temperature=1.0)


def test_random_samples_are_in_range_and_respect_occlusion(pair):
    rng = np.random.default_rng(0)
    patches = random_patch_pairs(pair, rng, count=16, nonoccluded_only=True)
    assert patches.left.shape == (16, 3, 37, 37) and patches.right.shape == (16, 3, 37, 237)
    assert float(patches.left.min()) >= 0 and float(patches.right.max()) <= 1
    ys, xs = patches.pixels[:, 0].numpy(), patches.pixels[:, 1].numpy()
    assert pair.nonoccluded[ys, xs].all()
    assert bool(patches.inside[:, 100].all())
    crop = random_crop(pair, rng, height=32, width=48, nonoccluded_only=True)
    assert crop.left.shape == crop.right.shape == (3, 32, 48) and crop.disparity.shape == (32, 48)
    assert torch.isnan(crop.disparity).any()  # occluded pixels removed from the truth
    with pytest.raises(ValueError, match="larger"):
        random_crop(pair, rng, height=64, width=48)
    with pytest.raises(ValueError, match="ground truth"):
        patch_pairs(pair, np.array([[0, 0]]), patch=5)  # x = 0: its match is outside the right image


def test_subpixel_label_keeps_its_mass_and_moves_its_centroid_by_the_shift():
    from training.losses import shifted_label
    label = soft_label(candidates=11).expand(4, 11)
    shift = torch.tensor([0.0, 0.3, -0.45, 1.0])
    moved = shifted_label(label, shift)
    positions = torch.arange(11, dtype=torch.float32)
    torch.testing.assert_close(moved.sum(dim=1), torch.ones(4))
    torch.testing.assert_close((moved * positions).sum(dim=1), 5.0 + shift)
    torch.testing.assert_close(moved[0], label[0])


def test_sharp_label_is_the_two_tap_interpolation_of_the_fractional_truth():
    from training.losses import LABELS, SHARP_LABEL
    logits = torch.randn(3, 11, generator=torch.Generator().manual_seed(3))
    shift = torch.tensor([0.0, 0.3, -0.25])
    expected_label = torch.zeros(3, 11)
    expected_label[0, 5] = 1.0
    expected_label[1, 5], expected_label[1, 6] = 0.7, 0.3
    expected_label[2, 5], expected_label[2, 4] = 0.75, 0.25
    expected = -(expected_label * torch.log_softmax(logits, dim=1)).sum(dim=1)
    torch.testing.assert_close(matching_loss(logits, shift=shift, shape=SHARP_LABEL, reduction="none"),
                               expected)
    # Unlike eq. (19), similarity one or two pixels off earns nothing: a peak on the truth alone wins.
    peak = torch.full((1, 11), -30.0)
    peak[0, 5] = 0.0
    broad = torch.log(soft_label(candidates=11).clamp_min(1e-13))[None]
    sharp = SHARP_LABEL
    assert float(matching_loss(peak, shape=sharp)) < float(matching_loss(broad, shape=sharp))
    assert float(matching_loss(peak)) > float(matching_loss(broad))
    assert LABELS["sharp"] == (SHARP_LABEL, True) and LABELS["paper"][1] is False
    with pytest.raises(ValueError, match="sum to 1"):
        soft_label(candidates=11, shape=(0.0, 0.0, 0.5, 0.0, 0.0))


def test_dense_shift_points_at_the_fractional_truth():
    features = F.normalize(torch.randn(1, 4, 3, 16), dim=1)
    truth = torch.full((1, 3, 16), 3.25)
    *_, shift = dense_candidates(features, features, truth, temperature=1.0, half_range=4)
    # Candidate index grows as disparity falls: a truth 0.25 px above its rounded value sits 0.25 before it.
    torch.testing.assert_close(shift, torch.full_like(shift, -0.25))


@pytest.mark.parametrize("label", sorted(LABELS))
@pytest.mark.parametrize("half_range", [3, 6, 100])
def test_the_banded_loss_equals_the_candidates_loss_and_its_gradients(label, half_range):
    """pixel_losses (the trainer's dense loss) is matching_loss over pixel_candidates, to float rounding:
    every label, near the crop's edges (candidates cut off), the sub-pixel shift and the temperature's
    gradient included."""
    generator = torch.Generator().manual_seed(4)
    features_left = F.normalize(torch.randn(2, 6, 5, 30, generator=generator), dim=1).requires_grad_()
    features_right = F.normalize(torch.randn(2, 6, 5, 30, generator=generator), dim=1).requires_grad_()
    truth = torch.rand(2, 5, 30, generator=generator) * 24
    truth[0, 1, :7] = float("nan")
    temperature = torch.tensor(6.0, requires_grad=True)
    pixels, rounded, shift = labelled_pixels(truth)
    shape, fractional = LABELS[label]
    shift = shift if fractional else None
    logits, inside = pixel_candidates(features_left, features_right, pixels, rounded, temperature=temperature,
                                      half_range=half_range)
    assert not bool(inside.all())  # some candidates fall outside the crop
    expected = matching_loss(logits, inside, shift=shift, shape=shape, reduction="none")
    banded = pixel_losses(features_left, features_right, pixels, rounded, temperature=temperature,
                          shift=shift, shape=shape, half_range=half_range)
    torch.testing.assert_close(banded, expected, rtol=1e-5, atol=1e-5)
    weights = torch.rand(expected.shape[0], generator=generator)
    inputs = [features_left, features_right, temperature]
    for a, b in zip(torch.autograd.grad((weights * banded).sum(), inputs),
                    torch.autograd.grad((weights * expected).sum(), inputs), strict=True):
        torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-6)


def test_the_banded_loss_refuses_a_band_narrower_than_its_label():
    features = F.normalize(torch.randn(1, 4, 2, 10, generator=torch.Generator().manual_seed(5)), dim=1)
    pixels, truth, _ = labelled_pixels(torch.full((1, 2, 10), 1.0))
    with pytest.raises(ValueError, match="half_range 2"):
        pixel_losses(features, features, pixels, truth, temperature=1.0, half_range=2)
