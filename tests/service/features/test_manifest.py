"""Manifest module: the small validator agrees with jsonschema, hashes are checked, the default resolves."""

from __future__ import annotations

import copy
import dataclasses
import json
from pathlib import Path

import jsonschema
import pytest

from service.features import (
    ModelError,
    default_model_dir,
    file_entry,
    load_manifest,
    validate_manifest,
    verify_files,
    write_manifest,
)
from service.features import manifest as mf
from service.features.defaults import RUNTIME_DEFAULTS

SHIPPED = sorted(p.parent for p in (Path(mf.MODELS_DIR)).glob("*/manifest.json"))


def _manifest() -> dict:
    return {
        "schema": "adsm-model/1",
        "name": "test-model",
        "config": "ncc-9x9",
        "channels": 81,
        "receptive_field": 9,
        "input": {"color": "rgb", "range": [0, 1], "mean": [0, 0, 0], "std": [1, 1, 1]},
        "cost": {"scale": 128, "definition": "-scale * <FL, FR>"},
        "sgm": {"p1": 30, "p2": 160, "paths": 4},
        "disparity": {"default_max": 128, "trained_range": [0, 0]},
        "onnx": {"opset": 17, "precision": "fp32"},
        "files": {
            "left.onnx": {"sha256": "a" * 64, "bytes": 10},
            "right.onnx": {"sha256": "b" * 64, "bytes": 10},
        },
        "training": None,
        "metrics": {"cones": {"bad2": 12.5, "note": "x", "seconds": None}},
    }


def _broken() -> list[tuple[str, dict]]:
    cases = []

    def case(label, edit):
        m = _manifest()
        edit(m)
        cases.append((label, m))

    case("schema", lambda m: m.update(schema="adsm-model/2"))
    case("missing", lambda m: m.pop("channels"))
    case("extra key", lambda m: m.update(colour="red"))
    case("name pattern", lambda m: m.update(name="Bad Name"))
    case("channels type", lambda m: m.update(channels=1.5))
    case("channels bool", lambda m: m.update(channels=True))
    case("channels min", lambda m: m.update(channels=0))
    case("std zero", lambda m: m["input"].update(std=[1, 0, 1]))
    case("mean length", lambda m: m["input"].update(mean=[0, 0]))
    case("color enum", lambda m: m["input"].update(color="bgr"))
    case("scale", lambda m: m["cost"].update(scale=0))
    case("paths", lambda m: m["sgm"].update(paths=8))
    case("p1 negative", lambda m: m["sgm"].update(p1=-1))
    case("p2 above the int16 SGM bound", lambda m: m["sgm"].update(p2=4097))
    case("scale above the int16 cost bound", lambda m: m["cost"].update(scale=1025))
    case("sha pattern", lambda m: m["files"]["left.onnx"].update(sha256="XYZ"))
    case("file missing", lambda m: m["files"].pop("right.onnx"))
    case("training type", lambda m: m.update(training="none"))
    case("training fields", lambda m: m.update(training={"command": "x"}))
    case("metric value", lambda m: m["metrics"]["cones"].update(bad2=[1]))
    case("opset", lambda m: m["onnx"].update(opset=11))
    return cases


def test_valid_manifest_accepted_by_both_validators():
    validate_manifest(_manifest())
    jsonschema.validate(_manifest(), mf.schema())


@pytest.mark.parametrize(("label", "manifest"), _broken(), ids=[label for label, _ in _broken()])
def test_invalid_manifest_rejected_by_both_validators(label, manifest):
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate(manifest, mf.schema())
    with pytest.raises(ModelError, match=r"manifest"):
        validate_manifest(manifest)


def test_error_names_the_key():
    m = _manifest()
    m["cost"]["scale"] = -3
    with pytest.raises(ModelError, match=r"manifest\.cost\.scale must be > 0"):
        validate_manifest(m)


def _folder(tmp_path: Path) -> Path:
    (tmp_path / "left.onnx").write_bytes(b"left tower bytes")
    (tmp_path / "right.onnx").write_bytes(b"right tower bytes")
    return tmp_path


def test_write_load_verify_round_trip(tmp_path):
    folder = _folder(tmp_path)
    path = write_manifest(folder, _manifest())
    assert path == folder / "manifest.json"
    loaded = load_manifest(folder)
    assert loaded["files"]["left.onnx"] == file_entry(folder / "left.onnx")
    assert loaded["files"]["left.onnx"]["bytes"] == len(b"left tower bytes")
    verify_files(folder, loaded)


def test_tampered_file_refused_with_both_hashes(tmp_path):
    folder = _folder(tmp_path)
    write_manifest(folder, _manifest())
    manifest = load_manifest(folder)
    (folder / "right.onnx").write_bytes(b"right tower bytes, modified")
    with pytest.raises(ModelError) as info:
        verify_files(folder, manifest)
    message = str(info.value)
    assert "right.onnx" in message
    assert manifest["files"]["right.onnx"]["sha256"] in message
    assert file_entry(folder / "right.onnx")["sha256"] in message


def test_write_refuses_missing_tower(tmp_path):
    (tmp_path / "left.onnx").write_bytes(b"x")
    with pytest.raises(ModelError, match=r"right\.onnx"):
        write_manifest(tmp_path, _manifest())


def test_write_refuses_invalid_manifest_and_writes_nothing(tmp_path):
    folder = _folder(tmp_path)
    bad = _manifest()
    bad["channels"] = 0
    with pytest.raises(ModelError, match="channels"):
        write_manifest(folder, bad)
    assert not (folder / "manifest.json").exists()


@pytest.mark.parametrize(
    ("content", "match"),
    [(None, "cannot read"), ("{not json", "not valid JSON"), ("[]", "must be of type object")],
)
def test_load_errors_are_clear(tmp_path, content, match):
    if content is not None:
        (tmp_path / "manifest.json").write_text(content)
    with pytest.raises(ModelError, match=match):
        load_manifest(tmp_path)


def test_load_of_non_utf8_bytes_names_the_manifest(tmp_path):
    # A bare UnicodeDecodeError escaped before: 'adsm: error: 'utf-8' codec can't decode byte 0xff ...'
    (tmp_path / "manifest.json").write_bytes(b'{"name": "\xff\xfe"}')
    with pytest.raises(ModelError, match=r"manifest\.json is not UTF-8 text"):
        load_manifest(tmp_path)


def test_load_missing_folder(tmp_path):
    with pytest.raises(ModelError, match="does not exist"):
        load_manifest(tmp_path / "nowhere")


def test_default_model_dir_env_override(monkeypatch, tmp_path):
    monkeypatch.setenv("ADSM_MODEL_DIR", str(tmp_path))
    assert default_model_dir() == tmp_path


def test_default_model_dir_names_a_shipped_folder(monkeypatch):
    monkeypatch.delenv("ADSM_MODEL_DIR", raising=False)
    folder = default_model_dir()
    assert folder.parent == mf.MODELS_DIR
    assert (folder / "manifest.json").is_file()


def test_default_pointer_rejects_paths(monkeypatch, tmp_path):
    monkeypatch.delenv("ADSM_MODEL_DIR", raising=False)
    pointer = tmp_path / "DEFAULT"
    pointer.write_text("../elsewhere\n")
    monkeypatch.setattr(mf, "DEFAULT_POINTER", pointer)
    with pytest.raises(ModelError, match="one model folder name"):
        default_model_dir()


@pytest.mark.parametrize("folder", SHIPPED, ids=[p.name for p in SHIPPED])
def test_shipped_manifests_valid_and_files_match(folder):
    manifest = load_manifest(folder)
    jsonschema.validate(manifest, mf.schema())
    verify_files(folder, manifest)
    assert manifest["name"] == folder.name


def test_write_does_not_mutate_the_template(tmp_path):
    # Exporters reuse their template dicts: write_manifest fills a copy.
    template = _manifest()
    del template["files"]
    before = copy.deepcopy(template)
    write_manifest(_folder(tmp_path), template)
    assert template == before
    assert "files" in json.loads((tmp_path / "manifest.json").read_text())


def test_runtime_defaults_fill_a_valid_manifest_and_cannot_be_changed():
    defaults = RUNTIME_DEFAULTS
    manifest = _manifest()
    manifest["input"] = defaults.input()
    manifest["cost"]["scale"] = defaults.cost_scale
    manifest["sgm"].update(p1=defaults.p1, p2=defaults.p2)
    manifest["disparity"]["default_max"] = defaults.default_max
    validate_manifest(manifest)
    jsonschema.validate(manifest, mf.schema())
    with pytest.raises(dataclasses.FrozenInstanceError):
        defaults.p1 = 1.0  # type: ignore[misc]
    assert defaults.deploy({"p1": 5.0})["p1"] == 5.0 and defaults.p1 == 30.0
