"""The sub-pixel vertex term (``--subpixel-loss``): the runtime's quadratic fit at the true match against
the fractional truth, per pixel, on top of eq. (18)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from tests.helpers import two_surface_crop
from training.losses import labelled_pixels, pixel_losses, vertex_errors
from training.train import main as train_main
from training.trainer.objective import Objective

pytestmark = pytest.mark.torch


def _parabola_scores(vertex: float, rounded: int) -> torch.Tensor:
    """Similarities at disparities rounded + 1, rounded, rounded - 1 of a cost (d - vertex)^2 + 3."""
    return torch.tensor([[-((rounded + o - vertex) ** 2 + 3.0) for o in (1, 0, -1)]], dtype=torch.float64)


@pytest.mark.parametrize("vertex", [10.3, 9.6, 10.0, 10.45])
def test_the_vertex_of_an_exact_parabola_is_the_fractional_truth(vertex) -> None:
    rounded = int(np.floor(vertex + 0.5))
    scores = _parabola_scores(vertex, rounded)
    error = vertex_errors(scores, torch.tensor([rounded - vertex], dtype=torch.float64))
    assert float(error) == pytest.approx(0.0, abs=1e-9)
    # The same vertex read against a truth 0.2 px larger is 0.2 px short.
    error = vertex_errors(scores, torch.tensor([rounded - vertex - 0.2], dtype=torch.float64))
    assert float(error) == pytest.approx(-0.2, abs=1e-9)


def test_the_fit_is_the_runtimes_clamp_and_rule_included() -> None:
    from service.refinement.subpixel import refine_subpixel

    generator = np.random.default_rng(3)
    costs = generator.integers(0, 2000, size=(1, 64, 9)).astype(np.int16)
    winners = np.full((1, 64), 4)
    refined = refine_subpixel(costs, winners)[0]
    scores = -torch.from_numpy(costs[0, :, [5, 4, 3]].T.astype(np.float64))    # disparities 5, 4, 3
    # Against a truth of exactly 4 (shift 0) the error is the runtime's offset: clamped to +-0.5, and 0
    # where the parabola does not open upwards.
    errors = vertex_errors(scores, torch.zeros(64, dtype=torch.float64)).numpy()
    np.testing.assert_allclose(4 + errors, refined, atol=1e-5)
    assert (errors == 0).any() and (np.abs(errors) == 0.5).any()


def test_the_weight_adds_its_multiple_of_the_absolute_error_per_pixel() -> None:
    generator = torch.Generator().manual_seed(5)
    features_left = F.normalize(torch.randn(2, 6, 4, 40, generator=generator), dim=1)
    features_right = F.normalize(torch.randn(2, 6, 4, 40, generator=generator), dim=1)
    disparity = torch.rand(2, 4, 40, generator=generator) * 12
    pixels, truth, shift = labelled_pixels(disparity)
    plain = pixel_losses(features_left, features_right, pixels, truth, temperature=5.0)
    weighted = pixel_losses(features_left, features_right, pixels, truth, temperature=5.0, vertex_weight=2.0,
                            fractional_shift=shift)
    # By hand: the similarities at the three columns around each true match.
    b, y, x = pixels.unbind(1)
    columns = (x - truth)[:, None] + torch.arange(-1, 2)[None, :]
    fitted = (columns[:, 0] >= 0) & (columns[:, 2] < 40)
    rows = torch.einsum("nc,ncw->nw", features_left[b, :, y, x] * 5.0, features_right[b, :, y])
    scores = rows.gather(1, columns.clamp(0, 39))
    expected = plain + 2.0 * vertex_errors(scores, shift).abs() * fitted
    torch.testing.assert_close(weighted, expected, rtol=1e-5, atol=1e-5)
    assert bool((weighted > plain).any()) and bool((~fitted).any())
    with pytest.raises(ValueError, match="fractional shift"):
        pixel_losses(features_left, features_right, pixels, truth, temperature=5.0, vertex_weight=1.0)


def test_the_objective_trains_the_vertex_and_refuses_what_it_cannot_take() -> None:
    model, left, right, disparity = two_surface_crop(1)
    plain, count = Objective(model, mode="dense")(left, right, disparity)
    loss, vertex_count = Objective(model, mode="dense", vertex_weight=1.0)(left, right, disparity)
    assert vertex_count == count and float(loss.detach()) > float(plain.detach())
    loss.backward()
    assert all(p.grad is not None and bool(torch.isfinite(p.grad).all()) for p in model.parameters())
    for kwargs in ({"mode": "patch"}, {"mode": "dense", "sgm_share": 1.0},
                   {"mode": "dense", "vertex_weight": -1}, {"mode": "dense", "vertex_weight": float("nan")}):
        with pytest.raises(ValueError, match="vertex weight"):
            Objective(model, **{"vertex_weight": 1.0, **kwargs})


def test_the_trainer_takes_the_subpixel_loss_and_records_it(tmp_path) -> None:
    from training.checkpoint import load_checkpoint
    assert train_main(["--config", "9-4conv", "--channels", "4", "--shared", "--iterations", "2",
                       "--batch-size", "1", "--crop", "48", "96", "--max-disparity", "16", "--val-every", "2",
                       "--val-pairs", "1", "--cones", "", "--subpixel-loss", "0.5",
                       "--out", str(tmp_path)]) == 0
    checkpoint = load_checkpoint(tmp_path / "last.pt")
    assert checkpoint.config["subpixel_loss"] == 0.5 and "--subpixel-loss" in checkpoint.config["command"]
