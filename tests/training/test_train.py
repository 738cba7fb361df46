"""Trainer: schedule, deterministic batches, a few real iterations, exact resume, validation via runtime."""

from __future__ import annotations

import dataclasses
import itertools
import json
import re

import numpy as np
import pytest
import torch

from service.datasets import open_dataset
from tests.helpers import ROOT
from training.checkpoint import load_checkpoint
from training.data.evaluation_only import CONES_FOLDER as CONES
from training.data.synthetic import PHOTO_SHARE
from training.evaluation import TorchTowers, tune_sgm
from training.networks import build_tower_pair
from training.schedule import FLOOR_FRACTION, learning_rate
from training.train import build_parser, main, recorded_command
from training.trainer import BatchSpec, TrainConfig, TrainingData, train
from training.trainer.objective import Objective

pytestmark = pytest.mark.torch

# The evaluation-only real pair, beside the checkout as in CI.

TINY = dict(channels=4, crop=(48, 96), max_disparity=24, batch_size=2, val_pairs=1, cones="", threads=1)


def history(out) -> list[dict]:
    return [json.loads(line) for line in (out / "history.jsonl").read_text().splitlines()]


def test_schedule_warms_up_then_decays_to_the_floor():
    rates = [learning_rate(s, peak=1e-3, iterations=200, schedule="cosine") for s in range(200)]
    assert rates[0] < rates[3] == pytest.approx(1e-3, rel=1e-6)      # 4 warm-up steps (2 %)
    assert all(a >= b for a, b in itertools.pairwise(rates[4:]))
    assert rates[-1] == pytest.approx(FLOOR_FRACTION * 1e-3, rel=1e-3)
    assert learning_rate(150, peak=1e-3, iterations=200, schedule="constant") == 1e-3
    with pytest.raises(ValueError, match="schedule"):
        learning_rate(0, peak=1e-3, iterations=10, schedule="steps")
    with pytest.raises(ValueError):
        learning_rate(0, peak=0.0, iterations=10)


def test_batches_are_a_function_of_seed_and_index():
    spec = BatchSpec(height=48, width=96, max_disparity=24, augmentation="photometric")
    data = TrainingData("synthetic", seed=3, spec=spec)
    left, right, disparity = data.crops([5, 6])
    again = TrainingData("synthetic", seed=3, spec=spec).crops([5, 6])
    assert torch.equal(left, again[0]) and torch.equal(right, again[1])
    assert torch.equal(torch.nan_to_num(disparity, -1.0), torch.nan_to_num(again[2], -1.0))
    assert left.shape == (2, 3, 48, 96) and disparity.shape == (2, 48, 96)
    assert not torch.equal(left[0], left[1])
    assert float(left.min()) >= 0.0 and float(left.max()) <= 1.0
    assert float(np.nanmax(disparity.numpy())) <= 24.0
    other_seed = TrainingData("synthetic", seed=4, spec=spec).crops([5])[0]
    assert not torch.equal(other_seed[0], left[0])
    plain = TrainingData("synthetic", seed=3, spec=dataclasses.replace(spec, augmentation="none"))
    assert not torch.equal(plain.crops([5])[0][0], left[0])   # the augmentation changes the views


def test_patch_batches_follow_the_paper_geometry():
    data = TrainingData("synthetic", seed=0, spec=BatchSpec(height=64, width=128, max_disparity=24,
                                                            patches_per_pair=3))
    pairs = data.patches([0, 1])
    assert pairs.left.shape == (6, 3, 37, 37) and pairs.right.shape == (6, 3, 37, 237)
    assert pairs.inside.shape == (6, 201) and bool(pairs.inside[:, 100].all())


def test_evaluation_pair_is_refused_as_training_data():
    with pytest.raises(ValueError, match="evaluation"):
        TrainingData(f"cones:{CONES}", seed=0, spec=BatchSpec())
    with pytest.raises(ValueError, match="seed"):
        TrainingData("synthetic", seed=100, spec=BatchSpec())


def test_a_few_dense_iterations_learn_and_write_checkpoints(tmp_path, monkeypatch):
    # Every step trains on the same batch (examples 0 and 1), so a falling loss is descent, not the luck
    # of easier crops. Measured (lr 3e-3): 10.85 6.31 4.66 4.55 4.52 4.50 4.48 4.46 4.44 4.41, falling
    # at every step; on changing batches the same run logged 10.85 5.78 5.00 4.74 4.59 4.57.
    data = TrainingData("synthetic", seed=0, spec=BatchSpec(height=48, width=96, max_disparity=24))
    fixed = data.crops([0, 1])
    monkeypatch.setattr(TrainingData, "crops", lambda self, indices: fixed)
    out = tmp_path / "run"
    summary = train(TrainConfig(**TINY, iterations=10, val_every=10, lr=3e-3, out=str(out)))
    assert summary["steps"] == 10
    losses = [row["loss"] for row in history(out)]
    assert len(losses) == 10 and all(np.isfinite(losses))
    assert all(later < earlier for earlier, later in itertools.pairwise(losses)), losses
    assert losses[-1] < 0.5 * losses[0], losses
    best = load_checkpoint(out / "best.pt")
    last = load_checkpoint(out / "last.pt")
    assert last.step == 10 and last.training["iterations"] == 10 and "finished" in last.training
    assert last.deploy["trained_range"] == [0, 24]
    assert set(best.metrics["synthetic-validation"]) >= {"bad2", "bad3", "bad4", "bad5", "epe"}
    assert last.optimizer is not None and last.rng is not None


def test_resume_reproduces_the_loss_curve(tmp_path):
    config = TrainConfig(**TINY, iterations=4, val_every=2)
    train(dataclasses.replace(config, out=str(tmp_path / "straight")))
    halfway = dataclasses.replace(config, out=str(tmp_path / "resumed"))
    # The same 4-step schedule interrupted after 2 steps, then resumed from its last checkpoint.
    train(dataclasses.replace(halfway, stop_after=2))
    assert [r["step"] for r in history(tmp_path / "resumed")] == [1, 2]
    train(halfway, resume=str(tmp_path / "resumed" / "last.pt"))
    straight, resumed = history(tmp_path / "straight"), history(tmp_path / "resumed")
    assert [r["loss"] for r in resumed] == [r["loss"] for r in straight]
    assert [r["lr"] for r in resumed] == [r["lr"] for r in straight]
    a = load_checkpoint(tmp_path / "straight" / "last.pt").state_dict
    b = load_checkpoint(tmp_path / "resumed" / "last.pt").state_dict
    # Not bit-equal: two straight runs in one process already differ in the last bits (oneDNN picks
    # kernels by alignment), and Adam turns a rounding-level gradient on a near-flat weight into a step
    # of up to lr. The bound is one such step per iteration; the loss curve, compared exactly above, is
    # what catches a lost or repeated step.
    for name in a:
        step_bound = config.lr * config.iterations
        torch.testing.assert_close(a[name].float(), b[name].float(), rtol=0, atol=step_bound)


def test_worker_processes_give_the_loss_curve_of_inline_batches(tmp_path):
    # Batches are a pure function of the step, so building them in other processes changes nothing.
    config = TrainConfig(**TINY, iterations=3, val_every=3)
    train(dataclasses.replace(config, out=str(tmp_path / "inline")))
    train(dataclasses.replace(config, out=str(tmp_path / "workers"), workers=2))
    inline, workers = history(tmp_path / "inline"), history(tmp_path / "workers")
    assert [r["loss"] for r in workers] == [r["loss"] for r in inline]


def test_time_budget_checkpoints_and_resume_auto_continues(tmp_path):
    out = tmp_path / "chunks"
    argv = ["--channels", "4", "--crop", "48", "96", "--max-disparity", "24", "--batch-size", "2",
            "--val-pairs", "1", "--cones", "", "--threads", "1", "--iterations", "3", "--val-every", "3",
            "--out", str(out), "--resume", "auto"]
    assert main([*argv, "--time-budget", "0"]) == 0      # spent at once: one step, validated, saved
    first = load_checkpoint(out / "last.pt")
    assert first.step == 1 and "finished" not in first.training and first.optimizer is not None
    assert main(argv) == 0                                 # the same command picks up where it stopped
    last = load_checkpoint(out / "last.pt")
    assert last.step == 3 and "finished" in last.training
    assert [r["step"] for r in history(out)] == [1, 2, 3]


def test_cuda_device_is_refused_clearly_without_a_gpu(tmp_path, monkeypatch):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)  # also on a machine with a GPU
    with pytest.raises(ValueError, match="no CUDA device"):
        train(TrainConfig(**TINY, iterations=1, out=str(tmp_path / "gpu"), device="cuda"))


def test_patch_mode_iterations(tmp_path):
    out = tmp_path / "patch"
    train(TrainConfig(**{**TINY, "batch_size": 8}, mode="patch", iterations=2, val_every=2, out=str(out)))
    rows = history(out)
    assert [r["examples"] for r in rows] == [8, 8] and all(np.isfinite(r["loss"]) for r in rows)


def test_patch_mode_cuts_the_configs_own_patch_size(tmp_path):
    # A 29-px tower fed 37-px patches would output 9x9 instead of 1x1 and the loss would fail.
    out = tmp_path / "patch29"
    config = TrainConfig(**{**TINY, "batch_size": 4}, config="29-4conv", mode="patch", iterations=1,
                         val_every=1, out=str(out))
    train(config)
    assert len(history(out)) == 1


def test_dense_and_patch_objectives_agree_on_the_same_pixel():
    # A conv-only tower: with a deconv, an isolated patch feeds it zeros where a crop gives real pixels.
    torch.manual_seed(0)
    model = build_tower_pair("37-4conv", channels=4).eval()
    data = TrainingData("synthetic", seed=0, spec=BatchSpec(height=48, width=240, max_disparity=16,
                                                            augmentation="none"))
    sample, _ = data.sample(0)
    from training.data.samples import patch_pairs
    from training.losses import dense_candidates, matching_loss
    from training.networks import dense_features

    ys, xs = np.nonzero(np.isfinite(sample.disparity) & (np.arange(240) >= 130)[None, :])
    pixel = np.array([[ys[0], xs[0]]])
    pairs = patch_pairs(sample, pixel)
    with torch.no_grad():
        patch_loss, _ = Objective(model, mode="patch")(pairs.left, pairs.right, pairs.inside)
        left, right = (torch.from_numpy(v.transpose(2, 0, 1)).float()[None] / 255 for v in (sample.left,
                                                                                          sample.right))
        logits, inside, where, _ = dense_candidates(dense_features(model.left, left),
                                                 dense_features(model.right, right),
                                                 torch.from_numpy(sample.disparity)[None],
                                                 temperature=model.log_temperature.exp())
        row = int(((where[:, 1] == int(pixel[0, 0])) & (where[:, 2] == int(pixel[0, 1]))).nonzero()[0, 0])
        dense_loss = matching_loss(logits[row:row + 1], inside[row:row + 1])
    assert float(patch_loss) == pytest.approx(float(dense_loss), rel=1e-4, abs=1e-5)


def test_validation_runs_the_runtime_and_tunes_on_synthetic_only():
    torch.manual_seed(0)
    model = build_tower_pair("37-1deconv5-4conv", channels=4)
    towers = TorchTowers(model)
    image = np.random.default_rng(0).integers(0, 256, (50, 60, 3), dtype=np.uint8)
    left, _ = towers(image, image)
    assert left.shape == (4, 50, 60) and left.dtype == np.float32
    np.testing.assert_allclose(np.linalg.norm(left, axis=0), 1.0, rtol=1e-4)
    best, rows = tune_sgm(model, open_dataset("synthetic:1"), p1_grid=(10.0, 30.0), p2_grid=(160.0,))
    assert len(rows) == 2
    chosen = next(r for r in rows if (r["p1"], r["p2"]) == (best["p1"], best["p2"]))
    assert chosen["bad2"] == min(r["bad2"] for r in rows)


def test_recorded_command_names_the_measured_defaults():
    argv = ["--iterations", "9", "--schedule=cosine"]
    command = recorded_command(argv, build_parser().parse_args(argv))
    assert command == "python -m training.train --iterations 9 --schedule=cosine --augmentation none"


def test_cli_rejects_bad_arguments(capsys):
    assert main(["--iterations", "0"]) == 2
    assert "--iterations" in capsys.readouterr().err
    assert main(["--workers", "-1"]) == 2
    assert "--workers" in capsys.readouterr().err
    assert main(["--data", f"cones:{CONES}", "--iterations", "1"]) == 1
    assert "evaluation" in capsys.readouterr().err


def test_warm_start_widens_a_checkpoint_almost_without_changing_its_matches(tmp_path):
    from training.checkpoint import save_checkpoint
    from training.trainer.warm_start import warm_start

    torch.manual_seed(0)
    narrow = build_tower_pair("37-1deconv5-4conv", channels=4, shared=True)
    for module in narrow.modules():             # non-trivial BN statistics, as after training
        if isinstance(module, torch.nn.BatchNorm2d):
            module.running_mean.uniform_(-0.1, 0.1)
            module.running_var.uniform_(0.5, 2.0)
    path = save_checkpoint(tmp_path / "narrow.pt", model=narrow, step=1)
    wide = build_tower_pair("37-1deconv5-4conv", channels=8, shared=True)
    warm_start(wide, str(path), generator=torch.Generator().manual_seed(0))
    image = np.random.default_rng(0).integers(0, 256, (50, 70, 3), dtype=np.uint8)
    shifted = np.ascontiguousarray(np.roll(image, 3, axis=1))
    (fl_narrow, fr_narrow), (fl_wide, fr_wide) = (TorchTowers(m.eval())(image, shifted)
                                                  for m in (narrow, wide))
    cosine_narrow, cosine_wide = (fl_narrow * fr_narrow).sum(0), (fl_wide * fr_wide).sum(0)
    assert np.abs(cosine_narrow - cosine_wide).max() < 1e-3
    assert not np.allclose(fl_wide[4:], 0.0)                   # the new channels can grow
    with pytest.raises(ValueError, match="narrower"):
        warm_start(build_tower_pair("37-1deconv5-4conv", channels=2, shared=True), str(path))
    with pytest.raises(ValueError, match="shared"):
        warm_start(build_tower_pair("37-1deconv5-4conv", channels=8), str(path))


SHIPPED = ROOT / "service" / "models"
TRAINED = ("adsm-fast", "adsm-fast-int8", "adsm-paper", "adsm-paper-int8")
TRAINED_ARCHITECTURE = {"adsm-fast": ("13-1deconv3-4conv", 32), "adsm-paper": ("37-1deconv5-4conv", 64)}


@pytest.mark.parametrize("name", TRAINED)
def test_shipped_trained_models_record_their_training(name):
    from service.features.manifest import load_manifest, verify_files

    folder = SHIPPED / name
    manifest = load_manifest(folder)
    verify_files(folder, manifest)
    assert sum(f.stat().st_size for f in folder.iterdir()) < 20 * 2**20
    config, channels = TRAINED_ARCHITECTURE[name.removesuffix("-int8")]
    assert manifest["config"] == config and manifest["channels"] == channels
    assert manifest["training"]["command"].startswith("python -m training.train")
    assert manifest["training"]["wall_time_s"] > 0 and manifest["training"]["iterations"] > 0
    assert "synthetic" in manifest["sgm"]["tuned_on"]
    assert {"synthetic-validation", "middlebury2003-cones"} <= set(manifest["metrics"])
    assert manifest["onnx"]["precision"] == ("int8" if name.endswith("int8") else "fp32")


def test_default_model_beats_the_ncc_baseline_by_the_rule_and_on_cones():
    # The rule ranks models by the synthetic validation split; Cones only confirms. Both figures are the
    # manifests' own, measured on their folders by export.measure (tests/export/test_measured_metrics.py holds
    # them to a fresh run).
    from service.features.manifest import default_model_dir, load_manifest

    default = load_manifest(default_model_dir())["metrics"]
    baseline = load_manifest(SHIPPED / "ncc-baseline")["metrics"]
    for data in ("synthetic-validation", "middlebury2003-cones"):
        assert default[data]["bad2"] < baseline[data]["bad2"], data


def test_the_data_levers_reach_the_generator() -> None:
    plain = TrainingData("synthetic", seed=0, spec=BatchSpec())
    assert plain.synthetic.rectification is None and plain.synthetic.photometric.vignetting == (0.0, 0.0)
    levers = TrainingData("synthetic", seed=0, spec=BatchSpec(rectification_error=True, vignetting=0.2))
    assert levers.synthetic.rectification is not None
    assert levers.synthetic.photometric.vignetting == (0.0, 0.2)
    # The levers change the pairs the trainer sees (the same example index, another right view).
    assert not np.array_equal(plain.sample(3)[0].right, levers.sample(3)[0].right)
    curved = TrainingData("synthetic", seed=0, spec=BatchSpec(curved_surfaces=0.5))
    assert plain.synthetic.curved_surfaces == 0 and curved.synthetic.curved_surfaces == 0.5
    # Curved surfaces move only the objects that bulge: the crop and augmentation draws stay the same.
    (a, rng_a), (b, rng_b) = plain.sample(3), curved.sample(3)
    assert rng_a.random() == rng_b.random()
    assert 0 < np.mean(a.disparity != b.disparity) < 0.9
    fine = TrainingData("synthetic", seed=0, spec=BatchSpec(fine_textures=0.5))
    assert plain.synthetic.fine_textures == 0 and fine.synthetic.fine_textures == 0.5
    # Fine textures repaint surfaces only: the same disparities, crop and augmentation draws, other pixels.
    (a, rng_a), (c, rng_c) = plain.sample(3), fine.sample(3)
    assert rng_a.random() == rng_c.random()
    np.testing.assert_array_equal(a.disparity, c.disparity)
    assert not np.array_equal(a.left, c.left)
    photos = TrainingData("synthetic", seed=0, spec=BatchSpec(photo_textures=0.7))
    assert plain.synthetic.photo_probability == PHOTO_SHARE and photos.synthetic.photo_probability == 0.7
    assert not np.array_equal(plain.sample(3)[0].left, photos.sample(3)[0].left)


@pytest.mark.parametrize("flag, field, message", [
    ("--vignetting", "vignetting", "vignetting must be in [0, 1), got"),
    ("--clean-views", "clean_views", "clean views must be a share in [0, 1], got"),
    ("--curved-surfaces", "curved_surfaces", "curved surfaces must be a share in [0, 1], got"),
    ("--fine-textures", "fine_textures", "fine textures must be a share in [0, 1], got"),
    ("--downsampled-views", "downsampled_views", "downsampled views must be a share in [0, 1], got"),
    ("--photo-textures", "photo_textures", "photo textures must be a share in [0, 1], got"),
])
def test_bad_data_lever_values_are_refused(tmp_path, capsys, flag, field, message) -> None:
    with pytest.raises(ValueError, match=re.escape(message)):
        BatchSpec(**{field: 1.5})
    assert main(["--config", "9-4conv", "--channels", "4", "--shared", "--iterations", "1",
                 "--batch-size", "1", "--crop", "48", "96", "--max-disparity", "16", "--cones", "",
                 flag, "-0.1", "--out", str(tmp_path)]) == 1
    assert f"{message} -0.1" in capsys.readouterr().err


def test_downsampled_views_photograph_that_share_of_the_scenes_at_twice_the_size() -> None:
    plain = TrainingData("synthetic", seed=5, spec=BatchSpec(height=48, width=96, max_disparity=24,
                                                             camera_draws=2))
    share = TrainingData("synthetic", seed=5, spec=BatchSpec(height=48, width=96, max_disparity=24,
                                                             downsampled_views=0.5, camera_draws=2))
    chosen, unknown = [], 0
    for index in range(12):
        (a, rng_a), (b, rng_b) = plain.sample(index), share.sample(index)
        assert b.left.shape == a.left.shape and b.max_disparity == a.max_disparity
        assert rng_a.random() == rng_b.random()  # the crop and augmentation draws are the run's own
        chosen.append(not np.array_equal(a.disparity, b.disparity, equal_nan=True))
        unknown += chosen[-1] and bool(np.isnan(b.disparity).any())
    assert unknown  # the blocks across a depth edge have no truth
    # The choice is per scene: both camera draws of a scene (examples 2j, 2j + 1) share it.
    assert chosen[0::2] == chosen[1::2] and 0 < sum(chosen) < 12
    for index in range(12):  # the examples of the other scenes are a run's without the lever
        if not chosen[index]:
            np.testing.assert_array_equal(share.sample(index)[0].left, plain.sample(index)[0].left)


def test_clean_views_render_that_share_of_the_same_scenes_without_camera_effects() -> None:
    plain = TrainingData("synthetic", seed=5, spec=BatchSpec())
    share = TrainingData("synthetic", seed=5, spec=BatchSpec(clean_views=0.3))
    every = TrainingData("synthetic", seed=5, spec=BatchSpec(clean_views=1.0))
    clean = []
    for index in range(20):
        (a, rng_a), (b, rng_b), (c, _) = plain.sample(index), share.sample(index), every.sample(index)
        # Same scene and truth, and the same crop and augmentation draws: only the cameras change.
        np.testing.assert_array_equal(a.disparity, b.disparity)
        assert rng_a.random() == rng_b.random()
        assert not np.array_equal(a.left, c.left)
        clean.append(np.array_equal(b.left, c.left))
        if not clean[-1]:
            np.testing.assert_array_equal(a.left, b.left)
    assert 2 <= sum(clean) <= 12  # a share of 0.3 of 20 draws


def test_camera_draws_share_one_rendered_scene_among_consecutive_examples() -> None:
    spec = BatchSpec(height=48, width=96, max_disparity=24)
    one = TrainingData("synthetic", seed=3, spec=spec)
    four = TrainingData("synthetic", seed=3, spec=dataclasses.replace(spec, camera_draws=4))
    scene = [four.sample(index)[0] for index in range(8, 12)]  # scene 2 of seed 3
    # The first draw is exactly the pair of the scene's seed (example 2 of a run with one draw each) ...
    reference = one.sample(2)[0]
    for field in ("left", "right", "disparity", "nonoccluded"):
        np.testing.assert_array_equal(getattr(scene[0], field), getattr(reference, field))
    # ... the others the same scene and truth through other cameras, each its own.
    for other in scene[1:]:
        np.testing.assert_array_equal(other.disparity, reference.disparity)
        assert np.mean(other.left != reference.left) > 0.5 and np.mean(other.right != reference.right) > 0.5
    assert not np.array_equal(scene[1].left, scene[2].left)
    # Examples stay a pure function of their index: any order, any process, the same pixels (resume, DDP,
    # workers), and the crop and augmentation draws stay the example's own.
    again = TrainingData("synthetic", seed=3, spec=dataclasses.replace(spec, camera_draws=4))
    (late, rng_late), (early, _) = again.sample(10), again.sample(8)
    np.testing.assert_array_equal(late.left, scene[2].left)
    np.testing.assert_array_equal(early.left, scene[0].left)
    assert rng_late.random() == one.sample(10)[1].random()
    assert not np.array_equal(four.sample(12)[0].disparity, reference.disparity)  # the next scene


def test_camera_draws_must_be_whole_and_divide_a_steps_examples(tmp_path, capsys) -> None:
    for bad in (0, True, 1.5):
        with pytest.raises(ValueError, match="camera draws must be a whole number >= 1"):
            BatchSpec(camera_draws=bad)
    with pytest.raises(ValueError, match="--camera-draws 3 must divide the 2 examples of a step"):
        train(TrainConfig(**TINY, iterations=1, camera_draws=3, out=str(tmp_path / "run")))
    assert not (tmp_path / "run").exists()
    assert main(["--camera-draws", "0"]) == 2
    assert "--camera-draws must be >= 1, got 0" in capsys.readouterr().err


def test_camera_draws_are_recorded_with_the_training_data(tmp_path) -> None:
    out = tmp_path / "run"
    train(TrainConfig(**TINY, iterations=1, val_every=1, camera_draws=2, out=str(out)))
    assert "2 camera draws per scene" in load_checkpoint(out / "last.pt").training["data"]


def test_bench_synthetic_times_training_examples_per_camera_draws(tmp_path) -> None:
    from bench.synthetic import main as bench_synthetic

    report = tmp_path / "synthetic.json"
    assert bench_synthetic(["--size", "48", "96", "--max-disparity", "24", "--pairs", "1",
                            "--camera-draws", "1", "4", "--json", str(report)]) == 0
    examples = json.loads(report.read_text())["training_ms_per_example"]
    assert set(examples) == {"1", "4"} and all(ms > 0 for ms in examples.values())


def test_the_training_step_benchmark_times_both_losses_and_restores_the_trainer():
    from bench.training_step import step_seconds
    from training.losses import pixel_losses
    from training.trainer import objective

    for loss in ("candidates", "banded", "both-views"):
        seconds = step_seconds(config="11-5conv", channels=4, batch_size=1, steps=1, threads=1, loss=loss,
                                kept=False)
        assert 0 < seconds < 60
    assert objective.pixel_losses is pixel_losses  # the candidates variant's stand-in is gone again
    with pytest.raises(ValueError, match="loss must be one of"):
        step_seconds(config="11-5conv", channels=4, batch_size=1, steps=1, threads=1, loss="sparse",
                      kept=False)
