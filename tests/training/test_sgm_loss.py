"""The loss after SGM (``--sgm-loss``): the runtime's aggregation, its gradient, and eq. (18) over it."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from service.optimization.sgm import aggregate
from tests.helpers import two_surface_crop
from training.losses import SHARP_LABEL, dense_candidates, matching_loss
from training.networks import dense_features
from training.sgm_loss import aggregated_losses, cost_volume, volume_disparities
from training.sgm_paths import sgm_paths
from training.train import main as train_main
from training.trainer.objective import Objective

pytestmark = pytest.mark.torch


def _reference_paths(cost: torch.Tensor, p1: float, p2: float) -> torch.Tensor:
    """Eq. (20) written with torch operations only, so that autograd differentiates it independently."""
    def scan(volume: torch.Tensor) -> torch.Tensor:
        previous, steps = volume[:, :, 0], [volume[:, :, 0]]
        for x in range(1, volume.shape[2]):
            low = previous.amin(-1, keepdim=True)
            far = torch.full_like(previous[..., :1], 1e9)
            neighbour = torch.minimum(torch.cat([far, previous[..., :-1]], -1),
                                      torch.cat([previous[..., 1:], far], -1))
            best = torch.minimum(torch.minimum(previous, neighbour + p1), low + p2)
            previous = volume[:, :, x] + best - low
            steps.append(previous)
        return torch.stack(steps, 2)

    horizontal = scan(cost) + scan(cost.flip(2)).flip(2)
    turned = cost.transpose(1, 2)
    vertical = (scan(turned) + scan(turned.flip(2)).flip(2)).transpose(1, 2)
    return horizontal + vertical


def test_the_paths_are_the_runtimes_sgm_exactly() -> None:
    costs = np.random.default_rng(0).integers(-128, 129, size=(2, 5, 7, 9)).astype(np.int16)
    ours = sgm_paths(torch.tensor(costs, dtype=torch.float32), p1=20.0, p2=360.0).numpy()
    runtime = np.stack([aggregate(volume, p1=20, p2=360) for volume in costs])
    assert np.array_equal(ours, runtime.astype(np.float32))


def test_the_gradient_follows_the_winning_paths_as_autograd_does() -> None:
    torch.manual_seed(0)
    cost = torch.randn(2, 4, 6, 8) * 50           # continuous costs: no ties between candidates
    upstream = torch.randn(2, 4, 6, 8)
    ours = cost.clone().requires_grad_()
    (sgm_paths(ours, p1=20.0, p2=90.0) * upstream).sum().backward()
    reference = cost.clone().requires_grad_()
    (_reference_paths(reference, 20.0, 90.0) * upstream).sum().backward()
    assert torch.allclose(ours.grad, reference.grad, atol=1e-4)
    assert float(ours.grad.abs().max()) > 1.0      # the gradient reaches beyond each cell's own cost


def test_the_paths_refuse_what_the_runtime_refuses() -> None:
    with pytest.raises(ValueError, match="0 <= P1 <= P2"):
        sgm_paths(torch.zeros(1, 2, 2, 3), p1=50.0, p2=20.0)
    with pytest.raises(ValueError, match=r"\[N, H, W, D\]"):
        sgm_paths(torch.zeros(2, 2, 3), p1=1.0, p2=2.0)


def test_the_cost_volume_is_the_runtimes_definition() -> None:
    torch.manual_seed(1)
    left = torch.nn.functional.normalize(torch.randn(1, 4, 3, 10), dim=1)
    right = torch.nn.functional.normalize(torch.randn(1, 4, 3, 10), dim=1)
    volume = cost_volume(left, right, disparities=6)
    assert volume.shape == (1, 3, 10, 6)
    assert float(volume[0, 2, 7, 3]) == pytest.approx(-128.0 * float(left[0, :, 2, 7] @ right[0, :, 2, 4]))
    assert bool((volume[0, :, 2, 3:] == 128.0).all())        # x - d < 0: outside the right image
    assert volume_disparities(96, 256) == 128 and volume_disparities(96, 100) == 100


def test_the_loss_is_eq_18_over_the_aggregated_costs_of_every_disparity() -> None:
    torch.manual_seed(2)
    left = torch.nn.functional.normalize(torch.randn(1, 8, 6, 40), dim=1)
    right = torch.nn.functional.normalize(torch.randn(1, 8, 6, 40), dim=1)
    pixels = torch.tensor([[0, 1, 5], [0, 2, 30], [0, 3, 0], [0, 5, 39]])
    truth, shift = torch.tensor([1, 19, 0, 10]), torch.tensor([0.3, -0.4, 0.5, -0.2])
    aggregated = sgm_paths(cost_volume(left, right, disparities=20), p1=20.0, p2=360.0)
    # The same loss through the strip of training.losses: candidate n is the disparity truth + 100 - n.
    candidate = truth[:, None] + torch.arange(100, -101, -1)[None, :]
    inside = (candidate >= 0) & (candidate < 20)
    rows = -aggregated[pixels[:, 0], pixels[:, 1], pixels[:, 2]] / (128.0 * 4)
    logits = 10.0 * rows.gather(1, candidate.clamp(0, 19))
    for label, label_shift in ((SHARP_LABEL, shift), ((0.05, 0.2, 0.5, 0.2, 0.05), None)):
        ours = aggregated_losses(left, right, pixels, truth, temperature=10.0, disparities=20,
                                 shift=label_shift, shape=label)
        expected = matching_loss(logits, inside, reduction="none", shift=label_shift, shape=label)
        assert torch.allclose(ours, expected, atol=1e-5)
    with pytest.raises(ValueError, match=r"must lie in 0\.\.19"):
        aggregated_losses(left, right, pixels, torch.tensor([1, 20, 0, 0]), temperature=10.0, disparities=20)


def test_the_objective_mixes_the_two_losses_by_the_share() -> None:
    model, left, right, disparity = two_surface_crop(3)
    with torch.no_grad():
        raw, count = Objective(model, mode="dense")(left, right, disparity)
        after, after_count = Objective(model, mode="dense", sgm_share=1.0, sgm_disparities=16)(
            left, right, disparity)
        half, _ = Objective(model, mode="dense", sgm_share=0.5, sgm_disparities=16)(left, right, disparity)
        features_left, features_right = dense_features(model.left, left), dense_features(model.right, right)
        temperature = model.log_temperature.exp()
        logits, inside, pixels, _ = dense_candidates(features_left, features_right, disparity,
                                                     temperature=temperature)
        truth = disparity[pixels[:, 0], pixels[:, 1], pixels[:, 2]].long()
        expected = aggregated_losses(features_left, features_right, pixels, truth, temperature=temperature,
                                     disparities=16).mean()
    assert count == after_count == pixels.shape[0]
    assert float(raw) == pytest.approx(float(matching_loss(logits, inside)), rel=1e-5)
    assert float(after) == pytest.approx(float(expected), rel=1e-5)
    assert float(half) == pytest.approx(0.5 * float(raw) + 0.5 * float(after), rel=1e-5)
    assert float(after) != pytest.approx(float(raw), rel=1e-2)
    with pytest.raises(ValueError, match=r"in 0\.\.1"):
        Objective(model, mode="dense", sgm_share=1.5)
    with pytest.raises(ValueError, match="dense cost volume"):
        Objective(model, mode="patch", sgm_share=0.5)


def test_the_trainer_trains_through_sgm_and_refuses_a_share_above_one(tmp_path, capsys) -> None:
    common = ["--config", "9-4conv", "--channels", "4", "--shared", "--iterations", "2", "--batch-size", "1",
              "--crop", "48", "96", "--max-disparity", "16", "--val-every", "2", "--val-pairs", "1",
              "--cones", ""]
    assert train_main([*common, "--sgm-loss", "2", "--out", str(tmp_path / "refused")]) == 1
    assert "share of the loss after SGM must be in 0..1" in capsys.readouterr().err
    assert train_main([*common, "--sgm-loss", "1", "--out", str(tmp_path / "run")]) == 0
    history = (tmp_path / "run" / "history.jsonl").read_text().splitlines()
    assert len(history) == 2 and all(np.isfinite(json.loads(line)["loss"]) for line in history)
