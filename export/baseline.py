"""Build the classical NCC baseline model folder: ONNX towers whose features are normalised raw patches.

    python -m export.baseline --out service/models/ncc-baseline --measure --evaluate CONES_FOLDER
    python -m export.baseline --out DIR [--window W --p1 P1 --p2 P2]     (no measurement)

Each tower: RGB -> grey (BT.601), edge padding by w // 2 (inside the graph, so H, W are kept), the
w x w window around each pixel unfolded into w*w channels with the window mean subtracted (one
convolution whose kernels are one-hot minus 1 / w^2), then L2 normalisation over the channels. So
<FL, FR> is the normalised cross-correlation of the two windows and the runtime's cost is -scale * NCC.
A flat window (no texture) gives a zero vector, i.e. an indifferent cost 0 at every disparity.

It needs only `onnx` (no torch), proves the runtime end to end before a trained model exists, and stays
the baseline every trained model must beat. ``--measure`` chooses the window and the SGM penalties on
synthetic pairs from the project's generator (see :func:`measure`) and records its table in the
manifest's ``build.selection``; the defaults below are that measurement's choice. ``--evaluate`` records
bad-2/bad-3/EPE on a Middlebury-style folder (evaluation only: nothing is chosen from it).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

from export.folder import write_folder
from service.features.defaults import RUNTIME_DEFAULTS
from service.features.manifest import SCHEMA_ID, TOWER_FILES, ModelError

OPSET = 17
GREY = (0.299, 0.587, 0.114)
# Added to the squared norm before the square root. One grey level of texture in one pixel of the window
# has energy (1/255)^2 ~ 1.5e-5, so textured windows keep a unit norm, while a flat window (whose
# zero-mean residual is float32 rounding, ~1e-8) maps to ~1e-5 instead of amplified rounding noise.
NORM_EPS = 1e-6
# The choice of `--measure` (table in service/models/ncc-baseline/manifest.json, build.selection).
DEFAULT_WINDOW = 9
MAX_WINDOW = 63  # w^2 = 3969 feature channels per pixel; a larger window only exhausts memory
SGM_P1 = 65.0
SGM_P2 = 360.0


def build_tower(window: int, *, side: str) -> onnx.ModelProto:
    """One NCC tower as an ONNX model: input ``image`` [1, 3, H, W] -> ``features`` [1, w*w, H, W]."""
    if window < 1 or window % 2 == 0 or window > MAX_WINDOW:
        raise ValueError(f"window must be an odd positive size up to {MAX_WINDOW}, got {window}")
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


def baseline_manifest(
    *, window: int, name: str, p1: float = SGM_P1, p2: float = SGM_P2, selection: dict | None = None
) -> dict:
    """The manifest (without ``files``, which write_manifest fills from the written towers)."""
    build: dict = {
        "command": f"python -m export.baseline --out <folder> --window {window} --p1 {p1} --p2 {p2}"
    }
    if selection:
        build["command"] = "python -m export.baseline --out <folder> --measure"
        build["selection"] = selection
    return {
        "schema": SCHEMA_ID,
        "name": name,
        "description": (
            f"Classical baseline: normalised cross-correlation of {window}x{window} grey windows. "
            "Not trained; every trained model must beat it."
        ),
        "config": f"ncc-{window}x{window}",
        "channels": window * window,
        "receptive_field": window,
        "shared_towers": True,
        "input": RUNTIME_DEFAULTS.input(),
        "cost": {
            "scale": RUNTIME_DEFAULTS.cost_scale,  # NCC 1 -> cost -128
            "definition": "CL[y, x, d] = -scale * NCC(window_L(y, x), window_R(y, x - d)); "
            "x - d < 0 -> +scale",
            "dtype": "int16",
        },
        "sgm": {
            "p1": p1,
            "p2": p2,
            "paths": 4,
            "tuned_on": "synthetic pairs of training.data.synthetic (python -m export.baseline --measure)",
        },
        "disparity": {"default_max": RUNTIME_DEFAULTS.default_max, "trained_range": [0, 0]},
        "onnx": {"opset": OPSET, "precision": "fp32", "exporter": "onnx helper API (export/baseline.py)"},
        "training": None,
        "build": build,
        "metrics": {},
    }


def build_folder(
    out: str | Path,
    *,
    window: int = DEFAULT_WINDOW,
    p1: float = SGM_P1,
    p2: float = SGM_P2,
    selection: dict | None = None,
    metrics: dict | None = None,
) -> Path:
    """Write left.onnx, right.onnx and manifest.json into ``out``; returns the manifest path."""
    out = Path(out)
    towers = {name: build_tower(window, side=name.removesuffix(".onnx")).SerializeToString(deterministic=True)
              for name in TOWER_FILES}
    manifest = baseline_manifest(window=window, name=out.name, p1=p1, p2=p2, selection=selection)
    if metrics:
        manifest["metrics"] = metrics
    return write_folder(out, towers, manifest)


# The measurement that chose DEFAULT_WINDOW: synthetic pairs from the project's generator (seeds from
# TUNING_SEED, far from the validation split), never a real pair with ground truth. SGM_P1 and SGM_P2 are
# then chosen by the rule every shipped model follows (service.evaluation.tuning).
TUNING_SEED = 700_000_000
WINDOWS = (5, 7, 9, 11, 13)
# The window is chosen at the paper's P1, P2 (the runtime defaults), then the penalties at it.
PAPER_PENALTIES = (RUNTIME_DEFAULTS.p1, RUNTIME_DEFAULTS.p2)
# Cost-volume work grows with w^2, so a larger window must beat a smaller one by more than this (bad-2, %).
WINDOW_MARGIN = 0.5


def measure(*, pairs: int = 8, height: int = 192, width: int = 384, max_disparity: int = 96) -> dict:
    """Mean bad-1/bad-2 (%) on non-occluded pixels for each window at the paper's penalties, the smallest
    window within WINDOW_MARGIN of the best; then P1, P2 at that window by the shared tuning rule
    (:func:`service.evaluation.tuning.tune_penalties` on the synthetic validation split)."""
    import tempfile

    from service.datasets import open_dataset
    from service.evaluation import count_errors
    from service.evaluation.tuning import TUNING_DATA, tune_penalties
    from service.matcher import Matcher, MatchOptions
    from training.data.synthetic import SyntheticConfig, generate

    config = SyntheticConfig(height=height, width=width, max_disparity=max_disparity * 3 // 4)
    samples = [generate(TUNING_SEED + index, config) for index in range(pairs)]

    def score(matcher: Matcher, p1: float, p2: float) -> dict:
        bad1, bad2 = [], []
        for sample in samples:
            options = MatchOptions(max_disparity=max_disparity, p1=p1, p2=p2)
            disparity = matcher(sample.left, sample.right, options).disparity
            figures = count_errors(disparity, sample.disparity, sample.nonoccluded).summary()
            bad1.append(figures["bad1"])
            bad2.append(figures["bad2"])
        return {"p1": p1, "p2": p2, "bad1": round(sum(bad1) / pairs, 2), "bad2": round(sum(bad2) / pairs, 2)}

    table: dict = {"pairs": f"synthetic seeds {TUNING_SEED}..{TUNING_SEED + pairs - 1}, {height}x{width}, "
                   f"D={max_disparity}, non-occluded pixels", "windows": {}, "penalties": []}
    with tempfile.TemporaryDirectory() as scratch:
        for window in WINDOWS:
            folder = build_folder(Path(scratch) / f"ncc-{window}", window=window).parent
            table["windows"][window] = score(Matcher.from_folder(folder), *PAPER_PENALTIES)
            print(f"window {window}: {table['windows'][window]}", file=sys.stderr)
        lowest = min(row["bad2"] for row in table["windows"].values())
        best = min(w for w in WINDOWS if table["windows"][w]["bad2"] <= lowest + WINDOW_MARGIN)
        matcher = Matcher.from_folder(build_folder(Path(scratch) / "best", window=best).parent)
        def log(row: str) -> None:
            print(f"window {best}: {row}", file=sys.stderr)

        chosen, table["penalties"] = tune_penalties(matcher, open_dataset(TUNING_DATA), log=log)
    table["penalties_on"] = f"{TUNING_DATA} (the validation split), all ground-truth pixels, bad-2"
    table["choice"] = {"window": best, "p1": chosen["p1"], "p2": chosen["p2"]}
    return table


def evaluate(folder: Path, pairs_folder: Path) -> dict:
    """bad-2, bad-3 (%) and EPE of the model folder on each pair of a Middlebury-style folder (all pixels
    with ground truth, and the non-occluded ones), the runtime's defaults, D = the dataset's range; the
    figures of ``adsm eval`` (service.evaluation), rounded for the manifest."""
    from service.datasets.readers import cones
    from service.evaluation.evaluate import evaluate as run
    from service.matcher import Matcher

    matcher, metrics = Matcher.from_folder(folder), {}
    matcher.warmup()  # seconds without JIT compilation, as adsm eval reports them
    for pair in run(matcher, cones(pairs_folder))["per_pair"]:
        row = {"max_disparity": pair["max_disparity"], "seconds": round(pair["seconds"], 3)}
        for suffix, figures in (("", pair["all"]), ("_nonocc", pair["nonoccluded"])):
            if figures is not None:
                row[f"bad2{suffix}"] = round(figures["bad2"], 2)
                row[f"bad3{suffix}"] = round(figures["bad3"], 2)
                row[f"epe{suffix}"] = round(figures["epe"], 3)
        metrics[pair["name"]] = row
    return metrics


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m export.baseline", description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, required=True, help="model folder to write (created if needed)")
    parser.add_argument("--window", type=int, default=DEFAULT_WINDOW, help="odd window side (%(default)s)")
    parser.add_argument("--p1", type=float, default=SGM_P1, help="SGM P1 in cost units (%(default)s)")
    parser.add_argument("--p2", type=float, default=SGM_P2, help="SGM P2 in cost units (%(default)s)")
    parser.add_argument("--measure", action="store_true", help="choose window, P1, P2 by the measurement")
    parser.add_argument("--evaluate", type=Path, metavar="DIR", help="record metrics on a Middlebury folder")
    args = parser.parse_args(argv)
    window, p1, p2, selection = args.window, args.p1, args.p2, None
    try:
        if args.measure:
            selection = measure()
            window, p1, p2 = (selection["choice"][key] for key in ("window", "p1", "p2"))
        path = build_folder(args.out, window=window, p1=p1, p2=p2, selection=selection)
        if args.evaluate is not None:
            metrics = evaluate(args.out, args.evaluate)
            path = build_folder(args.out, window=window, p1=p1, p2=p2, selection=selection, metrics=metrics)
            print(json.dumps(metrics))
    except (OSError, ValueError, ModelError) as error:
        print(f"export.baseline: error: {error}", file=sys.stderr)
        return 1
    print(path)
    return 0


if __name__ == "__main__":
    sys.exit(main())
