"""Peers timed in the same run as our runtime: OpenCV StereoSGBM, CNES libsgm, a reference ONNX conv.

Used by ``python -m bench suite``; not a benchmark on its own. Each peer answers seconds (median over
repeats after one warm-up) so the suite can print ratios against our stages measured minutes apart on
the same, equally loaded, machine:

- OpenCV StereoSGBM on the same image pair (whole classical pipeline, 4-path ``MODE_HH4``);
- CNES libsgm (``pip install libsgm``, module ``c_libsgm``) aggregating *our* cost volume. Its
  ``sgm_api`` only accepts 8 directions, so its figure is per cell per path over 8 paths;
- one ``C -> C`` 11x11 convolution in ONNX Runtime with the towers' session settings: the GFLOP/s this
  machine reaches on one large conv, against which a tower's GFLOP/s reads as an efficiency.
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

LIBSGM_DIRECTIONS = np.array(
    [[0, 1], [1, 0], [1, 1], [1, -1], [0, -1], [-1, 0], [-1, -1], [-1, 1]], np.int32
)
REFERENCE_KERNEL = 11


def median_seconds(run: Callable[[], object], repeats: int) -> tuple[float, float]:
    """(median wall seconds, median CPU seconds of this process) over ``repeats`` runs after a warm-up."""
    run()
    walls, cpus = [], []
    for _ in range(repeats):
        wall, cpu = time.perf_counter(), time.process_time()
        run()
        walls.append(time.perf_counter() - wall)
        cpus.append(time.process_time() - cpu)
    return statistics.median(walls), statistics.median(cpus)


def opencv_sgbm(left: np.ndarray, right: np.ndarray, disparities: int, *, threads: int, repeats: int
                ) -> dict[str, float] | None:
    """OpenCV StereoSGBM (4 paths, 5x5 blocks, P1/P2 as OpenCV's docs suggest) on a uint8 RGB pair."""
    try:
        import cv2
    except ImportError:
        return None
    cv2.setNumThreads(threads)
    grey = [cv2.cvtColor(image, cv2.COLOR_RGB2GRAY) for image in (left, right)]
    block = 5
    matcher = cv2.StereoSGBM_create(
        minDisparity=0, numDisparities=-(-disparities // 16) * 16, blockSize=block,
        P1=8 * block * block, P2=32 * block * block, uniquenessRatio=10, disp12MaxDiff=1,
        mode=cv2.STEREO_SGBM_MODE_HH4,
    )
    wall, cpu = median_seconds(lambda: matcher.compute(*grey), repeats)
    return {"wall_s": wall, "cpu_s": cpu, "version": cv2.__version__}


def libsgm_aggregate(volume: np.ndarray, *, p1: float, p2: float, repeats: int) -> dict[str, float] | None:
    """CNES libsgm's 8-path aggregation of an (H, W, D) volume; None when it is not installed.

    libsgm takes float32 only, so our int16 volume is widened for it (outside the timed call): the
    comparison is libsgm on float32 against ours on int16, each in its own native cost type.
    """
    try:
        import c_libsgm
    except ImportError:
        return None
    volume = volume.astype(np.float32)
    height, width, _ = volume.shape
    paths = len(LIBSGM_DIRECTIONS)
    p1_map = np.full((height, width, paths), p1, np.float32)
    p2_map = np.full((height, width, paths), p2, np.float32)
    segmentation = np.ones((height, width), np.float32)

    def run() -> None:
        c_libsgm.sgm_api(volume, p1_map, p2_map, LIBSGM_DIRECTIONS, np.float32(np.nan), segmentation,
                         False, False, False)

    wall, cpu = median_seconds(run, repeats)
    cells_paths = volume.size * paths
    return {"wall_s": wall, "cpu_s": cpu, "paths": paths, "ns_per_cell_per_path": wall / cells_paths * 1e9,
            "cpu_ns_per_cell_per_path": cpu / cells_paths * 1e9}


def conv_flops(onnx_path: Path, height: int, width: int) -> int:
    """2 x multiply-adds of every Conv / ConvTranspose of an ONNX tower run on a height x width image."""
    import onnx
    from onnx import numpy_helper, shape_inference

    model = onnx.load(str(onnx_path))
    graph_input = model.graph.input[0]
    dims = graph_input.type.tensor_type.shape.dim
    for dim, value in zip(dims, (1, 3, height, width), strict=True):
        dim.Clear()
        dim.dim_value = value
    model = shape_inference.infer_shapes(model)
    shapes = {info.name: [d.dim_value for d in info.type.tensor_type.shape.dim]
              for info in [*model.graph.value_info, *model.graph.output, *model.graph.input]}
    weights = {init.name: numpy_helper.to_array(init).shape for init in model.graph.initializer}
    total = 0
    for node in model.graph.node:
        if node.op_type not in ("Conv", "ConvTranspose"):
            continue
        weight = _weight_shape(model, node.input[1], weights)
        kernel = int(np.prod(weight[2:]))
        if node.op_type == "Conv":  # weight (C_out, C_in, k, k); cost per output pixel
            out = shapes.get(node.output[0])
            total += 2 * int(np.prod(out[2:])) * weight[0] * weight[1] * kernel
        else:  # weight (C_in, C_out, k, k); every input pixel scatters a k x k x C_out patch
            source = shapes.get(node.input[0])
            total += 2 * int(np.prod(source[2:])) * weight[0] * weight[1] * kernel
    return total


def _weight_shape(model, name: str, weights: dict[str, tuple[int, ...]]) -> tuple[int, ...]:
    if name in weights:
        return weights[name]
    # int8 QDQ graphs feed the conv a DequantizeLinear of the stored int8 weight.
    for node in model.graph.node:
        if name in node.output and node.op_type == "DequantizeLinear":
            return weights[node.input[0]]
    raise ValueError(f"cannot find the shape of conv weight {name!r}")


class _RandomFeeds:
    """Calibration reader for the int8 reference conv (ONNX Runtime's CalibrationDataReader protocol)."""

    def __init__(self, shape: tuple[int, ...]) -> None:
        feeds = [{"x": np.random.default_rng(i).random(shape, dtype=np.float32)} for i in range(2)]
        self._feeds = iter(feeds)

    def get_next(self) -> dict[str, np.ndarray] | None:
        return next(self._feeds, None)


def reference_conv_gflops(channels: int, height: int, width: int, *, precision: str, threads: int,
                          repeats: int) -> float:
    """GFLOP/s of one ``channels -> channels`` 11x11 valid conv in ONNX Runtime with the towers' settings.

    ``precision`` "int8" quantises it as export/quantize.py does a tower (QDQ, per-channel int8 weights,
    uint8 activations), so an int8 tower reads against an int8 conv of its own channel count.
    """
    import tempfile

    import onnx
    import onnxruntime as ort
    from onnx import TensorProto, helper, numpy_helper

    rng = np.random.default_rng(0)
    weight = rng.standard_normal((channels, channels, REFERENCE_KERNEL, REFERENCE_KERNEL)).astype(np.float32)
    shape = (1, channels, height, width)
    graph = helper.make_graph(
        [helper.make_node("Conv", ["x", "w"], ["y"])], "reference",
        [helper.make_tensor_value_info("x", TensorProto.FLOAT, list(shape))],
        [helper.make_tensor_value_info("y", TensorProto.FLOAT, None)],
        [numpy_helper.from_array(weight, "w")],
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)], ir_version=8)
    with tempfile.TemporaryDirectory(prefix="adsm-bench-reference-") as scratch:
        path = Path(scratch) / "reference.onnx"
        onnx.save(model, path)
        if precision == "int8":
            from onnxruntime.quantization import QuantFormat, QuantType, quantize_static

            quantized = Path(scratch) / "reference-int8.onnx"
            quantize_static(path, quantized, _RandomFeeds(shape), quant_format=QuantFormat.QDQ,
                            per_channel=True, activation_type=QuantType.QUInt8, weight_type=QuantType.QInt8)
            path = quantized
        options = ort.SessionOptions()
        options.intra_op_num_threads = threads
        options.inter_op_num_threads = 1
        options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
        session = ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
    image = rng.random(shape, dtype=np.float32)
    wall, _ = median_seconds(lambda: session.run(None, {"x": image}), repeats)
    out_pixels = (height - REFERENCE_KERNEL + 1) * (width - REFERENCE_KERNEL + 1)
    return 2 * out_pixels * channels * channels * REFERENCE_KERNEL**2 / wall / 1e9
