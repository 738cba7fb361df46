"""The depth-edge weighted loss (``--edge-weight``): which pixels count more, and by how much."""

from __future__ import annotations

import math

import pytest
import torch

from tests.helpers import two_surface_crop
from training.losses import dense_candidates, depth_edge_weights, matching_loss
from training.networks import build_tower_pair, dense_features
from training.train import main as train_main
from training.trainer.objective import Objective

pytestmark = pytest.mark.torch


def _all_pixels(batch: int, height: int, width: int) -> torch.Tensor:
    b, y, x = torch.meshgrid(torch.arange(batch), torch.arange(height), torch.arange(width), indexing="ij")
    return torch.stack([b.flatten(), y.flatten(), x.flatten()], dim=1)


def test_pixels_within_the_radius_of_a_jump_weigh_more_and_the_rest_one() -> None:
    disparity = torch.full((1, 9, 20), 5.0)
    disparity[:, :, 10:] = 9.0                      # a 4 px jump between columns 9 and 10
    weights = depth_edge_weights(disparity, _all_pixels(1, 9, 20), weight=3.0, radius=2).view(9, 20)
    near = (weights == 4.0).nonzero()[:, 1].unique().tolist()
    assert near == [7, 8, 9, 10, 11, 12]             # columns 9 and 10 carry the jump, dilated by 2
    assert bool((weights[:, :7] == 1.0).all()) and bool((weights[:, 13:] == 1.0).all())


def test_a_slanted_surface_is_not_an_edge_but_an_occlusion_border_is() -> None:
    ramp = torch.arange(20, dtype=torch.float32).expand(1, 9, 20) * 1.5   # 1.5 px per column: no jump
    assert bool((depth_edge_weights(ramp, _all_pixels(1, 9, 20), weight=5.0) == 1.0).all())
    occluded = ramp.clone()
    occluded[:, :, 12:14] = math.nan                 # unlabelled: the pixels beside it are edges
    weights = depth_edge_weights(occluded, _all_pixels(1, 9, 20), weight=5.0, radius=1).view(9, 20)
    assert set((weights == 6.0).nonzero()[:, 1].unique().tolist()) == {10, 11, 12, 13, 14, 15}
    assert depth_edge_weights(occluded, _all_pixels(1, 9, 20), weight=0.0).eq(1.0).all()
    with pytest.raises(ValueError, match=">= 0"):
        depth_edge_weights(occluded, _all_pixels(1, 9, 20), weight=-1.0)


def test_the_far_region_is_the_background_a_nearer_surface_reaches() -> None:
    disparity = torch.full((1, 9, 30), 5.0)
    disparity[:, 3:6, 12:16] = 20.0                  # a nearer block: rows 3-5, columns 12-15
    disparity[:, :, 25] = math.nan                   # an unlabelled column far from it
    weights = depth_edge_weights(disparity, _all_pixels(1, 9, 30), weight=3.0, radius=2,
                                 region="far").view(9, 30)
    heavy = weights == 4.0
    expected = torch.zeros(9, 30, dtype=torch.bool)
    expected[1:8, 10:18] = True                      # the block dilated by the radius ...
    expected[3:6, 12:16] = False                     # ... less the block itself (the near side)
    assert bool((heavy == expected).all())
    assert bool((weights[~heavy] == 1.0).all())
    # Unlike "both", an unlabelled column is no edge here, and a step of JUMP_PX or less is no surface.
    assert bool((weights[:, 22:29] == 1.0).all())
    ramp = torch.arange(30, dtype=torch.float32).expand(1, 9, 30) * 0.5
    assert depth_edge_weights(ramp, _all_pixels(1, 9, 30), weight=3.0, radius=4, region="far").eq(1.0).all()
    with pytest.raises(ValueError, match="region must be one of"):
        depth_edge_weights(disparity, _all_pixels(1, 9, 30), weight=3.0, region="near")


def test_the_objective_reaches_as_far_as_the_towers_see() -> None:
    model = build_tower_pair("11-5conv", channels=4, shared=True)
    assert Objective(model, mode="dense", edge_weight=4.0).edge_radius == 3
    assert Objective(model, mode="dense", edge_weight=4.0, edge_region="far").edge_radius == 5
    with pytest.raises(ValueError, match="edge_region must be one of"):
        Objective(model, mode="dense", edge_weight=4.0, edge_region="near")


def test_the_objective_is_the_weighted_mean_of_eq_18() -> None:
    model, left, right, disparity = two_surface_crop(0)
    loss, count = Objective(model, mode="dense", edge_weight=2.0)(left, right, disparity)
    plain, plain_count = Objective(model, mode="dense")(left, right, disparity)
    loss, plain = loss.detach(), plain.detach()
    # Recompute by hand from the same candidates.
    with torch.no_grad():
        logits, inside, pixels, _ = dense_candidates(dense_features(model.left, left),
                                                     dense_features(model.right, right), disparity,
                                                     temperature=model.log_temperature.exp())
        losses = matching_loss(logits, inside, reduction="none")
        weights = depth_edge_weights(disparity, pixels, weight=2.0)
    assert count == plain_count == pixels.shape[0]
    assert float(loss) == pytest.approx(float((weights * losses).sum() / weights.sum()), rel=1e-5)
    assert float(plain) == pytest.approx(float(losses.mean()), rel=1e-5)
    assert float(loss) != pytest.approx(float(plain), rel=1e-3)   # the edge pixels' losses differ
    with pytest.raises(ValueError, match="dense ground truth"):
        Objective(model, mode="patch", edge_weight=1.0)


def test_the_objective_uses_the_label_it_is_given() -> None:
    from training.losses import SHARP_LABEL
    torch.manual_seed(0)
    model = build_tower_pair("9-4conv", channels=8, shared=True)
    left, right = torch.rand(1, 3, 24, 48), torch.rand(1, 3, 24, 48)
    disparity = torch.full((1, 24, 48), 3.3)
    with torch.no_grad():
        sharp, _ = Objective(model, mode="dense", label="sharp", edge_weight=2.0)(left, right, disparity)
        logits, inside, pixels, shift = dense_candidates(dense_features(model.left, left),
                                                         dense_features(model.right, right), disparity,
                                                         temperature=model.log_temperature.exp())
        losses = matching_loss(logits, inside, shift=shift, shape=SHARP_LABEL, reduction="none")
        weights = depth_edge_weights(disparity, pixels, weight=2.0)
    assert float(sharp) == pytest.approx(float((weights * losses).sum() / weights.sum()), rel=1e-5)
    for label in ("subpixel", "sharp"):
        with pytest.raises(ValueError, match="fractional truth"):
            Objective(model, mode="patch", label=label)
    with pytest.raises(ValueError, match="label must be one of"):
        Objective(model, mode="dense", label="onehot")


def test_the_trainer_takes_the_weight_and_refuses_a_negative_one(tmp_path, capsys) -> None:
    assert train_main(["--config", "9-4conv", "--channels", "4", "--shared", "--iterations", "1",
                       "--batch-size", "1", "--crop", "48", "96", "--max-disparity", "16", "--val-every", "1",
                       "--val-pairs", "1", "--cones", "", "--edge-weight", "-1", "--out", str(tmp_path)]) == 1
    assert "depth-edge weight must be >= 0" in capsys.readouterr().err
    assert train_main(["--config", "9-4conv", "--channels", "4", "--shared", "--iterations", "1",
                       "--batch-size", "1", "--crop", "48", "96", "--max-disparity", "16", "--val-every", "1",
                       "--val-pairs", "1", "--cones", "", "--edge-region", "far",
                       "--out", str(tmp_path / "far")]) == 2
    assert "give a weight > 0" in capsys.readouterr().err and not (tmp_path / "far").exists()


def _chunk_command_lines(tmp_path, **env: str) -> list:
    import shlex
    import subprocess

    from tests.helpers import ROOT
    from training.train import build_parser

    env = {"PATH": "/usr/bin:/bin", "OUT": str(tmp_path), "DRY_RUN": "1", **env}
    printed = subprocess.run(["bash", str(ROOT / "training" / "edge_weight_chunk.sh")], check=True,
                             capture_output=True, text=True, cwd=ROOT, env=env).stdout
    return [build_parser().parse_args(shlex.split(line)[3:]) for line in printed.splitlines()]


def test_the_prepared_gpu_chunk_runs_the_wider_3x3_17px_tower_alone_and_plans_name_others(tmp_path):
    """training/edge_weight_chunk.sh (issue 11's GPU list): by default the 17-px field of eight 3x3 convs
    with 48 channels at edge weight 4 alone, one camera draw per scene, the 14000 steps of adsm-fast's
    tower's 32-channel arm (the twenty-fourth session's run), resumed from its own folder; PLAN names other
    runs (adsm-fast's tower and the 11-px tower at 48 channels; the twenty-third session's call: the weight
    against its control, the same seed, steps and schedule) and their channels (32 unless a run says cN)."""
    from training.train import argument_problem

    (alone,) = _chunk_command_lines(tmp_path, WORKERS="15")
    assert (alone.config, alone.channels, alone.edge_weight, alone.out) == (
        "17-8conv", 48, 4.0, ".gpu/c48/k17dc48-w4")
    assert alone.camera_draws == 1
    (wide,) = _chunk_command_lines(tmp_path, PLAN="k17c48-w4")
    assert (wide.config, wide.channels, wide.out) == ("13-1deconv3-4conv", 48, ".gpu/c48/k17c48-w4")
    (narrow,) = _chunk_command_lines(tmp_path, PLAN="k11c48-w4")
    assert (narrow.config, narrow.channels, narrow.iterations, narrow.out) == (
        "11-5conv", 48, 14000, ".gpu/c48/k11c48-w4")
    pair = _chunk_command_lines(tmp_path, PLAN="k17-w4 k17-w0", ITERATIONS="5000", RUNS=".gpu/runs",
                                WORKERS="7")
    assert [(args.config, args.channels, args.edge_weight) for args in pair] == [
        ("13-1deconv3-4conv", 32, 4.0), ("13-1deconv3-4conv", 32, 0.0)]
    for args, iterations, workers in [(alone, 14000, 15), *((args, 5000, 7) for args in pair)]:
        assert argument_problem(args) is None
        assert (args.device, args.resume, args.schedule, args.seed, args.iterations, args.workers) == (
            "cuda", "auto", "cosine", 0, iterations, workers)
        assert args.time_budget == 420
    assert [args.out for args in pair] == [".gpu/runs/k17-w4", ".gpu/runs/k17-w0"]
    four = _chunk_command_lines(tmp_path, PLAN="k11-w4 k11c16-w0 k17c64-w4 k17-w0", ITERATIONS="9000",
                                DRAWS="4")
    assert [(args.config, args.channels, args.edge_weight, args.iterations) for args in four] == [
        ("11-5conv", 32, 4.0, 9000), ("11-5conv", 16, 0.0, 9000), ("13-1deconv3-4conv", 64, 4.0, 9000),
        ("13-1deconv3-4conv", 32, 0.0, 9000)]
    assert all(args.camera_draws == 4 for args in four)
    deep = _chunk_command_lines(tmp_path, PLAN="k17dc48-w4 k21d-w4")
    assert [(args.config, args.channels, args.edge_weight) for args in deep] == [
        ("17-8conv", 48, 4.0), ("21-10conv", 32, 4.0)]
    (control,) = _chunk_command_lines(tmp_path, PLAN="k11-w4", RUNS=".gpu/long")
    assert (control.channels, control.camera_draws, control.iterations, control.out) == (
        32, 1, 14000, ".gpu/long/k11-w4")
    assert argument_problem(control) is None  # the A/B's other arm, as it ran


def test_the_prepared_gpu_chunk_refuses_a_plan_it_cannot_read(tmp_path):
    import subprocess

    from tests.helpers import ROOT

    unreadable = [("k17-w4 k13-w0", "k13-w0"), ("k11c0-w4", "k11c0-w4"), ("k11c-w4", "k11c-w4"),
                  ("k11c48w4", "k11c48w4"), ("k11d-w4", "k11d-w4")]
    for plan, name in unreadable:
        refused = subprocess.run(["bash", str(ROOT / "training" / "edge_weight_chunk.sh")],
                                 capture_output=True, text=True, cwd=ROOT,
                                 env={"PATH": "/usr/bin:/bin", "OUT": str(tmp_path), "DRY_RUN": "1",
                                      "PLAN": plan})
        assert refused.returncode == 2 and f"'{name}' is not TOWER[cCHANNELS]-wWEIGHT" in refused.stderr
