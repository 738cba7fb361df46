"""Build the classical NCC baseline model folder: ONNX towers whose features are normalised raw patches.

    python -m export.baseline --out service/models/ncc-baseline --measure   # window and P1/P2 by the rule
    python -m export.measure --model service/models/ncc-baseline --write --synthetic 20
    python -m export.baseline --out DIR [--window W --p1 P1 --p2 P2]     (no measurement)

Each tower: edge padding by w // 2 (inside the graph, so H, W are kept), then one convolution that
turns each pixel's w x w window of grey values (BT.601) into its w*w - 1 coordinates in an orthonormal
basis of the zero-mean windows (:func:`zero_mean_basis`), then L2 normalisation over the channels. The
coordinates of a window's zero-mean residual have its norm and its dot products, so <FL, FR> is the
normalised cross-correlation of the two windows and the runtime's cost is -scale * NCC, with one channel
fewer than the w*w taps (the mean carries no correlation): 8 for a 3x3 window, which keeps the 48 + 8
channels of adsm-rf17-ncc3-int8 a multiple of the cost volume's 8 lanes. Grey is linear, so it folds into
the same convolution. A flat window (no texture) gives a zero vector, i.e. an indifferent cost 0 at
every disparity.

It needs only `onnx` (no torch), proves the runtime end to end before a trained model exists, and stays
the baseline every trained model must beat. ``--measure`` chooses the window and its SGM penalties by
the rule every shipped model follows (see :func:`measure`: the lowest bad-2 on the synthetic validation
split, never a real pair) and records its table in the manifest's ``build.selection``; the defaults
below are that measurement's choice. The folder's figures are then recorded by ``export.measure``, as
for every model.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

from export.folder import write_folder
from service.evaluation.tuning import P1_GRID, P2_GRID, TUNING_DATA, tune_penalties
from service.features.defaults import RUNTIME_DEFAULTS
from service.features.manifest import SCHEMA_ID, TOWER_FILES, ModelError

OPSET = 17
GREY = (0.299, 0.587, 0.114)
# Added to the squared norm before the square root. One grey level of texture in one pixel of the window
# has energy (1/255)^2 ~ 1.5e-5, so textured windows keep a unit norm, while a flat window (whose
# zero-mean residual is float32 rounding, ~1e-8) maps to ~1e-5 instead of amplified rounding noise.
NORM_EPS = 1e-6
# The choice of `--measure` (table in service/models/ncc-baseline/manifest.json, build.selection).
DEFAULT_WINDOW = 7
MIN_WINDOW = 3  # a 1x1 window has no zero-mean coordinate: nothing to correlate
MAX_WINDOW = 63  # w^2 - 1 = 3968 feature channels per pixel; a larger window only exhausts memory
SGM_P1 = 65.0
SGM_P2 = 540.0


def ncc_channels(window: int) -> int:
    """Feature channels of a w x w NCC window: its zero-mean coordinates, one fewer than its taps.

    >>> ncc_channels(3)
    8
    """
    return window * window - 1


def zero_mean_basis(window: int) -> np.ndarray:
    """Orthonormal rows spanning the zero-mean w x w windows: ``(w*w - 1, w*w)``, each row orthogonal to ones.

    The Helmert basis: row k - 1 compares tap k with the mean of the taps before it, so it is fixed, exact and
    independent of any library's QR.

    >>> basis = zero_mean_basis(3)
    >>> basis.shape, bool(np.allclose(basis @ basis.T, np.eye(8))), bool(np.allclose(basis.sum(axis=1), 0))
    ((8, 9), True, True)
    """
    taps = window * window
    basis = np.zeros((ncc_channels(window), taps))
    for k in range(1, taps):
        basis[k - 1, :k] = 1.0
        basis[k - 1, k] = -k
        basis[k - 1] /= np.sqrt(k * (k + 1))
    return basis


def build_tower(window: int, *, side: str) -> onnx.ModelProto:
    """One NCC tower as an ONNX model: input ``image`` [1, 3, H, W] -> ``features`` [1, w*w - 1, H, W]."""
    if window < MIN_WINDOW or window % 2 == 0 or window > MAX_WINDOW:
        raise ValueError(f"window must be an odd size from {MIN_WINDOW} to {MAX_WINDOW}, got {window}")
    radius = window // 2
    channels = ncc_channels(window)
    # Subtracting the window mean, the change of basis and the grey conversion are all linear: one kernel.
    kernels = zero_mean_basis(window)[:, None, :] * np.asarray(GREY)[None, :, None]
    unfold = kernels.reshape(channels, 3, window, window).astype(np.float32)
    initializers = [
        numpy_helper.from_array(np.array([0, 0, radius, radius, 0, 0, radius, radius], np.int64), "pads"),
        numpy_helper.from_array(unfold, "unfold_weights"),
        numpy_helper.from_array(np.array([NORM_EPS], np.float32), "norm_eps"),
    ]
    nodes = [
        helper.make_node("Pad", ["image", "pads"], ["padded"], mode="edge", name="edge_pad"),
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
        [helper.make_tensor_value_info("features", TensorProto.FLOAT, [1, channels, "height", "width"])],
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


def _tuned_on(selection: dict | None) -> str:
    """How the folder's window and penalties were chosen, for ``sgm.tuned_on``."""
    if not selection:
        return "given (python -m export.baseline --window/--p1/--p2)"
    windows = ", ".join(f"{w}x{w}" for w in selection["windows"])
    grid = selection["grid"]
    return (f"windows {windows}, each over the grid P1 {grid['p1']} x P2 {grid['p2']}; lowest bad-2 on "
            f"{selection['data']} (python -m export.baseline --measure)")


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
        "channels": ncc_channels(window),
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
            "tuned_on": _tuned_on(selection),
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
) -> Path:
    """Write left.onnx, right.onnx and manifest.json into ``out``; returns the manifest path."""
    out = Path(out)
    towers = {name: build_tower(window, side=name.removesuffix(".onnx")).SerializeToString(deterministic=True)
              for name in TOWER_FILES}
    manifest = baseline_manifest(window=window, name=out.name, p1=p1, p2=p2, selection=selection)
    return write_folder(out, towers, manifest)


# The windows `--measure` compares: every odd side from the smallest with a texture to correlate (3x3)
# to past the largest that has ever ranked first.
WINDOWS = (3, 5, 7, 9, 11, 13)


def measure(*, pairs: int = 20, windows: Sequence[int] = WINDOWS, p1_grid: Sequence[float] = P1_GRID,
            p2_grid: Sequence[float] = P2_GRID, log: Callable[[str], Any] | None = None) -> dict[str, Any]:
    """Choose the window and its SGM penalties by the project's one rule, as every shipped model is chosen.

    Each window's P1, P2 come from :func:`service.evaluation.tuning.tune_penalties` on the synthetic
    validation split (``synthetic:pairs``, every ground-truth pixel); the window whose tuned bad-2 is lowest
    wins, EPE breaking ties. Returns the table recorded as the manifest's ``build.selection``: each
    window's choice and figures, the winner's whole grid, and ``choice`` (window, p1, p2).
    """
    import tempfile

    from service.datasets import open_dataset
    from service.features import CachedTowers, FeatureTowers
    from service.matcher import Matcher

    dataset = open_dataset(f"{TUNING_DATA.partition(':')[0]}:{pairs}")
    table: dict[str, Any] = {
        "rule": "tune_penalties for each window, then the lowest bad-2 (EPE breaks ties); export.baseline",
        "data": f"synthetic:{pairs} (the validation split), all ground-truth pixels",
        "grid": {"p1": list(p1_grid), "p2": list(p2_grid)},
        "windows": {},
    }
    grids: dict[int, list[dict[str, Any]]] = {}
    with tempfile.TemporaryDirectory() as scratch:
        for window in windows:
            folder = build_folder(Path(scratch) / f"ncc-{window}", window=window).parent
            towers = CachedTowers(FeatureTowers(folder), pairs=pairs)
            chosen, grids[window] = tune_penalties(
                Matcher(towers), dataset, p1_grid=p1_grid, p2_grid=p2_grid,
                log=None if log is None else (lambda row, window=window: log(f"window {window}: {row}")))
            table["windows"][str(window)] = next(
                row for row in grids[window] if row["p1"] == chosen["p1"] and row["p2"] == chosen["p2"])
    winner = min(windows, key=lambda w: (table["windows"][str(w)]["bad2"], table["windows"][str(w)]["epe"]))
    table["penalties"] = grids[winner]
    table["choice"] = {"window": winner, "p1": table["windows"][str(winner)]["p1"],
                       "p2": table["windows"][str(winner)]["p2"]}
    return table


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m export.baseline", description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, required=True, help="model folder to write (created if needed)")
    parser.add_argument("--window", type=int, default=DEFAULT_WINDOW, help="odd window side (%(default)s)")
    parser.add_argument("--p1", type=float, default=SGM_P1, help="SGM P1 in cost units (%(default)s)")
    parser.add_argument("--p2", type=float, default=SGM_P2, help="SGM P2 in cost units (%(default)s)")
    parser.add_argument("--measure", action="store_true",
                        help="choose the window, P1 and P2 by the project's rule (minutes; needs the train "
                        "extra's generator) instead of --window/--p1/--p2")
    args = parser.parse_args(argv)
    window, p1, p2, selection = args.window, args.p1, args.p2, None
    try:
        if args.measure:
            selection = measure(log=lambda line: print(line, file=sys.stderr))
            window, p1, p2 = (selection["choice"][key] for key in ("window", "p1", "p2"))
            print(json.dumps(selection["choice"]), file=sys.stderr)
        path = build_folder(args.out, window=window, p1=p1, p2=p2, selection=selection)
    except (OSError, ValueError, ModelError) as error:
        print(f"export.baseline: error: {error}", file=sys.stderr)
        return 1
    print(path)
    return 0


if __name__ == "__main__":
    sys.exit(main())
