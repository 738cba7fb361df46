"""Eq. (18) from the right view too (``--both-views``): which matches the right view sees, and that the
mirrored banded loss is the right pixel's cross-entropy over its left row."""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F

from tests.helpers import two_surface_crop
from training.losses import (
    HALF_RANGE,
    LABELS,
    labelled_pixels,
    matching_loss,
    pixel_losses,
    right_view_examples,
    soft_label,
)
from training.networks import dense_features
from training.train import main as train_main
from training.trainer.objective import Objective

pytestmark = pytest.mark.torch


def _seen_columns(disparity: torch.Tensor) -> set[int]:
    pixels, truth, shift = labelled_pixels(disparity)
    _, _, _, chosen = right_view_examples(pixels, truth, shift, size=tuple(disparity.shape))
    return {int(x) for x in pixels[chosen, 2]}


def test_a_nearer_square_hides_the_background_left_of_it_in_the_right_view() -> None:
    # Background at disparity 2, a fronto-parallel surface at 8 over columns 20..29: its right-view
    # footprint (columns 12..21) covers the matches of background columns 14..23, which are hidden.
    disparity = torch.full((1, 1, 40), 2.0)
    disparity[..., 20:30] = 8.0
    assert _seen_columns(disparity) == set(range(2, 14)) | set(range(20, 30)) | set(range(30, 40))


def test_a_column_a_stretched_nearer_surface_skips_is_not_the_hidden_backgrounds() -> None:
    # The nearer surface's truth steps from 8 to 7 at column 22: its matches 12, 13, 15, 16, 17 skip 14,
    # which the background column 16 (disparity 2, hidden behind it) would claim.
    disparity = torch.full((1, 1, 40), 2.0)
    disparity[0, 0, 20:25] = torch.tensor([8.0, 8.0, 7.0, 7.0, 7.0])
    seen = _seen_columns(disparity)
    assert 16 not in seen and set(range(20, 25)) <= seen and {2, 13, 30} <= seen


@pytest.mark.parametrize("label", sorted(LABELS))
def test_the_mirrored_loss_is_the_right_pixels_cross_entropy_over_the_left_row(label) -> None:
    generator = torch.Generator().manual_seed(7)
    features_left = F.normalize(torch.randn(2, 6, 4, 40, generator=generator), dim=1)
    features_right = F.normalize(torch.randn(2, 6, 4, 40, generator=generator), dim=1)
    disparity = torch.rand(2, 4, 40, generator=generator) * 12
    disparity[0, 2, 10:20] += 9.0    # nearer surfaces hide some background
    pixels, truth, shift = labelled_pixels(disparity)
    mirrored, right_truth, right_shift, chosen = right_view_examples(pixels, truth, shift,
                                                                      size=tuple(disparity.shape))
    assert 0 < chosen.numel() < pixels.shape[0]
    shape, fractional = LABELS[label]
    temperature = 5.0
    losses = pixel_losses(features_right.flip(3), features_left.flip(3), mirrored, right_truth,
                          temperature=temperature, shift=right_shift if fractional else None, shape=shape,
                          half_range=HALF_RANGE)
    # By hand: right pixel u = x - t against left columns x + H - n (candidate n: disparity t + H - n, the
    # left view's strip order), the label on the truth moved by the same round(d) - d.
    b, y, x = pixels[chosen].unbind(1)
    u = x - right_truth
    columns = x[:, None] + HALF_RANGE - torch.arange(2 * HALF_RANGE + 1)[None, :]
    inside = (columns >= 0) & (columns < disparity.shape[2])
    left_rows = features_left[b, :, y].transpose(1, 2)                       # [N, W, C]
    candidates = left_rows.gather(1, columns.clamp(0, 39)[..., None].expand(-1, -1, 6))
    logits = temperature * (candidates * features_right[b, :, y, u][:, None, :]).sum(-1)
    expected = matching_loss(logits, inside, shift=right_shift if fractional else None, shape=shape,
                             reduction="none")
    torch.testing.assert_close(losses, expected, rtol=1e-5, atol=1e-5)
    assert soft_label(shape=shape).sum() == pytest.approx(1.0)


def test_the_objective_averages_the_two_views_and_refuses_what_it_cannot_take() -> None:
    model, left, right, disparity = two_surface_crop(0)
    with torch.no_grad():
        left_only, count = Objective(model, mode="dense")(left, right, disparity)
        both, both_count = Objective(model, mode="dense", both_views=True)(left, right, disparity)
        # The right view alone: the left view's loss over the mirrored, swapped features with the right
        # view's truth (background 0..21 of the right image, the nearer surface 22..47; the left columns
        # 25..29 it hides have no right pixel).
        right_truth = torch.full((1, 24, 48), 3.0)
        right_truth[:, :, 22:] = 8.0
        pixels, truth, _ = labelled_pixels(right_truth.flip(2))
        features_left, features_right = dense_features(model.left, left), dense_features(model.right, right)
        mirrored = pixel_losses(features_right.flip(3), features_left.flip(3), pixels, truth,
                                temperature=model.log_temperature.exp()).mean()
        weighted, _ = Objective(model, mode="dense", edge_weight=2.0, both_views=True)(left, right, disparity)
    assert both_count == count
    assert float(both) == pytest.approx(0.5 * (float(left_only) + float(mirrored)), rel=1e-5)
    assert float(mirrored) != pytest.approx(float(left_only), rel=1e-3)
    assert float(weighted) != pytest.approx(float(both), rel=1e-3)
    for kwargs, message in (({"mode": "patch"}, "dense crops"), ({"mode": "dense", "sgm_share": 0.5},
                                                                  "raw costs")):
        with pytest.raises(ValueError, match=message):
            Objective(model, both_views=True, **kwargs)


def test_the_trainer_takes_both_views_and_records_them(tmp_path) -> None:
    from training.checkpoint import load_checkpoint
    assert train_main(["--config", "9-4conv", "--channels", "4", "--shared", "--iterations", "2",
                       "--batch-size", "1", "--crop", "48", "96", "--max-disparity", "16", "--val-every", "2",
                       "--val-pairs", "1", "--cones", "", "--both-views", "--out", str(tmp_path)]) == 0
    checkpoint = load_checkpoint(tmp_path / "last.pt")
    assert checkpoint.config["both_views"] is True and "--both-views" in checkpoint.config["command"]
