"""Feature tower speed: fp32 and int8 ONNX Runtime time per tower at 375x1242, GFLOP/s vs a reference conv.

    python -m bench towers [--config 37-1deconv5-4conv] [--channels 64 32 16] [--size 375 1242]
                           [--repeats 3] [--threads N] [--json OUT]

For each channel count a random-init model (with non-trivial BN statistics) is exported exactly as
``python -m export.to_onnx`` does, plus its int8 QDQ twin (default calibration). Speed does not depend on
the weights. One tower is timed (left and right have the same graph): one warm-up run, then the median of
``--repeats`` runs. GFLOP/s counts 2 x multiply-adds of the convs actually executed (padded input,
deconvs as full convs). The reference is a single C->C 11x11 conv in the same ONNX Runtime session setup
with the same FLOP count, fp32 and int8 QDQ, so a tower's efficiency reads against what one large conv
reaches on this machine in the same run.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import onnx
import onnxruntime as ort
import torch
from onnx import TensorProto, helper, numpy_helper
from onnxruntime.quantization import CalibrationDataReader, QuantFormat, QuantType, quantize_static
from onnxruntime.quantization.shape_inference import quant_pre_process

from bench import positive_int
from export.quantize import quantize_folder
from export.to_onnx import export_folder, fold_tower
from training.checkpoint import save_checkpoint
from training.networks import DEFAULT_CONFIG, FeatureTower, build_tower_pair, same_padding

REFERENCE_KERNEL = 11


def tower_flops(tower: FeatureTower, height: int, width: int) -> int:
    """2 x multiply-adds of every conv the exported graph runs for one height x width image."""
    left, right, top, bottom = same_padding(tower.patch_shape)
    h, w, total = height + top + bottom, width + left + right, 0
    for conv in fold_tower(tower):
        c_out, c_in, kh, kw = conv.weight.shape
        h, w = h + 2 * conv.padding[0] - kh + 1, w + 2 * conv.padding[1] - kw + 1
        total += 2 * h * w * c_out * c_in * kh * kw
    return total


def _session(model: str | bytes, threads: int) -> ort.InferenceSession:
    options = ort.SessionOptions()
    options.intra_op_num_threads = threads
    options.inter_op_num_threads = 1
    options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    return ort.InferenceSession(model, options, providers=["CPUExecutionProvider"])


def _seconds(session: ort.InferenceSession, image: np.ndarray, repeats: int) -> float:
    """Median wall time of ``repeats`` runs after one warm-up run."""
    feeds = {session.get_inputs()[0].name: image}
    session.run(None, feeds)
    times = []
    for _ in range(repeats):
        started = time.perf_counter()
        session.run(None, feeds)
        times.append(time.perf_counter() - started)
    return statistics.median(times)


class _RandomImages(CalibrationDataReader):
    def __init__(self, shape: tuple[int, ...], count: int = 2) -> None:
        rng = np.random.default_rng(0)
        self._feeds = iter([{"x": rng.random(shape, dtype=np.float32)} for _ in range(count)])

    def get_next(self) -> dict[str, np.ndarray] | None:
        return next(self._feeds, None)


def reference_conv(channels: int, height: int, width: int, folder: Path) -> tuple[Path, Path]:
    """A 'same' C->C 11x11 conv as fp32 and int8 QDQ ONNX files (input ``x`` [1, C, height, width])."""
    rng = np.random.default_rng(0)
    weight = rng.standard_normal((channels, channels, REFERENCE_KERNEL, REFERENCE_KERNEL)).astype(np.float32)
    pad = REFERENCE_KERNEL // 2
    node = helper.make_node("Conv", ["x", "w"], ["y"], pads=[pad] * 4)
    inputs = [helper.make_tensor_value_info("x", TensorProto.FLOAT, [1, channels, height, width])]
    outputs = [helper.make_tensor_value_info("y", TensorProto.FLOAT, None)]
    graph = helper.make_graph([node], "reference_conv", inputs, outputs,
                              initializer=[numpy_helper.from_array(weight, "w")])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    fp32, int8 = folder / "reference.onnx", folder / "reference-int8.onnx"
    onnx.save(model, fp32)
    quant_pre_process(str(fp32), str(fp32))  # as export.quantize does before QDQ insertion
    quantize_static(fp32, int8, _RandomImages((1, channels, height, width)), quant_format=QuantFormat.QDQ,
                    per_channel=True, activation_type=QuantType.QUInt8, weight_type=QuantType.QInt8)
    return fp32, int8


def measure(config: str, channels: int, height: int, width: int, *, repeats: int, threads: int,
            scratch: Path) -> dict[str, Any]:
    """Times and GFLOP/s of one tower (fp32, int8) and of its same-FLOP reference conv."""
    torch.manual_seed(0)
    pair = build_tower_pair(config, channels=channels).train()
    with torch.no_grad():  # BN statistics away from the identity, as in a trained model
        pair.left(torch.rand(2, 3, 64, 64))
    checkpoint = save_checkpoint(scratch / f"c{channels}.pt", model=pair.eval(), step=0, rng=False)
    fp32_folder = export_folder(checkpoint, scratch / f"c{channels}", command="bench towers").parent
    int8_folder = quantize_folder(fp32_folder, scratch / f"c{channels}-int8").parent
    flops = tower_flops(pair.left, height, width)
    image = np.random.default_rng(1).random((1, 3, height, width), dtype=np.float32)
    row: dict[str, Any] = {"config": config, "channels": channels, "gflop": round(flops / 1e9, 1)}
    for precision, folder in (("fp32", fp32_folder), ("int8", int8_folder)):
        seconds = _seconds(_session(str(folder / "left.onnx"), threads), image, repeats)
        row[f"{precision}_s"] = round(seconds, 3)
        row[f"{precision}_gflops"] = round(flops / seconds / 1e9, 1)
    # Same FLOP count: an 11x11 C->C conv over `height` rows and as many columns as that takes.
    ref_width = max(1, round(flops / (2 * channels * channels * REFERENCE_KERNEL**2 * height)))
    for precision, path in zip(("fp32", "int8"), reference_conv(channels, height, ref_width, scratch),
                               strict=True):
        data = np.random.default_rng(2).random((1, channels, height, ref_width), dtype=np.float32)
        seconds = _seconds(_session(str(path), threads), data, repeats)
        reference_flops = 2 * channels**2 * REFERENCE_KERNEL**2 * height * ref_width
        row[f"reference_{precision}_gflops"] = round(reference_flops / seconds / 1e9, 1)
    return row


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench towers", description=__doc__.splitlines()[0])
    parser.add_argument("--config", default=DEFAULT_CONFIG, help="network config (default: %(default)s)")
    parser.add_argument("--channels", type=positive_int, nargs="+", default=[64, 32, 16],
                        help="feature channels")
    parser.add_argument("--size", type=positive_int, nargs=2, default=[375, 1242], metavar=("H", "W"))
    parser.add_argument("--repeats", type=positive_int, default=3,
                        help="timed runs after one warm-up (median)")
    parser.add_argument("--threads", type=positive_int, default=len(os.sched_getaffinity(0)),
                        help="ONNX Runtime intra-op threads (default: the CPUs available, %(default)s)")
    parser.add_argument("--json", type=Path, help="also write the rows as JSON")
    args = parser.parse_args(argv)
    height, width = args.size
    load = os.getloadavg()[0]  # the machine may be shared: a load above the thread count skews the times
    print(f"{args.config} tower at {height}x{width}, {args.threads} threads, onnxruntime {ort.__version__}, "
          f"load average {load:.1f} at start")
    print(f"{'C':>3} {'GFLOP':>7} {'fp32 s':>8} {'GFLOP/s':>8} {'int8 s':>8} {'GFLOP/s':>8} "
          f"{'ref fp32':>9} {'ref int8':>9}  (ref: one {REFERENCE_KERNEL}x{REFERENCE_KERNEL} conv, GFLOP/s)")
    rows = []
    with tempfile.TemporaryDirectory(prefix="adsm-bench-towers-") as scratch:
        for channels in args.channels:
            row = measure(args.config, channels, height, width, repeats=args.repeats, threads=args.threads,
                          scratch=Path(scratch))
            rows.append(row)
            print(f"{channels:>3} {row['gflop']:>7} {row['fp32_s']:>8} {row['fp32_gflops']:>8} "
                  f"{row['int8_s']:>8} {row['int8_gflops']:>8} {row['reference_fp32_gflops']:>9} "
                  f"{row['reference_int8_gflops']:>9}", flush=True)
    if args.json:
        summary = {"size": [height, width], "threads": args.threads, "load_average_at_start": round(load, 1),
                   "load_average_at_end": round(os.getloadavg()[0], 1), "rows": rows}
        args.json.write_text(json.dumps(summary, indent=2) + "\n")
    return 0
