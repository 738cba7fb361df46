"""Adaptive support in the towers: the CPU kernel equals PyTorch's ops, gain 0 is the plain tower, dense
features equal the patch tower, support stops at colour edges, and unsuitable towers are refused."""

from __future__ import annotations

import pytest
import torch

from training.checkpoint import save_checkpoint
from training.networks import FeatureTower, build_tower_pair, dense_features, get_config
from training.networks.adaptive_support import adaptive_conv, stacked_adaptive_conv, support_weights
from training.networks.tower import same_padding
from training.trainer.warm_start import warm_start

pytestmark = pytest.mark.torch


@pytest.mark.parametrize("threads", [1, 2])  # the serial and the parallel kernels
def test_cpu_kernel_equals_the_stacked_ops_in_value_and_gradient(threads: int) -> None:
    before = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        _kernel_equals_the_stacked_ops()
    finally:
        torch.set_num_threads(before)


def _kernel_equals_the_stacked_ops() -> None:
    generator = torch.Generator().manual_seed(0)
    features = torch.rand(2, 5, 9, 12, generator=generator, requires_grad=True)
    weight = torch.randn(4, 5, 3, 3, generator=generator, requires_grad=True)
    support = torch.rand(2, 9, 7, 10, generator=generator, requires_grad=True)
    fast = adaptive_conv(features, weight, support)
    reference = stacked_adaptive_conv(features, weight, support)
    torch.testing.assert_close(fast, reference, atol=1e-5, rtol=1e-5)
    probe = torch.randn(fast.shape, generator=generator)
    for mine, theirs in zip(torch.autograd.grad((fast * probe).sum(), (features, weight, support)),
                            torch.autograd.grad((reference * probe).sum(), (features, weight, support)),
                            strict=True):
        torch.testing.assert_close(mine, theirs, atol=1e-5, rtol=1e-5)


def test_weights_sum_to_the_taps_and_are_flat_on_a_flat_image() -> None:
    image = torch.rand(1, 3, 8, 8, generator=torch.Generator().manual_seed(1))
    weights = support_weights(image, (3, 3), torch.tensor(10.0))
    torch.testing.assert_close(weights.sum(dim=1), torch.full((1, 6, 6), 9.0))
    flat = support_weights(torch.full((1, 3, 5, 5), 0.4), (3, 3), torch.tensor(10.0))
    torch.testing.assert_close(flat, torch.ones_like(flat))


def test_gain_zero_is_the_plain_tower_and_dense_features_equal_the_patch_tower() -> None:
    torch.manual_seed(0)
    adaptive = build_tower_pair("11-5conv", channels=6, adaptive_support=True).eval()
    plain = build_tower_pair("11-5conv", channels=6).eval()
    plain.load_state_dict({k: v for k, v in adaptive.state_dict().items() if "support" not in k})
    image = torch.rand(1, 3, 21, 30)
    with torch.no_grad():
        adaptive.left.support_log_gain.fill_(-40.0)
        torch.testing.assert_close(dense_features(adaptive.left, image), dense_features(plain.left, image),
                                   atol=1e-5, rtol=1e-5)
        adaptive.left.support_log_gain.fill_(3.0)
        dense = dense_features(adaptive.left, image)
        padded = torch.nn.functional.pad(image, same_padding((11, 11)), mode="replicate")
        for y, x in ((0, 0), (10, 17), (20, 29)):
            torch.testing.assert_close(adaptive.left(padded[:, :, y:y + 11, x:x + 11])[0, :, 0, 0],
                                       dense[0, :, y, x], atol=1e-5, rtol=1e-5)


def test_support_stops_at_a_colour_edge() -> None:
    """A pixel 3 px from a strong edge: the plain tower's feature follows the texture across it, the
    adaptive tower's (large gain) does not."""
    torch.manual_seed(0)
    adaptive = build_tower_pair("11-5conv", channels=8, adaptive_support=True).eval()
    with torch.no_grad():
        adaptive.left.support_log_gain.fill_(8.0)
    plain = build_tower_pair("11-5conv", channels=8).eval()
    plain.load_state_dict({k: v for k, v in adaptive.state_dict().items() if "support" not in k})
    image = torch.full((1, 3, 21, 40), 0.2)
    image[:, :, :, :20] += 0.05 * torch.rand(1, 3, 21, 20)
    textured, other = image.clone(), image.clone()
    textured[:, :, :, 20:] = 0.6 + 0.4 * torch.rand(1, 3, 21, 20)
    other[:, :, :, 20:] = 0.6 + 0.4 * torch.rand(1, 3, 21, 20)
    with torch.no_grad():
        changes = [float((dense_features(tower, textured) - dense_features(tower, other))[0, :, 10, 17]
                         .norm()) for tower in (plain.left, adaptive.left)]
    assert changes[0] > 0.05 and changes[1] < 1e-3, changes


@pytest.mark.parametrize(("config", "window"), [("13-1deconv3-4conv", 0), ("21x5-1deconv3-4conv", 0),
                                                ("11-5conv", 5)])
def test_towers_it_cannot_weigh_are_refused(config: str, window: int) -> None:
    with pytest.raises(ValueError, match="adaptive support needs a conv-only tower of odd kernels"):
        FeatureTower(get_config(config), channels=4, standardize_window=window, adaptive_support=True)


def test_warm_start_between_plain_and_adaptive_towers(tmp_path) -> None:
    plain = build_tower_pair("9-4conv", channels=4)
    adaptive = build_tower_pair("9-4conv", channels=4, adaptive_support=True)
    warm_start(adaptive, str(save_checkpoint(tmp_path / "plain.pt", model=plain, step=1)))
    torch.testing.assert_close(adaptive.left.layers[0].weight, plain.left.layers[0].weight)
    assert torch.all(adaptive.left.support_log_gain.exp() > 1)  # the initial gain, not 0
    with pytest.raises(ValueError, match="give --adaptive-support"):
        warm_start(plain, str(save_checkpoint(tmp_path / "adaptive.pt", model=adaptive, step=1)))
