"""Export: deconv-as-conv, ONNX Runtime == PyTorch, the model folder, int8, the runtime end to end."""

from __future__ import annotations

import json
from pathlib import Path

import jsonschema
import numpy as np
import onnx
import onnxruntime as ort
import pytest
import torch
import torch.nn.functional as F
from onnx import helper
from PIL import Image

from export.measure import measure_folder
from export.quantize import calibration_images, calibration_pairs, float_nodes, quantize_folder
from export.to_onnx import export_folder, fold_tower, main, tower_to_onnx
from service.cli import main as adsm
from service.features import ModelError, load_manifest
from service.features.manifest import SCHEMA_PATH
from service.features.tiles import work_bytes_per_pixel
from service.features.towers import FeatureTowers
from service.matcher import Matcher
from training.checkpoint import save_checkpoint
from training.networks import TowerPair, build_tower_pair, dense_features

pytestmark = pytest.mark.torch

PROVENANCE = {"command": "python -m training.train", "data": "synthetic", "wall_time_s": 2.0, "iterations": 5}


def _with_statistics(pair: TowerPair, seed: int = 0) -> TowerPair:
    """Random weights plus non-trivial BN statistics and affine terms, so that folding is really tested."""
    torch.manual_seed(seed)
    with torch.no_grad():
        for module in pair.modules():
            if isinstance(module, torch.nn.BatchNorm2d):
                module.weight.uniform_(0.5, 1.5)
                module.bias.uniform_(-0.2, 0.2)
        pair.train()
        for _ in range(2):
            pair.left(torch.rand(2, 3, 64, 64))
            pair.right(torch.rand(2, 3, 64, 64))
    return pair.eval()


def _relative_error(actual: np.ndarray, expected: np.ndarray) -> float:
    return float(np.abs(actual - expected).max() / np.abs(expected).max())


def _ort_features(model: onnx.ModelProto, image: torch.Tensor) -> np.ndarray:
    options = ort.SessionOptions()
    options.intra_op_num_threads = 1
    session = ort.InferenceSession(model.SerializeToString(), options, providers=["CPUExecutionProvider"])
    return session.run(None, {"image": image.numpy()})[0]


def test_stride1_transposed_conv_equals_full_conv_with_flipped_kernel() -> None:
    torch.manual_seed(0)
    deconv = torch.nn.ConvTranspose2d(3, 4, 5, bias=False)
    image = torch.rand(1, 3, 9, 12)
    flipped = deconv.weight.detach().transpose(0, 1).flip(2, 3)
    with torch.no_grad():
        torch.testing.assert_close(F.conv2d(image, flipped, padding=4), deconv(image))
    folded = fold_tower(build_tower_pair("37-1deconv5-4conv", channels=4).left)
    assert folded[0].padding == (4, 4) and folded[0].weight.shape == (4, 3, 5, 5)
    assert [layer.relu for layer in folded] == [False, True, True, True, False]
    assert folded[-1].bias is None and all(layer.bias is not None for layer in folded[:-1])


@pytest.mark.parametrize("name", ["37-1deconv5-4conv", "37-3deconv-6conv", "29-1deconv2-4conv", "45-8conv",
                                  "21x5-1deconv3-4conv"])
@pytest.mark.parametrize("opset", [13, 17, 18])
def test_onnx_runtime_matches_pytorch_eval_at_odd_shapes(name: str, opset: int) -> None:
    pair = _with_statistics(build_tower_pair(name, channels=6))
    model = tower_to_onnx(pair.left, opset=opset)
    image_input = model.graph.input[0].type.tensor_type.shape.dim
    assert [d.dim_param or d.dim_value for d in image_input] == [1, 3, "height", "width"]
    for height, width in [(1, 1), (17, 40), (37, 37), (31, 77)]:
        image = torch.rand(1, 3, height, width)
        with torch.no_grad():
            expected = dense_features(pair.left, image).numpy()
        actual = _ort_features(model, image)
        assert actual.shape == (1, 6, height, width)
        assert _relative_error(actual, expected) < 1e-4


def _export(tmp_path: Path, *, channels: int = 4, shared: bool = False, training: dict | None = PROVENANCE,
            standardize_window: int = 0, config: str = "29-1deconv3-4conv", adaptive_support: bool = False,
            **overrides) -> Path:
    pair = _with_statistics(build_tower_pair(config, channels=channels, shared=shared,
                                             standardize_window=standardize_window,
                                             adaptive_support=adaptive_support))
    checkpoint = save_checkpoint(tmp_path / "model.pt", model=pair, step=5, training=training,
                                 metrics={"synthetic": {"epe": 3.5}}, deploy={"trained_range": [0, 96]})
    return export_folder(checkpoint, tmp_path / "Model_A", command="test", **overrides).parent


def test_exported_folder_has_a_valid_manifest_with_provenance(tmp_path: Path) -> None:
    folder = _export(tmp_path, p1=12.0)
    manifest = load_manifest(folder)
    jsonschema.validate(manifest, json.loads(SCHEMA_PATH.read_text()))
    assert manifest["name"] == "model_a"
    assert manifest["config"] == "29-1deconv3-4conv" and manifest["channels"] == 4
    assert manifest["receptive_field"] == 33  # dense field: patch 29 + 2 * (3 - 1)
    # The checkpoint's metrics (PyTorch towers) are not copied: a manifest carries only measured figures.
    assert manifest["training"] == PROVENANCE and manifest["metrics"] == {}
    assert manifest["sgm"]["p1"] == 12.0 and manifest["sgm"]["p2"] == 160.0
    assert manifest["disparity"]["trained_range"] == [0, 96] and manifest["cost"]["scale"] == 128.0
    assert manifest["onnx"] == {**manifest["onnx"], "opset": 17, "precision": "fp32"}
    for name in ("left.onnx", "right.onnx"):
        onnx.checker.check_model(str(folder / name), full_check=True)


def test_runtime_refuses_a_tampered_tower(tmp_path: Path) -> None:
    folder = _export(tmp_path)
    FeatureTowers(folder, threads=1)
    tampered = bytearray((folder / "right.onnx").read_bytes())
    tampered[-1] ^= 0xFF
    (folder / "right.onnx").write_bytes(bytes(tampered))
    with pytest.raises(ModelError, match="does not match its manifest"):
        FeatureTowers(folder, threads=1)


def test_trained_checkpoint_without_trained_range_needs_one(tmp_path: Path) -> None:
    pair = build_tower_pair("29-4conv", channels=2)
    checkpoint = save_checkpoint(tmp_path / "c.pt", model=pair, step=1, training=PROVENANCE)
    with pytest.raises(ValueError, match="--trained-range"):
        export_folder(checkpoint, tmp_path / "out")
    manifest = load_manifest(export_folder(checkpoint, tmp_path / "out", trained_range=[0, 50]).parent)
    assert manifest["disparity"]["trained_range"] == [0, 50]


def test_cli_documents_every_option_and_reports_errors(capsys: pytest.CaptureFixture[str],
                                                         tmp_path: Path) -> None:
    with pytest.raises(SystemExit) as exit_info:
        main(["--help"])
    assert exit_info.value.code == 0
    text = capsys.readouterr().out
    for option in ("--checkpoint", "--out", "--int8", "--calibration", "--opset", "--cost-scale", "--p1",
                   "--p2", "--max-disparity", "--trained-range", "--name", "skimage"):
        assert option in text
    assert main(["--checkpoint", str(tmp_path / "missing.pt"), "--out", str(tmp_path / "x")]) == 1
    assert "export.to_onnx: error:" in capsys.readouterr().err


def test_calibration_refuses_the_evaluation_pair_and_unknown_images(tmp_path: Path) -> None:
    cones = tmp_path / "middlebury2003-cones"
    cones.mkdir()
    Image.new("RGB", (8, 8)).save(cones / "left.png")
    with pytest.raises(ValueError, match="evaluation-only"):
        calibration_images(str(cones))
    with pytest.raises(ValueError, match="no scikit-image data image 'nope'"):
        calibration_images("skimage:nope")
    with pytest.raises(ValueError, match="names no images"):
        calibration_images(str(tmp_path / "*.jpg"))
    assert [name for name, _ in calibration_images("skimage:astronaut,brick")] == ["astronaut", "brick"]
    (name, left, right), = calibration_pairs("synthetic:1")
    assert name.startswith("synthetic-") and left.shape == right.shape == (192, 256, 3)
    _, left, right = calibration_pairs("skimage:brick")[0]
    np.testing.assert_array_equal(left[:, 8:], right[:, :-8])  # the right camera sees the scene shifted
    with pytest.raises(ValueError, match="positive pair count"):
        calibration_pairs("synthetic:0")


def _unstamped(metrics: dict) -> dict:
    """Metrics without what changes from run to run (time taken, date, the command's wording)."""
    return {name: {key: value for key, value in entry.items()
                   if key not in ("seconds_per_pair", "date", "command")} for name, entry in metrics.items()}


def test_int8_twin_is_qdq_and_records_its_accuracy(tmp_path: Path) -> None:
    datasets = {"synthetic-validation": "synthetic:1"}
    folder = _export(tmp_path, channels=4, datasets=datasets)
    fp32 = load_manifest(folder)["metrics"]
    assert set(fp32) == {"synthetic-validation"} and fp32["synthetic-validation"]["data"] == "synthetic:1"
    assert fp32["synthetic-validation"]["command"].startswith("python -m export.measure --model ")
    lines: list[str] = []
    manifest = load_manifest(quantize_folder(folder, tmp_path / "int8", calibration="skimage:brick,rocket",
                                             log=lines.append).parent)
    # Measured on the int8 folder itself, on the fp32 twin's data sets (not copied from the fp32 manifest).
    fresh = measure_folder(tmp_path / "int8", datasets, command="test")
    assert _unstamped(manifest["metrics"]) == _unstamped(fresh) != _unstamped(fp32)
    jsonschema.validate(manifest, json.loads(SCHEMA_PATH.read_text()))
    assert manifest["name"] == "model_a-int8" and manifest["onnx"]["precision"] == "int8"
    accuracy = manifest["onnx"]["quantization"]["accuracy_vs_fp32"]
    assert -1.0 <= accuracy["feature_cosine_left"]["p01"] <= accuracy["feature_cosine_left"]["mean"] <= 1.0
    assert 0.0 <= accuracy["disparity_agreement_1px"] <= 1.0
    assert any("int8 vs fp32" in line for line in lines)
    graph = onnx.load(str(tmp_path / "int8" / "left.onnx")).graph
    ops = {node.op_type for node in graph.node}
    assert {"QuantizeLinear", "DequantizeLinear", "Conv"} <= ops
    assert any(init.data_type == onnx.TensorProto.INT8 for init in graph.initializer)
    # Each conv's ReLU is folded into its uint8 output range: no float32 round trip (DequantizeLinear ->
    # Relu -> QuantizeLinear) between two quantised convs.
    producers = {output: node.op_type for node in graph.node for output in node.output}
    assert [node.name for node in graph.node
            if node.op_type == "Relu" and producers.get(node.input[0]) == "DequantizeLinear"] == []


def test_float_nodes_are_the_first_conv_and_relus_that_follow_no_conv(tmp_path: Path) -> None:
    weight = helper.make_tensor("w", onnx.TensorProto.FLOAT, [3, 3, 1, 1], np.ones(9, np.float32))
    graph = helper.make_graph(
        [helper.make_node("Conv", ["image", "w"], ["c0"], name="conv0"),
         helper.make_node("Relu", ["c0"], ["r0"], name="relu0"),
         helper.make_node("Conv", ["r0", "w"], ["c1"], name="conv1"),
         helper.make_node("Relu", ["c1"], ["r1"], name="relu1"),
         helper.make_node("Relu", ["image"], ["variance"], name="variance"),  # e.g. the standardisation's
         helper.make_node("Add", ["r1", "variance"], ["features"], name="add")],
        "g", [helper.make_tensor_value_info("image", onnx.TensorProto.FLOAT, [1, 3, 4, 4])],
        [helper.make_tensor_value_info("features", onnx.TensorProto.FLOAT, [1, 3, 4, 4])], [weight])
    path = tmp_path / "g.onnx"
    onnx.save(helper.make_model(graph), str(path))
    assert float_nodes(path) == ["conv0", "variance"]


def test_random_init_export_runs_through_matcher_and_adsm_predict(tmp_path: Path) -> None:
    folder = _export(tmp_path, channels=4, shared=True, training=None)
    rng = np.random.default_rng(0)
    left = rng.integers(0, 256, (40, 64, 3), dtype=np.uint8)
    right = np.roll(left, -5, axis=1)
    result = Matcher.from_folder(folder, threads=1)(left, right)
    assert result.disparity.shape == (40, 64) and result.validity.shape == (40, 64)
    Image.fromarray(left).save(tmp_path / "left.png")
    Image.fromarray(right).save(tmp_path / "right.png")
    out = tmp_path / "disparity.npy"
    code = adsm(["predict", str(tmp_path / "left.png"), str(tmp_path / "right.png"), "-o", str(out),
                 "--model", str(folder), "--max-disparity", "16"])
    assert code == 0 and np.load(out).shape == (40, 64)


def test_paper_config_64_channels_matches_pytorch(tmp_path: Path) -> None:
    # The paper's width: wide convolutions can take other ONNX Runtime kernels than the 6-channel test
    # above. The image size changes nothing in the graph (its height and width are symbolic), so a small
    # odd image covers what the KITTI-size run did in 43 s (this one: 11.5 s at a load average of 9 on 2
    # cores).
    pair = _with_statistics(build_tower_pair("37-1deconv5-4conv", channels=64))
    model = tower_to_onnx(pair.right)
    image = torch.rand(1, 3, 45, 83)
    with torch.no_grad():
        expected = dense_features(pair.right, image).numpy()
    assert _relative_error(_ort_features(model, image), expected) < 1e-4


def test_input_standardization_exports_equal_and_the_runtime_measures_its_receptive_field(
        tmp_path: Path) -> None:
    pair = _with_statistics(build_tower_pair("13-1deconv3-4conv", channels=6, standardize_window=7))
    model = tower_to_onnx(pair.left)
    assert {"AveragePool", "Concat"} <= {node.op_type for node in model.graph.node}
    for height, width in [(1, 1), (9, 40), (31, 77)]:
        image = torch.rand(1, 3, height, width)
        with torch.no_grad():
            expected = dense_features(pair.left, image).numpy()
        assert _relative_error(_ort_features(model, image), expected) < 1e-4
    folder = _export(tmp_path, channels=4, shared=True, standardize_window=5)
    manifest = load_manifest(folder)
    assert manifest["receptive_field"] == 33 + 4
    assert "standardised over 5x5 windows" in manifest["description"]
    matcher = Matcher.from_folder(folder, threads=1)
    matcher.warmup()  # measures the towers' reach against receptive_field (service.features.towers)
    rng = np.random.default_rng(0)
    left = rng.integers(0, 256, (40, 64, 3), dtype=np.uint8)
    assert matcher(left, np.roll(left, -5, axis=1)).disparity.shape == (40, 64)


def test_adaptive_support_exports_equal_and_runs_in_the_matcher(tmp_path: Path) -> None:
    pair = _with_statistics(build_tower_pair("11-5conv", channels=5, adaptive_support=True))
    with torch.no_grad():
        pair.left.support_log_gain.copy_(torch.tensor([1.0, 2.0, 3.0, 2.5, 0.5]))
    for opset in (13, 17, 21):
        model = tower_to_onnx(pair.left, opset=opset)
        assert {"Exp", "Slice"} <= {node.op_type for node in model.graph.node}
        for height, width in [(1, 1), (9, 40), (31, 77)]:
            image = torch.rand(1, 3, height, width)
            with torch.no_grad():
                expected = dense_features(pair.left, image).numpy()
            assert _relative_error(_ort_features(model, image), expected) < 1e-4
    folder = _export(tmp_path, channels=4, shared=True, config="11-5conv", adaptive_support=True)
    manifest = load_manifest(folder)
    assert "adaptive support" in manifest["description"] and manifest["onnx"]["adaptive_support"] is True
    plain = {**manifest, "onnx": {key: value for key, value in manifest["onnx"].items()
                                  if key != "adaptive_support"}}
    assert work_bytes_per_pixel(manifest) > work_bytes_per_pixel(plain)
    matcher = Matcher.from_folder(folder, threads=1)
    matcher.warmup()
    rng = np.random.default_rng(0)
    left = rng.integers(0, 256, (40, 64, 3), dtype=np.uint8)
    assert matcher(left, np.roll(left, -5, axis=1)).disparity.shape == (40, 64)


def test_an_anisotropic_folder_declares_its_larger_side_and_runs(tmp_path: Path) -> None:
    folder = _export(tmp_path, channels=4, shared=True, config="21x5-1deconv3-4conv")
    assert load_manifest(folder)["receptive_field"] == 25  # the tiles' square halo covers 25 x 9
    matcher = Matcher.from_folder(folder, threads=1)
    matcher.warmup()  # the measured reach (rows: 12 px) must equal the manifest's half field
    rng = np.random.default_rng(0)
    left = rng.integers(0, 256, (40, 64, 3), dtype=np.uint8)
    assert matcher(left, np.roll(left, -5, axis=1)).disparity.shape == (40, 64)
