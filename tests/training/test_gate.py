"""training.gate and training.networks.gate: the learned NCC share of a trained folder, trained on the
folder's frozen ONNX features and written by export.hybrid into the same graph."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import onnxruntime as ort
import pytest
import torch

from export.baseline import build_tower
from export.hybrid import build_folder
from service.features.manifest import MODELS_DIR
from service.features.towers import FeatureTowers
from training.evaluation import GatedTowers
from training.gate import main
from training.networks.gate import NCCWindow, TextureGate, gated_features

pytestmark = pytest.mark.torch

LEARNED = MODELS_DIR / "adsm-rf11-int8"
TINY = ["--iterations", "3", "--val-every", "3", "--val-pairs", "1", "--crop", "48", "64",
        "--batch-size", "2"]


@pytest.mark.parametrize("window", [3, 5])
def test_the_ncc_window_is_the_baseline_tower(window: int) -> None:
    image = np.random.default_rng(1).random((1, 3, 20, 33), dtype=np.float32)
    image[..., :6] = 0.4   # a flat patch: the regularised norm must agree too
    session = ort.InferenceSession(build_tower(window, side="left").SerializeToString(),
                                   providers=["CPUExecutionProvider"])
    expected = session.run(None, {"image": image})[0]
    features, energy = NCCWindow(window)(torch.from_numpy(image))
    # Flat windows hold rounding residue only (|f| ~ 1e-4: the two runtimes sum the kernel's taps apart).
    flat = slice(0, 6 - window // 2)
    np.testing.assert_allclose(features.numpy()[..., flat.stop:], expected[..., flat.stop:], atol=1e-5)
    assert np.abs(features.numpy()[..., flat]).max() < 1e-3 and np.abs(expected[..., flat]).max() < 1e-3
    assert energy.shape == (1, 1, 20, 33) and float(energy[..., 1:4].max()) < 1e-10


def test_the_gate_starts_nearly_closed_keeps_unit_norm_and_round_trips() -> None:
    learned = torch.nn.functional.normalize(torch.randn(1, 8, 10, 12), dim=1)
    ncc, energy = NCCWindow(3)(torch.rand(1, 3, 10, 12))
    gate = TextureGate(learned_channels=8, window=3)
    share = gate(learned, ncc, energy)
    assert float(share.detach().max()) < 0.05
    features = gated_features(learned, ncc, share)
    torch.testing.assert_close(features.norm(dim=1), torch.ones(1, 10, 12), atol=1e-4, rtol=0)
    with torch.no_grad():
        gate.conv.weight.normal_()
    again = TextureGate.from_dict(json.loads(json.dumps(gate.to_dict())))
    torch.testing.assert_close(again(learned, ncc, energy), gate(learned, ncc, energy))
    with pytest.raises(ValueError, match="the gate has 3 weights; 17 expected"):
        TextureGate.from_dict({**gate.to_dict(), "weight": [0.0, 1.0, 2.0]})


def test_a_trained_gate_exports_to_the_features_it_was_trained_with(tmp_path: Path) -> None:
    out = tmp_path / "gate"
    assert main(["--learned", str(LEARNED), "--out", str(out), "--edge-weight", "4", *TINY]) == 0
    values = json.loads((out / "gate.json").read_text())
    assert values["schema"] == "adsm-gate/1" and values["learned"]["name"] == LEARNED.name
    training = values["training"]
    assert training["command"].startswith("python -m training.gate --learned")
    assert training["iterations"] == 3 and training["edge_weight"] == 4.0 and training["wall_time_s"] > 0
    assert "seed 41" in training["data"]
    (validation,) = values["validation"]
    assert validation["step"] == 3 and 0 <= validation["synthetic:1"]["bad2"] <= 100
    assert (out / "validation.jsonl").read_text().count("\n") == 1
    assert values["bias"] != -3.0   # it learned

    folder = build_folder(tmp_path / "gated", learned=LEARNED, gate=out / "gate.json").parent
    torch_towers = GatedTowers(FeatureTowers(LEARNED), TextureGate.from_dict(values))
    left = np.random.default_rng(2).integers(0, 256, (30, 50, 3), dtype=np.uint8)
    right = np.roll(left, -4, axis=1)
    for ours, graph in zip(torch_towers(left, right), FeatureTowers(folder)(left, right), strict=True):
        np.testing.assert_allclose(ours, graph, atol=1e-5)


def test_bad_arguments_are_one_line_and_a_gate_is_never_overwritten(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "g"
    assert main(["--learned", str(LEARNED), "--out", str(out), *TINY, "--window", "4"]) == 1
    assert main(["--learned", str(LEARNED), "--out", str(out), *TINY, "--iterations", "0"]) == 1
    assert main(["--learned", str(tmp_path / "nothing"), "--out", str(out), *TINY]) == 1
    assert main(["--learned", str(LEARNED), "--out", str(out), *TINY, "--edge-weight", "-1"]) == 1
    out.mkdir()
    (out / "gate.json").write_text("{}")
    assert main(["--learned", str(LEARNED), "--out", str(out), *TINY]) == 1
    assert (out / "gate.json").read_text() == "{}"
    errors = capsys.readouterr().err
    assert "--window must be odd" in errors and "--iterations must be >= 1" in errors
    assert "depth-edge weight must be >= 0" in errors and "already holds a gate" in errors
    assert "Traceback" not in errors and errors.count("training.gate: error:") == 5
