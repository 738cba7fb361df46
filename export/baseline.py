"""Build the classical NCC baseline model folder: ONNX towers whose features are normalised raw patches.

    python -m export.baseline --out service/models/ncc-baseline [--window 9]

Each tower: RGB -> grey (BT.601), edge padding by w // 2 (inside the graph, so H, W are kept), the
w x w window around each pixel unfolded into w*w channels with the window mean subtracted (one
convolution whose kernels are one-hot minus 1 / w^2), then L2 normalisation over the channels. So
<FL, FR> is the normalised cross-correlation of the two windows and the runtime's cost is -scale * NCC.
A flat window (no texture) gives a zero vector, i.e. an indifferent cost 0 at every disparity.

It needs only `onnx` (no torch), proves the runtime end to end before a trained model exists, and stays
the baseline every trained model must beat. The window and the SGM penalties stored in the manifest were
chosen with ``python -m export.baseline_tuning`` on synthetic pairs (see that module's docstring).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

from service.features.manifest import TOWER_FILES, write_manifest

OPSET = 17
GREY = (0.299, 0.587, 0.114)
# Added to the squared norm before the square root. One grey level of texture in one pixel of the window
# has energy (1/255)^2 ~ 1.5e-5, so textured windows keep a unit norm, while a flat window (whose
# zero-mean residual is float32 rounding, ~1e-8) maps to ~1e-5 instead of amplified rounding noise.
NORM_EPS = 1e-6
# Selected by the measurement recorded in the manifest's "build.selection" (python -m export.baseline_tuning).
DEFAULT_WINDOW = 9
COST_SCALE = 128.0
SGM_P1 = 30.0
SGM_P2 = 160.0
DEFAULT_MAX_DISPARITY = 128


def build_tower(window: int, *, side: str) -> onnx.ModelProto:
    """One NCC tower as an ONNX model: input ``image`` [1, 3, H, W] -> ``features`` [1, w*w, H, W]."""
    if window < 1 or window % 2 == 0:
        raise ValueError(f"window must be an odd positive size, got {window}")
    radius = window // 2
    taps = window * window
    one_hot = np.eye(taps, dtype=np.float32).reshape(taps, 1, window, window)
    # Subtracting the window mean is linear, so it folds into the unfolding kernels.
    unfold = one_hot - np.float32(1.0 / taps)
    initializers = [
        numpy_helper.from_array(np.asarray(GREY, np.float32).reshape(1, 3, 1, 1), "grey_weights"),
        numpy_helper.from_array(np.array([0, 0, radius, radius, 0, 0, radius, radius], np.int64), "pads"),
        numpy_helper.from_array(unfold, "unfold_weights"),
        numpy_helper.from_array(np.array([NORM_EPS], np.float32), "norm_eps"),
    ]
    nodes = [
        helper.make_node("Conv", ["image", "grey_weights"], ["grey"], name="to_grey"),
        helper.make_node("Pad", ["grey", "pads"], ["padded"], mode="edge", name="edge_pad"),
        helper.make_node("Conv", ["padded", "unfold_weights"], ["patches"], name="unfold_zero_mean"),
        helper.make_node("ReduceSumSquare", ["patches"], ["energy"], axes=[1], keepdims=1, name="energy"),
        helper.make_node("Add", ["energy", "norm_eps"], ["energy_eps"], name="regularise"),
        helper.make_node("Sqrt", ["energy_eps"], ["norm"], name="norm"),
        helper.make_node("Div", ["patches", "norm"], ["features"], name="l2_normalise"),
    ]
    graph = helper.make_graph(
        nodes,
        f"ncc_{window}x{window}_{side}",
        [helper.make_tensor_value_info("image", TensorProto.FLOAT, [1, 3, "height", "width"])],
        [helper.make_tensor_value_info("features", TensorProto.FLOAT, [1, taps, "height", "width"])],
        initializer=initializers,
    )
    model = helper.make_model(
        graph,
        opset_imports=[helper.make_opsetid("", OPSET)],
        producer_name="adsm export.baseline",
        doc_string=f"NCC baseline {side} tower: zero-mean, L2-normalised {window}x{window} grey windows",
    )
    model.ir_version = 8  # the oldest IR that opset 17 allows: loads in older ONNX Runtime builds too
    onnx.checker.check_model(model, full_check=True)
    return model


def baseline_manifest(*, window: int, name: str, selection: dict | None = None) -> dict:
    """The manifest (without ``files``, which write_manifest fills from the written towers)."""
    build: dict = {"command": f"python -m export.baseline --out <folder> --window {window}"}
    if selection:
        build["selection"] = selection
    return {
        "schema": "adsm-model/1",
        "name": name,
        "description": (
            f"Classical baseline: normalised cross-correlation of {window}x{window} grey windows. "
            "Not trained; every trained model must beat it."
        ),
        "config": f"ncc-{window}x{window}",
        "channels": window * window,
        "receptive_field": window,
        "shared_towers": True,
        "input": {"color": "rgb", "range": [0.0, 1.0], "mean": [0.0, 0.0, 0.0], "std": [1.0, 1.0, 1.0]},
        "cost": {
            "scale": COST_SCALE,
            "definition": "CL[y, x, d] = -scale * NCC(window_L(y, x), window_R(y, x - d)); "
            "x - d < 0 -> +scale",
            "dtype": "float32",
        },
        "sgm": {
            "p1": SGM_P1,
            "p2": SGM_P2,
            "paths": 4,
            "tuned_on": "synthetic slanted-plane pairs with occluding boxes (export.baseline_tuning)",
        },
        "disparity": {"default_max": DEFAULT_MAX_DISPARITY, "trained_range": [0, 0]},
        "onnx": {"opset": OPSET, "precision": "fp32", "exporter": f"onnx {onnx.__version__} helper API"},
        "training": None,
        "build": build,
        "metrics": {},
    }


def build_folder(out: str | Path, *, window: int = DEFAULT_WINDOW, metrics: dict | None = None) -> Path:
    """Write left.onnx, right.onnx and manifest.json into ``out``; returns the manifest path."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    for file_name in TOWER_FILES:
        model = build_tower(window, side=file_name.removesuffix(".onnx"))
        (out / file_name).write_bytes(model.SerializeToString(deterministic=True))
    manifest = baseline_manifest(window=window, name=out.name)
    if metrics:
        manifest["metrics"] = metrics
    return write_manifest(out, manifest)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m export.baseline", description=__doc__.splitlines()[0])
    parser.add_argument("--out", required=True, type=Path, help="model folder to write (created if needed)")
    parser.add_argument(
        "--window", type=int, default=DEFAULT_WINDOW, help="odd window side (default: %(default)s)"
    )
    args = parser.parse_args(argv)
    try:
        path = build_folder(args.out, window=args.window)
    except (OSError, ValueError) as error:
        print(f"export.baseline: error: {error}", file=sys.stderr)
        return 1
    print(path)
    return 0


if __name__ == "__main__":
    sys.exit(main())
