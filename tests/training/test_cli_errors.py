"""Training command lines: a bad argument or file gives one line and a non-zero exit, and never costs data."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
import torch

from service.features.manifest import MODELS_DIR, file_entry, load_manifest
from training import validate
from training.checkpoint import load_checkpoint, save_checkpoint, update_checkpoint
from training.model_folder import checkpoint_from_folder
from training.networks import build_tower_pair
from training.train import main as train_main
from training.trainer import TrainConfig, train

pytestmark = pytest.mark.torch

TINY = ["--config", "9-4conv", "--channels", "4", "--iterations", "1", "--batch-size", "1", "--crop", "48",
        "96", "--max-disparity", "16", "--val-pairs", "1", "--cones", "", "--threads", "1"]


def _one_line_error(capsys: pytest.CaptureFixture[str], prog: str) -> str:
    err = capsys.readouterr().err
    assert "Traceback" not in err and f"{prog}: error:" in err, err
    return err


def _checkpoint(path: Path, *, optimizer: bool = True) -> Path:
    model = build_tower_pair("9-4conv", channels=4)
    adam = torch.optim.Adam(model.parameters()) if optimizer else None
    return save_checkpoint(path, model=model, step=3, optimizer=adam)


def test_a_checkpoint_missing_its_keys_is_refused_in_one_line(tmp_path):
    torch.save({"format": "adsm-checkpoint/1"}, tmp_path / "partial.pt")
    with pytest.raises(ValueError, match="not a complete ADSM checkpoint: it lacks spec"):
        load_checkpoint(tmp_path / "partial.pt")


@pytest.mark.parametrize("argv, message", [
    (["--threads", "-1"], "--threads must be >= 1"),
    (["--stop-after", "0"], "--stop-after must be >= 1"),
    (["--val-pairs", "0"], "--val-pairs must be >= 1"),
    (["--lr", "inf"], "--lr must be a finite number > 0"),
    (["--temperature", "nan"], "--temperature must be a finite number > 0"),
    (["--time-budget", "nan"], "--time-budget must be a finite number >= 0"),
    (["--max-disparity", "96"], "--max-disparity must be in 1..95"),
    (["--device", "bogus"], "--device must be cpu or cuda[:N]"),
    (["--device", "cuda:x"], "--device must be cpu or cuda[:N]"),
    (["--device", "meta"], "--device must be cpu or cuda[:N]"),
    # Spent minutes generating 100000 crops, then died of memory.
    (["--batch-size", "100000"], "GiB per process (the B x H x W x W matching scores"),
    (["--adaptive-support", "--config", "13-1deconv3-4conv"], "adaptive support needs a conv-only tower"),
    (["--adaptive-support", "--standardize-window", "5"], "with input standardisation"),
])
def test_train_refuses_bad_numbers_and_devices_before_writing(tmp_path, capsys, argv, message):
    out = tmp_path / "run"
    assert train_main([*TINY, *argv, "--out", str(out)]) == 2
    assert message in _one_line_error(capsys, "training.train")
    assert not out.exists()


def test_train_refuses_nan_edge_weight_and_the_validation_split_as_data(tmp_path, capsys):
    assert train_main([*TINY, "--edge-weight", "nan", "--out", str(tmp_path / "a")]) == 1
    assert "depth-edge weight must be >= 0 and finite" in _one_line_error(capsys, "training.train")
    assert train_main([*TINY, "--subpixel-loss", "nan", "--out", str(tmp_path / "c")]) == 1
    message = _one_line_error(capsys, "training.train")
    assert "vertex weight (--subpixel-loss) must be >= 0 and finite" in message
    assert train_main([*TINY, "--data", "synthetic:5", "--out", str(tmp_path / "b")]) == 1
    assert "synthetic validation split" in _one_line_error(capsys, "training.train")


def test_a_fresh_start_never_overwrites_an_earlier_run(tmp_path, capsys):
    out = tmp_path / "run"
    out.mkdir()
    last = _checkpoint(out / "last.pt")
    (out / "history.jsonl").write_text('{"step": 1, "loss": 1.0}\n')
    before = last.read_bytes()
    assert train_main([*TINY, "--out", str(out)]) == 1
    assert "already holds a run" in _one_line_error(capsys, "training.train")
    assert last.read_bytes() == before and (out / "history.jsonl").read_text() == '{"step": 1, "loss": 1.0}\n'


def test_resuming_another_network_is_one_line(tmp_path, capsys):
    saved = _checkpoint(tmp_path / "other.pt")  # 9-4conv, 4 channels
    assert train_main([*TINY, "--channels", "8", "--resume", str(saved), "--out", str(tmp_path / "r")]) == 1
    assert "network differs: channels 4 (this run: 8)" in _one_line_error(capsys, "training.train")


def test_running_out_of_memory_is_one_line(tmp_path, capsys, monkeypatch):
    def exhausted(*_: object, **__: object) -> None:
        raise RuntimeError("[enforce fail at alloc_cpu.cpp:127] DefaultCPUAllocator: can't allocate memory")

    monkeypatch.setattr("training.train.train", exhausted)
    assert train_main([*TINY, "--out", str(tmp_path / "m")]) == 1
    assert "out of memory" in _one_line_error(capsys, "training.train")


def test_validate_reports_bad_files_and_numbers_in_one_line(tmp_path, capsys):
    (tmp_path / "text.pt").write_text("hello")
    for path in (tmp_path / "missing.pt", tmp_path / "text.pt", tmp_path):
        assert validate.main(["--checkpoint", str(path), "--pairs", "1", "--cones", ""]) == 1
        _one_line_error(capsys, "training.validate")
    saved = _checkpoint(tmp_path / "c.pt")
    assert validate.main(["--checkpoint", str(saved), "--threads", "0", "--cones", ""]) == 2
    _one_line_error(capsys, "training.validate")
    assert validate.main(["--checkpoint", str(saved), "--pairs", "1", "--cones", "bogus"]) == 1
    _one_line_error(capsys, "training.validate")


def test_tuning_a_checkpoint_keeps_what_resume_needs(tmp_path):
    saved = _checkpoint(tmp_path / "last.pt")
    before = load_checkpoint(saved)
    update_checkpoint(saved, metrics={"synthetic-validation": {"bad2": 1.0}}, deploy={"p1": 9.0})
    after = load_checkpoint(saved)
    assert after.optimizer is not None and after.rng is not None and after.step == before.step
    assert after.deploy == {"p1": 9.0} and after.metrics == {"synthetic-validation": {"bad2": 1.0}}
    # And so a tuned last.pt still resumes (it used to lose its optimizer state).
    config = TrainConfig(config="9-4conv", channels=4, crop=(48, 96), max_disparity=16, batch_size=1,
                         iterations=4, val_every=4, val_pairs=1, cones="", threads=1, out=str(tmp_path))
    assert train(config, resume=str(saved))["steps"] == 4


def test_a_model_folder_with_an_unreadable_graph_is_one_line(tmp_path):
    folder = tmp_path / "rf11"
    shutil.copytree(MODELS_DIR / "adsm-rf11", folder)
    (folder / "left.onnx").write_bytes(b"garbage")
    manifest = load_manifest(folder)
    manifest["files"]["left.onnx"] = file_entry(folder / "left.onnx")  # the hash matches: still unreadable
    (folder / "manifest.json").write_text(__import__("json").dumps(manifest))
    with pytest.raises(ValueError, match="is not a readable ONNX graph"):
        checkpoint_from_folder(folder)


def test_reproduce_checks_its_arguments_before_recording_a_protocol(tmp_path, capsys):
    from training.reproduce.__main__ import main as reproduce_main

    base = ["--table", "6", "--data", "synthetic", "--configs", "37-1deconv5-4conv"]
    assert reproduce_main([*base, "--out", str(tmp_path / "a"), "--batch-size", "3"]) == 1
    _one_line_error(capsys, "training.reproduce")
    assert not (tmp_path / "a" / "protocol.json").exists()  # it used to block the corrected command
    assert reproduce_main([*base, "--out", str(tmp_path / "b"), "--kubernetes-job", str(tmp_path)]) == 1
    _one_line_error(capsys, "training.reproduce")
    assert reproduce_main([*base, "--out", str(tmp_path / "b"), "--kubernetes-job", str(tmp_path / "j.yaml"),
                           "--gpus", "-1"]) == 2
    _one_line_error(capsys, "training.reproduce")
    # --report into an --out nothing has run into said only '[Errno 2] ... table.json'.
    assert reproduce_main([*base, "--out", str(tmp_path / "never"), "--report"]) == 1
    assert "is not a run folder" in _one_line_error(capsys, "training.reproduce")
