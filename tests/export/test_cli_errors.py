"""Export and bench command lines: bad arguments and files give one line, and never break a folder."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from bench.__main__ import main as bench_main
from export import baseline, hybrid, measure, to_onnx
from service.features.manifest import MODELS_DIR, load_manifest, verify_files

pytestmark = pytest.mark.torch


def _one_line_error(capsys: pytest.CaptureFixture[str], prog: str) -> str:
    err = capsys.readouterr().err
    assert "Traceback" not in err and f"{prog}: error" in err, err
    return err


def _digests(folder: Path) -> dict[str, bytes]:
    return {path.name: path.read_bytes() for path in sorted(folder.iterdir())}


def test_a_failed_export_leaves_an_existing_folder_intact(tmp_path, capsys):
    import torch

    from training.checkpoint import save_checkpoint
    from training.networks import build_tower_pair

    first = save_checkpoint(tmp_path / "a.pt", model=build_tower_pair("9-4conv", channels=4), step=0)
    torch.manual_seed(1)
    second = save_checkpoint(tmp_path / "b.pt", model=build_tower_pair("9-4conv", channels=4), step=0)
    folder = tmp_path / "model"
    assert to_onnx.main(["--checkpoint", str(first), "--out", str(folder), "--no-measure"]) == 0
    before = _digests(folder)
    argv = ["--checkpoint", str(second), "--out", str(folder), "--no-measure", "--p1", "nan"]
    assert to_onnx.main(argv) == 1
    _one_line_error(capsys, "export.to_onnx")
    assert _digests(folder) == before  # the towers used to be replaced, the manifest not: a broken folder
    verify_files(folder, load_manifest(folder))


def test_baseline_bad_penalties_are_one_line_and_keep_the_folder(tmp_path, capsys):
    folder = tmp_path / "ncc"
    assert baseline.main(["--out", str(folder), "--window", "5"]) == 0
    before = _digests(folder)
    for argv in (["--p1", "nan"], ["--p2", "-1"], ["--window", "99999"]):
        assert baseline.main(["--out", str(folder), "--window", "3", *argv]) == 1
        _one_line_error(capsys, "export.baseline")
    assert _digests(folder) == before


def test_hybrid_refuses_a_tampered_learned_folder(tmp_path, capsys):
    learned = tmp_path / "learned"
    shutil.copytree(MODELS_DIR / "adsm-rf11", learned)
    data = bytearray((learned / "right.onnx").read_bytes())
    data[-1] ^= 1
    (learned / "right.onnx").write_bytes(bytes(data))
    assert hybrid.main(["--learned", str(learned), "--core-weight", "0.5", "--out", str(tmp_path / "h")]) == 1
    assert "does not match its manifest" in _one_line_error(capsys, "export.hybrid")
    assert not (tmp_path / "h").exists()


def test_measure_refuses_data_under_a_reserved_name(tmp_path, capsys):
    folder = tmp_path / "rf11"
    shutil.copytree(MODELS_DIR / "adsm-rf11", folder)
    for argv in (["--data", "middlebury2003-cones=synthetic:1"], ["--synthetic", "-1"]):
        assert measure.main(["--model", str(folder), *argv]) == 1
        _one_line_error(capsys, "export.measure")


def test_bench_reports_bad_arguments_and_files_in_one_line(capsys):
    assert bench_main(["weighted_median", "--model", "/nonexistent-model-folder"]) == 1
    assert "does not exist" in _one_line_error(capsys, "bench weighted_median")
    # Counts and durations are checked by argparse (bench.positive_int / positive_float) before anything
    # runs: these used to run and report success, or fail only after the whole benchmark.
    for argv in (["synthetic", "--pairs", "0"], ["load", "--duration", "-1"], ["load", "--clients", "0"],
                 ["temperature", "--steps", "-1"], ["runtime", "--channels", "0"],
                 ["towers", "--repeats", "0"], ["memory", "--threads", "0"], ["load", "--duration", "nan"],
                 ["tower_scale", "--repeats", "0"], ["training_step", "--rounds", "0"]):
        with pytest.raises(SystemExit) as exit_code:
            bench_main(argv)
        assert exit_code.value.code == 2, argv
        err = capsys.readouterr().err
        assert f"argument {argv[1]}: expected a" in err and "Traceback" not in err, err
    with pytest.raises(SystemExit) as exit_code:
        bench_main(["tower_scale", "--scales", "1", "9"])
    assert exit_code.value.code == 2 and "every scale must be in 1..4" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exit_code:
        bench_main(["synthetic", "--camera-draws", "3"])
    assert exit_code.value.code == 2 and "each K must divide the batch of 8" in capsys.readouterr().err


def test_int8_calibration_refuses_tiny_images_and_a_failure_leaves_no_half_folder(tmp_path, monkeypatch):
    import numpy as np
    from PIL import Image

    import export.quantize as quantize

    images = tmp_path / "calibration"
    images.mkdir()
    Image.fromarray(np.full((4, 4, 3), 128, np.uint8)).save(images / "tiny.png")
    # A 4x4 calibration image failed inside ONNX Runtime's calibrator with a traceback.
    with pytest.raises(ValueError, match=r"'tiny' is 4x4 px; each needs at least"):
        quantize.quantize_folder(MODELS_DIR / "adsm-rf11", tmp_path / "int8", calibration=str(images))
    assert not (tmp_path / "int8").exists()
    # A calibrator failure on the second tower left a new left.onnx in an existing folder before.
    out = tmp_path / "existing"
    shutil.copytree(MODELS_DIR / "adsm-rf11-int8", out)
    before = _digests(out)
    real, calls = quantize.quantize_static, []

    def fails_on_the_right_tower(*args, **kwargs):
        calls.append(args[1])
        if len(calls) == 2:
            raise RuntimeError("calibrator failed")
        return real(*args, **kwargs)

    monkeypatch.setattr(quantize, "quantize_static", fails_on_the_right_tower)
    with pytest.raises(RuntimeError, match="calibrator failed"):
        quantize.quantize_folder(MODELS_DIR / "adsm-rf11", out, calibration="skimage:brick", datasets={})
    assert _digests(out) == before
    verify_files(out, load_manifest(out))


def test_quantize_cli_refuses_a_missing_an_int8_or_its_own_folder_and_records_its_command(tmp_path, capsys):
    from export.quantize import main as quantize_main

    for source, out, message in [(tmp_path / "nope", tmp_path / "a", "does not exist"),
                                 (MODELS_DIR / "adsm-rf11-int8", tmp_path / "b", "is already int8"),
                                 (MODELS_DIR / "adsm-rf11", MODELS_DIR / "adsm-rf11", "--out must differ")]:
        assert quantize_main(["--model", str(source), "--out", str(out), "--no-measure"]) == 1
        error = capsys.readouterr().err
        assert error.startswith("export.quantize: error: ") and message in error and "Traceback" not in error
        assert not out.exists() or out == MODELS_DIR / "adsm-rf11"
    argv = ["--model", str(MODELS_DIR / "adsm-rf11"), "--out", str(tmp_path / "int8"), "--no-measure",
            "--calibration", "skimage:brick"]
    assert quantize_main(argv) == 0
    manifest = load_manifest(tmp_path / "int8")
    assert manifest["onnx"]["precision"] == "int8" and manifest["metrics"] == {}
    assert manifest["onnx"]["quantization"]["command"] == "python -m export.quantize " + " ".join(argv)


@pytest.mark.parametrize("trained_range", [["5", "1"], ["-5", "10"]])
def test_a_reversed_or_negative_trained_range_is_refused(tmp_path, capsys, trained_range):
    from training.checkpoint import save_checkpoint
    from training.networks import build_tower_pair

    checkpoint = save_checkpoint(tmp_path / "a.pt", model=build_tower_pair("9-4conv", channels=4), step=0)
    argv = ["--checkpoint", str(checkpoint), "--out", str(tmp_path / "m"), "--no-measure",
            "--trained-range", *trained_range]
    assert to_onnx.main(argv) == 1
    assert "0 <= LOW <= HIGH" in _one_line_error(capsys, "export.to_onnx")
    assert not (tmp_path / "m").exists()
