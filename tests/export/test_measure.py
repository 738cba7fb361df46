"""`python -m export.measure`: a model folder's metrics measured on its own ONNX files, written with the
command and date, the manifest staying valid (schema, file hashes)."""

from __future__ import annotations

import importlib.util
import json
import shutil
from pathlib import Path
from types import SimpleNamespace

import jsonschema
import pytest
from PIL import Image

from export import measure
from export.measure import default_datasets, main, measure_command, measure_folder
from service.cli import main as adsm
from service.features import ModelError, load_manifest
from service.features.manifest import SCHEMA_PATH, verify_files
from service.io import write_disparity
from tests.helpers import ROOT
from training.data import photos
from training.data.synthetic import Photometric, SyntheticConfig, generate

SHIPPED = ROOT / "service" / "models" / "ncc-baseline"


@pytest.fixture
def tiny_cones(tmp_path: Path) -> Path:
    """A synthetic pair in the Cones layout (the command is tested without the real pair)."""
    sample = generate(3, SyntheticConfig(height=48, width=96, max_disparity=16, photometric=Photometric(
        blur_probability=0, jpeg_probability=0)))
    folder = tmp_path / "cones" / "pair"
    folder.mkdir(parents=True)
    Image.fromarray(sample.left).save(folder / "left.png")
    Image.fromarray(sample.right).save(folder / "right.png")
    write_disparity(folder / "disp_left.png", sample.disparity, "png16")
    Image.fromarray((sample.nonoccluded * 255).astype("uint8")).save(folder / "nonocc_mask.png")
    return folder.parent


@pytest.fixture
def model(tmp_path: Path) -> Path:
    return Path(shutil.copytree(SHIPPED, tmp_path / "model"))


@pytest.mark.torch
def test_write_records_the_figures_of_adsm_eval_with_command_and_date(model, tiny_cones, tmp_path, capsys):
    before = load_manifest(model)
    argv = ["--model", str(model), "--cones", str(tiny_cones), "--synthetic", "0", "--write"]
    assert main(argv) == 0, capsys.readouterr().err
    manifest = load_manifest(model)
    jsonschema.validate(manifest, json.loads(SCHEMA_PATH.read_text()))
    verify_files(model, manifest)
    assert manifest["files"] == before["files"]
    assert {k: v for k, v in manifest.items() if k != "metrics"} == {k: v for k, v in before.items()
                                                                     if k != "metrics"}
    entry = manifest["metrics"]["middlebury2003-cones"]
    # --synthetic 0: the whole metrics replaced; the Motorcycle pair is measured wherever it is installed.
    assert set(manifest["metrics"]) == {"middlebury2003-cones", "middlebury2014-motorcycle"}
    motorcycle = manifest["metrics"]["middlebury2014-motorcycle"]
    assert motorcycle["data"] == "motorcycle" and motorcycle["pixels"] == 343274  # its known truth
    assert motorcycle["max_disparity"] == 64 and 0 < motorcycle["bad2"] < 100
    assert entry["command"] == "python -m export.measure " + " ".join(argv)
    assert entry["date"].endswith("+00:00") and entry["data"].startswith("cones:")
    assert entry["pairs"] == 1 and entry["max_disparity"] == 64 and entry["pixels"] == 48 * 96
    # The same figures as `adsm eval` on the same folder and data.
    capsys.readouterr()
    assert adsm(["eval", "--model", str(model), "--data", f"cones:{tiny_cones}", "--json", "-"]) == 0
    report = json.loads(capsys.readouterr().out)
    for key in ("bad1", "bad2", "bad3", "bad4", "bad5", "d1", "epe", "density"):
        assert entry[key] == report["all"][key], key
        assert entry[f"{key}_nonocc"] == report["nonoccluded"][key], key


@pytest.mark.torch
def test_without_write_the_manifest_is_untouched(model, tiny_cones, capsys):
    text = (model / "manifest.json").read_text()
    argv = ["--model", str(model), "--cones", str(tiny_cones), "--synthetic", "0", "--no-motorcycle"]
    assert main(argv) == 0
    printed = capsys.readouterr()
    assert set(json.loads(printed.out)) == {"middlebury2003-cones"} and "README row" in printed.err
    assert (model / "manifest.json").read_text() == text


def test_synthetic_split_when_the_manifest_carries_it_or_asked():
    cones = Path(__file__)  # not a folder: left out
    assert default_datasets({"metrics": {}}, cones=cones, motorcycle=False) == {}
    carried = {"metrics": {"synthetic-validation": {"bad2": 1.0, "pairs": 3}}}
    assert default_datasets(carried, cones=cones, motorcycle=False) == {"synthetic-validation": "synthetic:3"}
    assert default_datasets(carried, cones=cones, synthetic_pairs=0, motorcycle=False) == {}
    assert default_datasets({"metrics": {}}, cones=cones, synthetic_pairs=2, motorcycle=False) == {
        "synthetic-validation": "synthetic:2"}


@pytest.mark.parametrize("installed", [True, False])
def test_motorcycle_wherever_scikit_image_ships_it(monkeypatch, installed):
    monkeypatch.setattr(measure, "motorcycle_installed", lambda: installed)
    expected = {"middlebury2014-motorcycle": "motorcycle"} if installed else {}
    assert default_datasets({"metrics": {}}, cones=None) == expected
    assert default_datasets({"metrics": {}}, cones=None, motorcycle=False) == {}


def test_motorcycle_installed_follows_scikit_image(monkeypatch):
    assert measure.motorcycle_installed() == (importlib.util.find_spec("skimage") is not None)
    no_skimage = SimpleNamespace(util=SimpleNamespace(find_spec=lambda _: None))
    monkeypatch.setattr(photos, "importlib", no_skimage)
    assert not measure.motorcycle_installed()


def test_recorded_command_reproduces_the_data_sets(tmp_path):
    datasets = {"middlebury2003-cones": f"cones:{tmp_path}", "synthetic-validation": "synthetic:2",
                "mine": "kitti2015:/data/k"}
    command = measure_command(tmp_path / "m", datasets)
    assert command.startswith("python -m export.measure --model ") and command.endswith(" --write")
    assert "--synthetic 2" in command and "--data mine=kitti2015:/data/k" in command
    assert f"--cones {tmp_path}" in command and "--no-motorcycle" in command
    with_motorcycle = measure_command(tmp_path / "m", datasets | {"middlebury2014-motorcycle": "motorcycle"})
    assert "motorcycle" not in with_motorcycle.replace(str(tmp_path), "")  # measured by default


@pytest.mark.torch
def test_a_tampered_folder_is_refused_not_measured(model, tiny_cones, capsys):
    data = bytearray((model / "left.onnx").read_bytes())
    data[-1] ^= 0xFF
    (model / "left.onnx").write_bytes(bytes(data))
    text = (model / "manifest.json").read_text()
    assert main(["--model", str(model), "--cones", str(tiny_cones), "--write"]) == 1
    assert "does not match its manifest" in capsys.readouterr().err
    assert (model / "manifest.json").read_text() == text
    with pytest.raises(ModelError):
        measure_folder(model, {"c": f"cones:{tiny_cones}"}, command="x")


def test_errors_are_one_line(model, tmp_path, capsys):
    assert main(["--model", str(model), "--cones", str(tmp_path / "missing")]) == 1
    assert capsys.readouterr().err.startswith("export.measure: error: no Cones folder")
    assert main(["--model", str(model), "--cones", str(tmp_path), "--data", "nonsense"]) == 1
    assert "NAME=SPEC" in capsys.readouterr().err
    assert main(["--model", str(model), "--cones", str(tmp_path), "--data",
                 "middlebury2014-motorcycle=cones:x"]) == 1
    assert "--no-motorcycle" in capsys.readouterr().err
