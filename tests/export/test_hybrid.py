"""export.hybrid: a learned model's towers and a core (an NCC window or another trained folder's towers)
blended into one cost, no runtime change."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort
import pytest

from export.baseline import build_tower, ncc_channels
from export.hybrid import build_folder, combine_towers, main
from service.features import load_manifest
from service.features.manifest import MODELS_DIR
from service.matcher import Matcher, MatchOptions

LEARNED = MODELS_DIR / "adsm-fast-int8"


def _features(model: onnx.ModelProto, image: np.ndarray) -> np.ndarray:
    session = ort.InferenceSession(model.SerializeToString(), providers=["CPUExecutionProvider"])
    return session.run(None, {"image": image})[0]


@pytest.fixture(scope="module")
def image() -> np.ndarray:
    return np.random.default_rng(3).random((1, 3, 24, 40), dtype=np.float32)


@pytest.mark.parametrize("window, weight", [(3, 0.3), (5, 0.6)])
def test_the_blend_is_the_weighted_sum_of_the_two_cosines(image: np.ndarray, window: int,
                                                           weight: float) -> None:
    learned, ncc = onnx.load(LEARNED / "left.onnx"), build_tower(window, side="left")
    hybrid = _features(combine_towers(learned, ncc, core_weight=weight), image)
    learned_features, ncc_features = _features(learned, image), _features(ncc, image)
    assert hybrid.shape == (1, learned_features.shape[1] + ncc_channels(window), 24, 40)
    np.testing.assert_allclose(np.linalg.norm(hybrid, axis=1), 1.0, atol=1e-5)
    # The runtime's cost is the dot product of the two views' features: for two pixels of the same image
    # it must be (1 - w) * learned cosine + w * NCC.
    def cosine(features: np.ndarray) -> float:
        return float(features[0, :, 5, 7] @ features[0, :, 11, 30])

    expected = (1 - weight) * cosine(learned_features) + weight * cosine(ncc_features)
    assert cosine(hybrid) == pytest.approx(expected, abs=1e-5)


def test_a_constant_share_scales_the_norm_not_the_channels(image: np.ndarray) -> None:
    # Both exporters end in Div(features, norm): the share goes into the 1-channel norm, so the graph has no
    # elementwise pass over all channels beside the concatenation. A tower ending otherwise gets its own.
    learned, ncc = onnx.load(LEARNED / "left.onnx"), build_tower(3, side="left")
    combined = combine_towers(learned, ncc, core_weight=0.02)
    assert [node.op_type for node in combined.graph.node].count("Mul") == (
        [node.op_type for node in learned.graph.node].count("Mul") + 2)   # one per branch, on its norm
    identity = onnx.helper.make_node("Identity", ["features"], ["renamed"])
    ncc_ending = onnx.load_from_string(ncc.SerializeToString())
    ncc_ending.graph.node.append(identity)
    ncc_ending.graph.output[0].name = "renamed"
    hybrid = _features(combine_towers(learned, ncc_ending, core_weight=0.02), image)
    np.testing.assert_allclose(hybrid[0, -8:], math.sqrt(0.02) * _features(ncc, image)[0], atol=1e-6)
    np.testing.assert_allclose(hybrid[0, :-8], math.sqrt(0.98) * _features(learned, image)[0], atol=1e-5)


def test_a_texture_adaptive_share_follows_the_window_energy(image: np.ndarray) -> None:
    image = image.copy()
    image[..., :20] = 0.5 + 0.002 * image[..., :20]   # a flat left half beside the textured right one
    learned, ncc = onnx.load(LEARNED / "left.onnx"), build_tower(3, side="left")
    hybrid = _features(combine_towers(learned, ncc, core_weight=0.8, texture_energy=0.01), image)
    learned_features, ncc_features = _features(learned, image), _features(ncc, image)
    grey = image[0].transpose(1, 2, 0) @ np.float32([0.299, 0.587, 0.114])
    padded = np.pad(grey, 1, mode="edge")
    windows = np.lib.stride_tricks.sliding_window_view(padded, (3, 3)).reshape(*grey.shape, 9)
    energy = ((windows - windows.mean(-1, keepdims=True)) ** 2).sum(-1)
    share = 0.8 * energy / (energy + 0.01)
    np.testing.assert_allclose(hybrid[0, :32], np.sqrt(1 - share) * learned_features[0], atol=1e-5)
    np.testing.assert_allclose(hybrid[0, 32:], np.sqrt(share) * ncc_features[0], atol=1e-5)
    # Unit norm up to the NCC tower's own regularisation of near-flat windows (export.baseline.NORM_EPS).
    np.testing.assert_allclose(np.linalg.norm(hybrid, axis=1), 1.0, atol=1e-4)
    assert share[:, 2:17].max() < 0.01 and share[:, 23:].min() > 0.6   # flat -> learned, textured -> NCC
    with pytest.raises(ValueError, match="texture energy must be positive"):
        combine_towers(learned, ncc, core_weight=0.8, texture_energy=0.0)


@pytest.mark.parametrize("weight", [0.0, 1.0, -0.2, 1.5, math.nan])
def test_a_weight_outside_the_open_interval_is_refused(weight: float) -> None:
    with pytest.raises(ValueError, match="strictly between 0 and 1"):
        combine_towers(onnx.load(LEARNED / "left.onnx"), build_tower(3, side="left"), core_weight=weight)


def test_the_folder_is_a_valid_model_that_matches(tmp_path: Path) -> None:
    path = build_folder(tmp_path / "hybrid", learned=LEARNED, window=3, core_weight=0.25, command="test")
    manifest, learned = load_manifest(path.parent), load_manifest(LEARNED)
    assert manifest["channels"] == learned["channels"] + ncc_channels(3)
    assert manifest["config"] == f"{learned['config']}+ncc-3x3"
    assert manifest["onnx"]["precision"] == learned["onnx"]["precision"]
    assert manifest["training"] == learned["training"]  # the towers' provenance goes with them
    assert (manifest["sgm"]["p1"], manifest["sgm"]["p2"]) == (learned["sgm"]["p1"], learned["sgm"]["p2"])
    assert manifest["build"]["core_weight"] == 0.25 and manifest["build"]["ncc_window"] == 3
    assert manifest["metrics"] == {}
    # A textured pair shifted by 6 px: the hybrid towers find the shift through the unchanged runtime.
    texture = np.random.default_rng(0).integers(0, 256, (48, 96, 3), dtype=np.uint8)
    left, right = texture[:, :-6], texture[:, 6:]
    disparity = Matcher.from_folder(path.parent)(left, right, MatchOptions(max_disparity=16)).disparity
    assert np.nanmedian(np.abs(disparity[8:-8, 24:-8] - 6)) < 0.5


def test_the_command_writes_penalties_given_and_reports_errors(tmp_path: Path,
                                                               capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "h"
    assert main(["--learned", str(LEARNED), "--core-weight", "0.4", "--out", str(out),
                 "--p1", "20", "--p2", "300"]) == 0
    manifest = json.loads((out / "manifest.json").read_text())
    assert (manifest["sgm"]["p1"], manifest["sgm"]["p2"]) == (20.0, 300.0)
    assert manifest["build"]["command"].startswith("python -m export.hybrid --learned")
    assert main(["--learned", str(LEARNED), "--core-weight", "1", "--out", str(tmp_path / "x")]) == 1
    assert main(["--learned", str(tmp_path / "nothing"), "--core-weight", "0.3", "--out", str(out)]) == 1
    assert main(["--learned", str(LEARNED), "--core-weight", "0.3", "--out", str(out), "--window", "4"]) == 1
    assert main(["--learned", str(LEARNED), "--core-weight", "0.3", "--out", str(out), "--tune",
                 "--p1", "3"]) == 1
    errors = capsys.readouterr().err
    assert "strictly between 0 and 1" in errors and "does not exist" in errors
    assert "odd size from 3" in errors and "give either --tune or --p1/--p2" in errors
    assert "Traceback" not in errors


TRAINED_CORE = MODELS_DIR / "adsm-fast"


def test_a_trained_core_blends_two_learned_cosines(image: np.ndarray) -> None:
    learned, core = onnx.load(LEARNED / "left.onnx"), onnx.load(TRAINED_CORE / "left.onnx")
    hybrid = _features(combine_towers(learned, core, core_weight=0.4), image)
    learned_features, core_features = _features(learned, image), _features(core, image)
    np.testing.assert_allclose(hybrid[0, :32], np.sqrt(0.6) * learned_features[0], atol=1e-5)
    np.testing.assert_allclose(hybrid[0, 32:], np.sqrt(0.4) * core_features[0], atol=1e-5)
    with pytest.raises(ValueError, match="needs an NCC core"):
        combine_towers(learned, core, core_weight=0.4, texture_energy=0.01)


def test_a_folder_with_a_trained_core_records_both_provenances(tmp_path: Path) -> None:
    path = build_folder(tmp_path / "ensemble", learned=LEARNED, core=TRAINED_CORE, core_weight=0.5,
                        command="test")
    manifest, learned, core = (load_manifest(folder) for folder in (path.parent, LEARNED, TRAINED_CORE))
    assert manifest["channels"] == learned["channels"] + core["channels"]
    assert manifest["config"] == f"{learned['config']}+{core['config']}"
    assert manifest["receptive_field"] == max(learned["receptive_field"], core["receptive_field"])
    # An int8 and an fp32 branch: the work-area bound of the tiles takes int8's, the larger.
    assert manifest["onnx"]["precision"] == "int8"
    assert manifest["training"] == learned["training"]
    assert manifest["build"]["core"] == core["name"]
    assert manifest["build"]["core_training"] == core["training"]
    assert "ncc_window" not in manifest["build"]
    texture = np.random.default_rng(1).integers(0, 256, (48, 96, 3), dtype=np.uint8)
    left, right = texture[:, :-5], texture[:, 5:]
    disparity = Matcher.from_folder(path.parent)(left, right, MatchOptions(max_disparity=16)).disparity
    assert np.nanmedian(np.abs(disparity[8:-8, 24:-8] - 5)) < 0.5


def test_the_command_refuses_two_cores_and_its_own_input_as_output(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    copy = tmp_path / "core"
    with pytest.raises(SystemExit) as usage:  # argparse: --core and --window exclude each other
        main(["--learned", str(LEARNED), "--core", str(TRAINED_CORE), "--window", "3", "--core-weight", "0.5",
              "--out", str(tmp_path / "h")])
    assert usage.value.code == 2 and "not allowed with argument" in capsys.readouterr().err
    assert build_folder(copy, learned=LEARNED, core=TRAINED_CORE, core_weight=0.5).exists()
    assert main(["--learned", str(LEARNED), "--core", str(copy), "--core-weight", "0.5",
                 "--out", str(copy)]) == 1
    assert main(["--learned", str(LEARNED), "--core", str(tmp_path / "missing"), "--core-weight", "0.5",
                 "--out", str(tmp_path / "h")]) == 1
    errors = capsys.readouterr().err
    assert "one of the folders it reads" in errors and "does not exist" in errors
    assert "Traceback" not in errors


def _gate(learned_channels: int = 32, window: int = 3, *, seed: int = 5) -> dict:
    """A gate.json as python -m training.gate writes it (random weights: the graph must apply any)."""
    rng = np.random.default_rng(seed)
    return {"schema": "adsm-gate/1", "window": window, "learned_channels": learned_channels,
            "weight": [float(v) for v in rng.normal(0, 0.5, learned_channels + ncc_channels(window) + 1)],
            "bias": 1.5, "learned": {"name": LEARNED.name}, "training": {"command": "test"}}


def test_a_learned_gate_sets_each_pixels_share(image: np.ndarray) -> None:
    gate = _gate()
    learned, ncc = onnx.load(LEARNED / "left.onnx"), build_tower(3, side="left")
    hybrid = _features(combine_towers(learned, ncc, core_weight=None, gate=gate), image)
    learned_features, ncc_features = _features(learned, image), _features(ncc, image)
    grey = image[0].transpose(1, 2, 0) @ np.float32([0.299, 0.587, 0.114])
    windows = np.lib.stride_tricks.sliding_window_view(np.pad(grey, 1, mode="edge"), (3, 3))
    windows = windows.reshape(*grey.shape, 9)
    energy = ((windows - windows.mean(-1, keepdims=True)) ** 2).sum(-1)
    inputs = np.concatenate([learned_features[0], ncc_features[0], np.log(energy + 1e-6)[None]])
    share = 1 / (1 + np.exp(-(np.tensordot(np.float32(gate["weight"]), inputs, axes=1) + gate["bias"])))
    assert share.min() > 0.05 and share.max() < 0.999 and share.std() > 0.05   # varies per pixel
    np.testing.assert_allclose(hybrid[0, :32], np.sqrt(1 - share) * learned_features[0], atol=1e-5)
    np.testing.assert_allclose(hybrid[0, 32:], np.sqrt(share) * ncc_features[0], atol=1e-5)
    with pytest.raises(ValueError, match="give no core weight"):
        combine_towers(learned, ncc, core_weight=0.3, gate=gate)
    with pytest.raises(ValueError, match="trained for 16 learned channels"):
        combine_towers(learned, ncc, core_weight=None, gate=_gate(16))


def test_a_gated_folder_records_its_gate_and_keeps_the_learned_settings(tmp_path: Path) -> None:
    gate_path = tmp_path / "gate.json"
    gate_path.write_text(json.dumps(_gate()))
    path = build_folder(tmp_path / "gated", learned=MODELS_DIR / "adsm-rf11-int8", gate=gate_path,
                        command="test")
    manifest = load_manifest(path.parent)
    learned = load_manifest(MODELS_DIR / "adsm-rf11-int8")
    assert manifest["build"]["gate"] == _gate() and manifest["build"]["ncc_window"] == 3
    assert manifest["channels"] == 32 + ncc_channels(3) and manifest["training"] == learned["training"]
    assert manifest["sgm"]["shiftable_windows"] is learned["sgm"]["shiftable_windows"] is True
    assert "learned (build.gate)" in manifest["description"]
    left = np.random.default_rng(4).integers(0, 256, (40, 64, 3), dtype=np.uint8)
    right = np.roll(left, -5, axis=1)
    disparity = Matcher.from_folder(path.parent)(left, right, MatchOptions(max_disparity=16)).disparity
    assert np.nanmedian(np.abs(disparity[8:-8, 24:-8] - 5)) < 0.5


def test_the_command_refuses_a_file_that_is_not_a_gate(tmp_path: Path,
                                                       capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "other.json").write_text(json.dumps({"schema": "something else"}))
    (tmp_path / "broken.json").write_text("{")
    (tmp_path / "gate5.json").write_text(json.dumps(_gate(window=5)))
    out = str(tmp_path / "h")
    assert main(["--learned", str(LEARNED), "--gate", str(tmp_path / "other.json"), "--out", out]) == 1
    assert main(["--learned", str(LEARNED), "--gate", str(tmp_path / "broken.json"), "--out", out]) == 1
    assert main(["--learned", str(LEARNED), "--gate", str(tmp_path / "gate5.json"), "--out", out,
                 "--window", "3"]) == 1
    assert main(["--learned", str(LEARNED), "--gate", str(tmp_path / "gate5.json"), "--out", out,
                 "--core", str(TRAINED_CORE)]) == 1
    errors = capsys.readouterr().err
    assert "not a gate of python -m training.gate" in errors and "is not JSON" in errors
    assert "trained for a 5x5 window, not 3x3" in errors and "not a trained core" in errors
    assert "Traceback" not in errors
