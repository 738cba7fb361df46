"""export.tune: the P1/P2 rule on a folder's own ONNX towers, and --write keeping the manifest honest."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from export.baseline import build_folder
from export.tune import main
from service.features import load_manifest
from service.features.manifest import write_manifest

# The synthetic validation split needs the train extra's generator (scikit-image's photographs).
pytestmark = pytest.mark.torch


def _measured_folder(tmp_path: Path) -> Path:
    """A 5x5 NCC folder whose metrics were measured with other penalties: --write must replace them."""
    folder = build_folder(tmp_path / "ncc", window=5, p1=30.0, p2=160.0).parent
    manifest = load_manifest(folder)
    write_manifest(folder, {**manifest, "metrics": {"synthetic-validation": {"bad2": 99.0,
                                                                             "data": "synthetic:1"}}})
    return folder


def test_the_rule_picks_the_lowest_bad2_and_write_re_measures(tmp_path: Path,
                                                              capsys: pytest.CaptureFixture[str]) -> None:
    folder = _measured_folder(tmp_path)
    assert main(["--model", str(folder), "--pairs", "1", "--p1", "5", "65", "--p2", "540", "--write"]) == 0
    out, err = capsys.readouterr()
    rows = [json.loads(line) for line in err.splitlines() if line.startswith("{")]
    assert len(rows) == 2
    chosen = {k: min(rows, key=lambda r: (r["bad2"], r["epe"]))[k] for k in ("p1", "p2")}
    assert json.loads(out) == chosen
    written = load_manifest(folder)
    assert (written["sgm"]["p1"], written["sgm"]["p2"]) == (chosen["p1"], chosen["p2"])
    assert "export.tune" in written["sgm"]["tuned_on"] and "1 pairs" in written["sgm"]["tuned_on"]
    entry = written["metrics"]["synthetic-validation"]
    assert entry["bad2"] == pytest.approx(next(r["bad2"] for r in rows if r["p1"] == chosen["p1"]), abs=1e-3)
    assert entry["command"].startswith("python -m export.tune --model")


def test_shiftable_windows_are_tuned_with_and_recorded(tmp_path: Path,
                                                       capsys: pytest.CaptureFixture[str]) -> None:
    folder = _measured_folder(tmp_path)
    grid = ["--model", str(folder), "--pairs", "1", "--p1", "30", "--p2", "160"]
    assert main(grid) == 0
    centred = json.loads(capsys.readouterr().err.splitlines()[-1])
    assert main([*grid, "--shiftable-windows", "--write"]) == 0
    shifted = json.loads(capsys.readouterr().err.splitlines()[0])
    assert shifted["bad2"] != centred["bad2"]  # the step ran in the tuning
    written = load_manifest(folder)
    assert written["sgm"]["shiftable_windows"] is True
    assert "shiftable windows on" in written["sgm"]["tuned_on"]
    entry = written["metrics"]["synthetic-validation"]  # measured with the step: the tuning's figure
    assert entry["bad2"] == pytest.approx(shifted["bad2"], abs=1e-3)
    assert main([*grid, "--no-shiftable-windows", "--write"]) == 0
    assert load_manifest(folder)["sgm"]["shiftable_windows"] is False


def test_the_border_band_is_tuned_with_and_recorded(tmp_path: Path,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    folder = _measured_folder(tmp_path)
    grid = ["--model", str(folder), "--pairs", "1", "--p1", "30", "--p2", "160"]
    assert main([*grid, "--border-band"]) == 0
    banded = json.loads(capsys.readouterr().err.splitlines()[0])
    assert main([*grid, "--no-border-band", "--write"]) == 0
    unbanded = json.loads(capsys.readouterr().err.splitlines()[0])
    assert unbanded["bad2"] != banded["bad2"]  # the step's switch reached the tuning
    written = load_manifest(folder)
    assert written["filling"] == {"border_band": False}
    assert "border band off" in written["sgm"]["tuned_on"]
    entry = written["metrics"]["synthetic-validation"]  # measured without the step: the tuning's figure
    assert entry["bad2"] == pytest.approx(unbanded["bad2"], abs=1e-3)
    assert main([*grid, "--border-band", "--write"]) == 0
    assert load_manifest(folder)["filling"] == {"border_band": True}


def test_bad_arguments_end_in_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--model", str(tmp_path / "missing")]) == 1
    assert main(["--model", str(tmp_path), "--pairs", "0"]) == 1
    err = capsys.readouterr().err
    assert "does not exist" in err and "--pairs must be >= 1" in err and "Traceback" not in err
