"""Build a hybrid model folder: a trained model's towers and an NCC window in one matching cost.

    python -m export.hybrid --learned service/models/adsm-fast-int8 --window 3 --ncc-weight 0.3 --out DIR
    python -m export.hybrid ... --p1 P1 --p2 P2        (penalties; default: the learned folder's)
    python -m export.hybrid ... --tune                 (P1/P2 by the shared rule: export.tune)

Each hybrid tower runs the learned tower and the NCC tower of ``export.baseline`` on the same input and
concatenates their unit-norm features scaled by sqrt(1 - w) and sqrt(w) (w = ``--ncc-weight``). The
runtime's cost is -scale times the dot product of the two views' features, so it becomes exactly

    CL[y, x, d] = -scale * ((1 - w) * <FL, FR>_learned + w * NCC_window(L(y, x), R(y, x - d)))

with no change to the runtime: a blend of costs that fail differently. The learned towers (17 px and
more) bring context where the image is flat and their training; the small NCC window keeps the cost sharp
at depth edges, where a wide receptive field fattens the foreground (docs/training.md, "Hybrid cost").
The NCC branch stays float32 in an int8 folder (9 taps of a 3x3 window: no work worth quantising).
The manifest keeps the learned folder's training provenance and records the build in ``build``.
"""

from __future__ import annotations

import argparse
import copy
import math
import shlex
import sys
from pathlib import Path
from typing import Any

import numpy as np
import onnx
from onnx import helper, numpy_helper

from export.baseline import build_tower
from export.tune import tune_folder
from service.features.manifest import TOWER_FILES, ModelError, load_manifest, write_manifest

FEATURES = "features"
NCC_PREFIX = "ncc/"
LEARNED_FEATURES = "learned/features"
ENERGY = NCC_PREFIX + "energy"  # export.baseline's node output: the window's zero-mean energy


def combine_towers(learned: onnx.ModelProto, ncc: onnx.ModelProto, *, ncc_weight: float,
                   texture_energy: float | None = None) -> onnx.ModelProto:
    """One graph: ``image`` -> concat(sqrt(1 - w) * learned features, sqrt(w) * NCC features).

    Both inputs map ``image`` [1, 3, H, W] to unit-norm ``features`` [1, C, H, W]; so does the result,
    with C the sum of theirs. ``texture_energy`` E0 makes the share depend on the pixel: w(x) = w * E /
    (E + E0), E the zero-mean energy of the pixel's NCC window, so flat windows (where noise decides a
    small window's correlation) lean on the learned features.
    """
    if not 0.0 < ncc_weight < 1.0:
        raise ValueError(f"the NCC weight must lie strictly between 0 and 1, got {ncc_weight}")
    if texture_energy is not None and not texture_energy > 0.0:
        raise ValueError(f"the texture energy must be positive, got {texture_energy}")
    combined = copy.deepcopy(learned)
    graph = combined.graph
    (image,) = (value.name for value in graph.input)
    for node in graph.node:
        node.output[:] = [LEARNED_FEATURES if name == FEATURES else name for name in node.output]
    ncc_graph = onnx.compose.add_prefix_graph(ncc.graph, NCC_PREFIX, rename_inputs=False)
    for node in ncc_graph.node:
        node.input[:] = [image if name == ncc.graph.input[0].name else name for name in node.input]
    graph.node.extend(ncc_graph.node)
    graph.initializer.extend(ncc_graph.initializer)
    ncc_channels = ncc.graph.output[0].type.tensor_type.shape.dim[1].dim_value
    learned_channels = graph.output[0].type.tensor_type.shape.dim[1].dim_value
    if texture_energy is None:
        graph.initializer.extend([
            numpy_helper.from_array(_scalar(math.sqrt(1.0 - ncc_weight)), "learned_share"),
            numpy_helper.from_array(_scalar(math.sqrt(ncc_weight)), "ncc_share"),
        ])
    else:
        graph.initializer.extend([numpy_helper.from_array(_scalar(value), name) for name, value in (
            ("blend/ncc_weight", ncc_weight), ("blend/texture_energy", texture_energy), ("blend/one", 1.0))])
        graph.node.extend([
            helper.make_node("Add", [ENERGY, "blend/texture_energy"], ["blend/energy_e0"],
                             name="blend_energy"),
            helper.make_node("Div", [ENERGY, "blend/energy_e0"], ["blend/textured"], name="blend_textured"),
            helper.make_node("Mul", ["blend/textured", "blend/ncc_weight"], ["blend/w"], name="blend_weight"),
            helper.make_node("Sub", ["blend/one", "blend/w"], ["blend/1-w"], name="blend_rest"),
            helper.make_node("Sqrt", ["blend/w"], ["ncc_share"], name="ncc_share_sqrt"),
            helper.make_node("Sqrt", ["blend/1-w"], ["learned_share"], name="learned_share_sqrt"),
        ])
    graph.node.extend([
        helper.make_node("Mul", [LEARNED_FEATURES, "learned_share"], ["learned/scaled"],
                         name="learned_share"),
        helper.make_node("Mul", [ncc_graph.output[0].name, "ncc_share"], ["ncc/scaled"], name="ncc_share"),
        helper.make_node("Concat", ["learned/scaled", "ncc/scaled"], [FEATURES], axis=1, name="blend"),
    ])
    graph.output[0].type.tensor_type.shape.dim[1].dim_value = learned_channels + ncc_channels
    graph.name = f"{graph.name}+{ncc.graph.name}"
    share = f"{ncc_weight:g}" if texture_energy is None else f"{ncc_weight:g} E / (E + {texture_energy:g})"
    combined.doc_string = f"hybrid tower: features of the learned cosine and of NCC ({ncc.graph.name}), " \
                          f"NCC share {share}"
    onnx.checker.check_model(combined, full_check=True)
    return combined


def hybrid_manifest(learned: dict[str, Any], *, name: str, window: int, ncc_weight: float,
                    texture_energy: float | None = None, p1: float, p2: float, tuned_on: str,
                    command: str) -> dict[str, Any]:
    """The hybrid folder's manifest (``files`` and ``metrics`` filled later), from the learned one's."""
    manifest = {key: copy.deepcopy(value) for key, value in learned.items()
                if key not in ("files", "metrics")}
    share = f"{ncc_weight:g}" if texture_energy is None else f"{ncc_weight:g} E / (E + {texture_energy:g})"
    manifest |= {
        "name": name,
        "description": (f"{learned.get('description', learned['config'])}, blended with the NCC of "
                        f"{window}x{window} grey windows: cost = (1 - w) x learned cosine + w x NCC, "
                        f"w = {share}"),
        "config": f"{learned['config']}+ncc-{window}x{window}",
        "channels": learned["channels"] + window * window,
        "receptive_field": max(learned["receptive_field"], window),
        "sgm": {"p1": p1, "p2": p2, "paths": 4, "tuned_on": tuned_on},
        "build": {"command": command, "learned": learned["name"], "ncc_window": window,
                  "ncc_weight": ncc_weight, "texture_energy": texture_energy,
                  "learned_build": learned.get("build")},
        "metrics": {},
    }
    manifest["cost"]["definition"] = (
        f"CL[y, x, d] = -scale * <FL, FR>, F = [sqrt(1 - w) F_learned, sqrt(w) F_ncc{window}x{window}], "
        f"w = {share}: for a constant w, (1 - w) learned cosine + w NCC; x - d < 0 -> +scale")
    return manifest


def build_folder(out: str | Path, *, learned: str | Path, window: int, ncc_weight: float,
                 texture_energy: float | None = None, p1: float | None = None, p2: float | None = None,
                 tuned_on: str | None = None, command: str = "") -> Path:
    """Write the hybrid left.onnx, right.onnx and manifest.json into ``out``; returns the manifest path.

    ``p1``/``p2`` default to the learned folder's penalties.
    """
    learned_manifest = load_manifest(learned)  # validated; the towers' hashes are checked on loading
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    for file_name in TOWER_FILES:
        side = file_name.removesuffix(".onnx")
        tower = combine_towers(onnx.load(Path(learned) / file_name), build_tower(window, side=side),
                               ncc_weight=ncc_weight, texture_energy=texture_energy)
        (out / file_name).write_bytes(tower.SerializeToString(deterministic=True))
    sgm = learned_manifest["sgm"]
    chosen_p1, chosen_p2 = (sgm["p1"] if p1 is None else p1), (sgm["p2"] if p2 is None else p2)
    if tuned_on is None:
        tuned_on = (f"the learned folder's ({learned_manifest['name']})" if (p1, p2) == (None, None)
                    else "given on the command line")
    manifest = hybrid_manifest(learned_manifest, name=out.name, window=window, ncc_weight=ncc_weight,
                               texture_energy=texture_energy, p1=chosen_p1, p2=chosen_p2, tuned_on=tuned_on,
                               command=command)
    return write_manifest(out, manifest)


def _scalar(value: float) -> np.ndarray:
    return np.asarray([value], np.float32)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m export.hybrid", description=__doc__.splitlines()[0])
    parser.add_argument("--learned", type=Path, required=True, metavar="DIR", help="a trained model folder")
    parser.add_argument("--window", type=int, default=3, help="odd NCC window side (%(default)s)")
    parser.add_argument("--ncc-weight", type=float, required=True, metavar="W",
                        help="the NCC share w of the cost, 0 < w < 1")
    parser.add_argument("--texture-energy", type=float, metavar="E0",
                        help="make the NCC share w * E / (E + E0), E the window's zero-mean energy "
                             "(default: a constant share w)")
    parser.add_argument("--out", type=Path, required=True, help="model folder to write (created if needed)")
    parser.add_argument("--p1", type=float, help="SGM P1 (default: the learned folder's)")
    parser.add_argument("--p2", type=float, help="SGM P2 (default: the learned folder's)")
    parser.add_argument("--tune", action="store_true", help="choose P1/P2 on the synthetic validation split")
    args = parser.parse_args(argv)
    command = shlex.join(["python", "-m", "export.hybrid", *(sys.argv[1:] if argv is None else argv)])
    try:
        if args.tune and (args.p1 is not None or args.p2 is not None):
            raise ValueError("--tune chooses P1 and P2: give either --tune or --p1/--p2")
        options = dict(learned=args.learned, window=args.window, ncc_weight=args.ncc_weight,
                       texture_energy=args.texture_energy, command=command)
        path = build_folder(args.out, p1=args.p1, p2=args.p2, **options)
        if args.tune:
            choice, tuned_on = tune_folder(args.out, log=lambda row: print(row, file=sys.stderr))
            path = build_folder(args.out, p1=choice["p1"], p2=choice["p2"], tuned_on=tuned_on, **options)
    except (OSError, ValueError, ModelError) as error:
        print(f"export.hybrid: error: {error}", file=sys.stderr)
        return 1
    print(path)
    return 0


if __name__ == "__main__":
    sys.exit(main())
