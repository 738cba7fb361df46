"""Build a hybrid model folder: a trained model's towers and a second, "core" tower in one matching cost.

    python -m export.hybrid --learned service/models/adsm-fast-int8 --window 3 --core-weight 0.3 --out DIR
    python -m export.hybrid --learned DIR_A --core DIR_B --core-weight 0.5 --out DIR   (two trained folders)
    python -m export.hybrid ... --p1 P1 --p2 P2        (penalties; default: the learned folder's)
    python -m export.hybrid ... --tune                 (P1/P2 by the shared rule: export.tune)
    python -m export.hybrid --learned DIR --gate runs/gate/NAME/gate.json --out DIR   (a learned share)

The core is an NCC window (the tower of ``export.baseline``, ``--window``) or another trained folder's
towers (``--core``). Each hybrid tower runs both towers on the same input and concatenates their
unit-norm features scaled by sqrt(1 - w) and sqrt(w) (w = ``--core-weight``). The runtime's cost is
-scale times the dot product of the two views' features, so it becomes exactly

    CL[y, x, d] = -scale * ((1 - w) * <FL, FR>_learned + w * <FL, FR>_core)

with no change to the runtime: a blend of costs that fail differently. With an NCC core the second term
is NCC_window(L(y, x), R(y, x - d)): the small window keeps the cost sharp at depth edges, where a wide
receptive field fattens the foreground (docs/training.md, "Hybrid cost"); it stays float32 in an int8
folder (8 zero-mean coordinates of a 3x3 window: no work worth quantising). With a trained core of
another receptive field the blend is an ensemble of two learned costs (docs/training.md, "Small towers
with today's runtime, and ensembles of towers"). The manifest keeps the learned folder's training
provenance, records the core's in ``build.core_training`` and the build in ``build``. With ``--gate`` (an
NCC core) the share is learned per pixel by ``python -m training.gate`` (training/networks/gate.py): w(x)
= sigmoid(a . [learned features, NCC window, log(E + eps)] + b), recorded with its training in
``build.gate``.
"""

from __future__ import annotations

import argparse
import copy
import json
import math
import shlex
import sys
from pathlib import Path
from typing import Any

import numpy as np
import onnx
from onnx import helper, numpy_helper

from export.baseline import NORM_EPS, build_tower, ncc_channels
from export.folder import read_graph, write_folder
from export.tune import tune_folder
from service.features.manifest import TOWER_FILES, ModelError, load_manifest, verify_files

FEATURES = "features"
CORE_PREFIX = "core/"
LEARNED_FEATURES = "learned/features"
ENERGY = CORE_PREFIX + "energy"  # export.baseline's node output: the NCC window's zero-mean energy
GATE_SCHEMA = "adsm-gate/1"  # what python -m training.gate writes


def combine_towers(learned: onnx.ModelProto, core: onnx.ModelProto, *, core_weight: float | None,
                   texture_energy: float | None = None,
                   gate: dict[str, Any] | None = None) -> onnx.ModelProto:
    """One graph: ``image`` -> concat(sqrt(1 - w) * learned features, sqrt(w) * core features).

    Both inputs map ``image`` [1, 3, H, W] to unit-norm ``features`` [1, C, H, W]; so does the result,
    with C the sum of theirs. ``texture_energy`` E0 (an NCC core only) makes the share depend on the
    pixel: w(x) = w * E / (E + E0), E the zero-mean energy of the pixel's NCC window, so flat windows
    (where noise decides a small window's correlation) lean on the learned features. ``gate`` (an NCC
    core, instead of ``core_weight``): the learned share of ``training.gate``'s gate.json.
    """
    if gate is not None:
        if core_weight is not None or texture_energy is not None:
            raise ValueError("a learned gate sets the share: give no core weight or texture energy with it")
    elif core_weight is None or not 0.0 < core_weight < 1.0:
        raise ValueError(f"the core weight must lie strictly between 0 and 1, got {core_weight}")
    if texture_energy is not None and not texture_energy > 0.0:
        raise ValueError(f"the texture energy must be positive, got {texture_energy}")
    if _opset(learned) != _opset(core):
        raise ValueError(f"the towers' opsets differ ({_opset(learned)} and {_opset(core)}): "
                         "export them alike")
    combined = copy.deepcopy(learned)
    graph = combined.graph
    (image,) = (value.name for value in graph.input)
    for node in graph.node:
        node.output[:] = [LEARNED_FEATURES if name == FEATURES else name for name in node.output]
    core_graph = onnx.compose.add_prefix_graph(core.graph, CORE_PREFIX, rename_inputs=False)
    for node in core_graph.node:
        node.input[:] = [image if name == core.graph.input[0].name else name for name in node.input]
    if (texture_energy is not None or gate is not None) and not any(ENERGY in node.output
                                                                   for node in core_graph.node):
        raise ValueError("a texture-adaptive or learned share needs an NCC core (--window): it reads the "
                         "window's energy")
    graph.node.extend(core_graph.node)
    graph.initializer.extend(core_graph.initializer)
    core_channels = core.graph.output[0].type.tensor_type.shape.dim[1].dim_value
    learned_channels = graph.output[0].type.tensor_type.shape.dim[1].dim_value
    core_features = core_graph.output[0].name
    if gate is None and texture_energy is None:
        assert core_weight is not None
        learned_out = _scale_normalised(graph, LEARNED_FEATURES, math.sqrt(1.0 - core_weight), "learned")
        core_out = _scale_normalised(graph, core_features, math.sqrt(core_weight), "core")
    else:  # a per-pixel share: blend/w, then learned_share and core_share
        if gate is not None:
            _gate_nodes(graph, gate, learned_channels=learned_channels, core_channels=core_channels,
                        core_features=core_features)
        else:
            graph.initializer.extend([numpy_helper.from_array(_scalar(value), name) for name, value in (
                ("blend/core_weight", core_weight), ("blend/texture_energy", texture_energy))])
            graph.node.extend([
                helper.make_node("Add", [ENERGY, "blend/texture_energy"], ["blend/energy_e0"],
                                 name="blend_energy"),
                helper.make_node("Div", [ENERGY, "blend/energy_e0"], ["blend/textured"],
                                 name="blend_textured"),
                helper.make_node("Mul", ["blend/textured", "blend/core_weight"], ["blend/w"],
                                 name="blend_weight"),
            ])
            _share_nodes(graph)
        learned_out, core_out = "learned/scaled", "core/scaled"
        graph.node.extend([
            helper.make_node("Mul", [LEARNED_FEATURES, "learned_share"], [learned_out], name="learned_share"),
            helper.make_node("Mul", [core_features, "core_share"], [core_out], name="core_share"),
        ])
    graph.node.append(helper.make_node("Concat", [learned_out, core_out], [FEATURES], axis=1, name="blend"))
    graph.output[0].type.tensor_type.shape.dim[1].dim_value = learned_channels + core_channels
    graph.name = f"{graph.name}+{core.graph.name}"
    share = _share_text(core_weight, texture_energy, gate)
    combined.doc_string = (f"hybrid tower: features of the learned cosine and of the core "
                           f"({core.graph.name}), core share {share}")
    onnx.checker.check_model(combined, full_check=True)
    return combined


def _scale_normalised(graph: onnx.GraphProto, features: str, share: float, branch: str) -> str:
    """``share`` x ``features`` for a constant share; returns the scaled tensor's name.

    Both exporters end a tower with ``Div(features, norm)``; dividing by ``norm / share`` instead scales
    the features at the cost of one channel (the norm) rather than every channel: the blend then costs
    only its concatenation (adsm-rf17-int8 + NCC 3x3: elementwise passes over its 48 and 9 channels fewer
    per view). Any other last node is followed by a Div by 1 / share.
    """
    inverse = f"{branch}/inverse_share"
    graph.initializer.append(numpy_helper.from_array(_scalar(1.0 / share), inverse))
    nodes = list(graph.node)
    index, producer = next((i, node) for i, node in enumerate(nodes) if features in node.output)
    if producer.op_type == "Div":
        scaled_norm = f"{branch}/norm_over_share"
        # Before the Div that reads it: ONNX wants the nodes in topological order.
        nodes.insert(index, helper.make_node("Mul", [producer.input[1], inverse], [scaled_norm],
                                             name=f"{branch}_norm_over_share"))
        producer.input[1] = scaled_norm
        del graph.node[:]
        graph.node.extend(nodes)
        return features
    graph.node.append(helper.make_node("Div", [features, inverse], [f"{branch}/scaled"],
                                       name=f"{branch}_share"))
    return f"{branch}/scaled"


def _gate_nodes(graph: onnx.GraphProto, gate: dict[str, Any], *, learned_channels: int, core_channels: int,
                core_features: str) -> None:
    """w = sigmoid(1x1 conv of [learned, core, log(E + eps)]) and the two shares: training.networks.gate."""
    inputs = learned_channels + core_channels + 1
    trained_for = ncc_channels(int(gate["window"]))
    if int(gate["learned_channels"]) != learned_channels or trained_for != core_channels:
        raise ValueError(f"the gate was trained for {gate['learned_channels']} learned channels and a "
                         f"{gate['window']}x{gate['window']} window, not {learned_channels} and "
                         f"{core_channels} NCC channels")
    weight = np.asarray(gate["weight"], np.float32)
    if weight.size != inputs:
        raise ValueError(f"the gate has {weight.size} weights; {inputs} expected")
    graph.initializer.extend([
        numpy_helper.from_array(weight.reshape(1, inputs, 1, 1), "gate/weight"),
        numpy_helper.from_array(_scalar(float(gate["bias"])), "gate/bias"),
        numpy_helper.from_array(_scalar(NORM_EPS), "gate/eps"),
    ])
    graph.node.extend([
        helper.make_node("Add", [ENERGY, "gate/eps"], ["gate/energy_eps"], name="gate_energy"),
        helper.make_node("Log", ["gate/energy_eps"], ["gate/log_energy"], name="gate_log_energy"),
        helper.make_node("Concat", [LEARNED_FEATURES, core_features, "gate/log_energy"], ["gate/inputs"],
                         axis=1, name="gate_inputs"),
        helper.make_node("Conv", ["gate/inputs", "gate/weight", "gate/bias"], ["gate/logit"], name="gate"),
        helper.make_node("Sigmoid", ["gate/logit"], ["blend/w"], name="gate_share"),
    ])
    _share_nodes(graph)


def _share_nodes(graph: onnx.GraphProto) -> None:
    """A per-pixel share ``blend/w`` -> ``core_share`` sqrt(w) and ``learned_share`` sqrt(1 - w)."""
    graph.initializer.append(numpy_helper.from_array(_scalar(1.0), "blend/one"))
    graph.node.extend([
        helper.make_node("Sub", ["blend/one", "blend/w"], ["blend/1-w"], name="blend_rest"),
        helper.make_node("Sqrt", ["blend/w"], ["core_share"], name="core_share_sqrt"),
        helper.make_node("Sqrt", ["blend/1-w"], ["learned_share"], name="learned_share_sqrt"),
    ])


def hybrid_manifest(learned: dict[str, Any], *, name: str, core_weight: float | None,
                    window: int | None = None, core: dict[str, Any] | None = None,
                    texture_energy: float | None = None, gate: dict[str, Any] | None = None, p1: float,
                    p2: float, tuned_on: str, command: str) -> dict[str, Any]:
    """The hybrid folder's manifest (``files`` and ``metrics`` filled later), from the learned one's.

    The core is an NCC ``window`` or the manifest of a trained ``core`` folder (exactly one of them).
    """
    if (window is None) == (core is None):
        raise ValueError("give the core as an NCC window or as a trained folder's manifest, not both")
    manifest = {key: copy.deepcopy(value) for key, value in learned.items()
                if key not in ("files", "metrics")}
    share = _share_text(core_weight, texture_energy, gate)
    if core is None:
        assert window is not None
        core_name, core_config = f"NCC of {window}x{window} grey windows", f"ncc-{window}x{window}"
        core_channels, core_field, core_label = ncc_channels(window), window, f"ncc{window}x{window}"
    else:
        core_name, core_config = f"the towers of {core['name']}", core["config"]
        core_channels, core_field, core_label = core["channels"], core["receptive_field"], "core"
        if core["input"] != learned["input"]:
            raise ValueError(f"the core expects other input ({core['input']}) than the learned towers "
                             f"({learned['input']})")
        manifest["shared_towers"] = bool(learned.get("shared_towers") and core.get("shared_towers"))
        if core["onnx"]["precision"] != learned["onnx"]["precision"]:
            # One figure bounds the work area of both branches (service.features.tiles): the larger.
            manifest["onnx"]["precision"] = "int8"
    manifest |= {
        "name": name,
        "description": (f"{learned.get('description', learned['config'])}, blended with {core_name}: "
                        f"cost = (1 - w) x learned cosine + w x core cosine, w = {share}"),
        "config": f"{learned['config']}+{core_config}",
        "channels": learned["channels"] + core_channels,
        "receptive_field": max(learned["receptive_field"], core_field),
        # The learned folder's shiftable-window setting stays: the blend changes the cost, not that step.
        "sgm": {"p1": p1, "p2": p2, "paths": 4, "tuned_on": tuned_on,
                **({"shiftable_windows": learned["sgm"]["shiftable_windows"]}
                   if "shiftable_windows" in learned["sgm"] else {})},
        "build": {"command": command, "learned": learned["name"], "core_weight": core_weight,
                  "texture_energy": texture_energy, "learned_build": learned.get("build")},
        "metrics": {},
    }
    if core is None:
        manifest["build"]["ncc_window"] = window
        if gate is not None:
            manifest["build"]["gate"] = copy.deepcopy(gate)
    else:
        manifest["build"] |= {"core": core["name"], "core_training": core.get("training"),
                              "core_build": core.get("build"), "core_onnx": core["onnx"]}
    manifest["cost"]["definition"] = (
        f"CL[y, x, d] = -scale * <FL, FR>, F = [sqrt(1 - w) F_learned, sqrt(w) F_{core_label}], "
        f"w = {share}: for a constant w, (1 - w) learned cosine + w core cosine; x - d < 0 -> +scale")
    return manifest


def build_folder(out: str | Path, *, learned: str | Path, core_weight: float | None = None,
                 window: int | None = None, core: str | Path | None = None,
                 texture_energy: float | None = None, gate: str | Path | None = None,
                 p1: float | None = None, p2: float | None = None, tuned_on: str | None = None,
                 command: str = "") -> Path:
    """Write the hybrid left.onnx, right.onnx and manifest.json into ``out``; returns the manifest path.

    The core is an NCC ``window`` (3 when neither is given; the gate's window with ``gate``) or a trained
    ``core`` folder. ``gate``: a gate.json of ``python -m training.gate`` instead of ``core_weight``.
    ``p1``/``p2`` default to the learned folder's penalties.
    """
    if window is not None and core is not None:
        raise ValueError("give the core as --window or as --core, not both")
    gate_values = None if gate is None else read_gate(gate)
    if gate_values is not None:
        if core is not None:
            raise ValueError("a learned gate blends an NCC window, not a trained core")
        if window is not None and window != int(gate_values["window"]):
            raise ValueError(f"the gate was trained for a {gate_values['window']}x{gate_values['window']} "
                             f"window, not {window}x{window}")
        window = int(gate_values["window"])
    if core is None and window is None:
        window = 3
    learned_manifest = load_manifest(learned)
    verify_files(learned, learned_manifest)  # a tampered or corrupted tower is refused, not combined
    core_manifest = None if core is None else load_manifest(core)
    if core is not None:
        verify_files(core, core_manifest)
    out = Path(out)
    if out.resolve() in {Path(learned).resolve(), *([] if core is None else [Path(core).resolve()])}:
        raise ValueError(f"--out {out} is one of the folders it reads: write the hybrid elsewhere")
    towers = []
    for file_name in TOWER_FILES:
        side = file_name.removesuffix(".onnx")
        core_tower = (build_tower(window, side=side) if window is not None
                      else read_graph(Path(core) / file_name))
        towers.append(combine_towers(read_graph(Path(learned) / file_name), core_tower,
                                     core_weight=core_weight, texture_energy=texture_energy,
                                     gate=gate_values))
    sgm = learned_manifest["sgm"]
    chosen_p1, chosen_p2 = (sgm["p1"] if p1 is None else p1), (sgm["p2"] if p2 is None else p2)
    if tuned_on is None:
        tuned_on = (f"the learned folder's ({learned_manifest['name']})" if (p1, p2) == (None, None)
                    else "given on the command line")
    manifest = hybrid_manifest(learned_manifest, name=out.name, core_weight=core_weight, window=window,
                               core=core_manifest, texture_energy=texture_energy, gate=gate_values,
                               p1=chosen_p1,
                               p2=chosen_p2, tuned_on=tuned_on, command=command)
    serialised = {name: tower.SerializeToString(deterministic=True)
                  for name, tower in zip(TOWER_FILES, towers, strict=True)}
    return write_folder(out, serialised, manifest)


def _scalar(value: float) -> np.ndarray:
    return np.asarray([value], np.float32)


def read_gate(path: str | Path) -> dict[str, Any]:
    """A gate.json of ``python -m training.gate``; ValueError if it is not one."""
    try:
        values = json.loads(Path(path).read_text())
    except json.JSONDecodeError as error:
        raise ValueError(f"{path} is not JSON: {error}") from None
    if not isinstance(values, dict) or values.get("schema") != GATE_SCHEMA:
        raise ValueError(f"{path} is not a gate of python -m training.gate (schema {GATE_SCHEMA})")
    keys = ("window", "learned_channels", "weight", "bias", "training")
    missing = [key for key in keys if key not in values]
    if missing:
        raise ValueError(f"{path} lacks {', '.join(missing)}")
    return values


def _share_text(core_weight: float | None, texture_energy: float | None,
                gate: dict[str, Any] | None = None) -> str:
    if gate is not None:
        return "sigmoid(a . [learned, NCC window, log(E + eps)] + b), learned (build.gate)"
    assert core_weight is not None
    return f"{core_weight:g}" if texture_energy is None else f"{core_weight:g} E / (E + {texture_energy:g})"


def _opset(model: onnx.ModelProto) -> int:
    return next((entry.version for entry in model.opset_import if entry.domain in ("", "ai.onnx")), 0)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m export.hybrid", description=__doc__.splitlines()[0])
    parser.add_argument("--learned", type=Path, required=True, metavar="DIR", help="a trained model folder")
    core = parser.add_mutually_exclusive_group()
    core.add_argument("--window", type=int, help="the core is NCC of odd N x N grey windows (default 3)")
    core.add_argument("--core", type=Path, metavar="DIR", help="the core is another trained folder's towers")
    share = parser.add_mutually_exclusive_group(required=True)
    share.add_argument("--core-weight", type=float, metavar="W",
                       help="the core's share w of the cost, 0 < w < 1")
    share.add_argument("--gate", type=Path, metavar="JSON",
                       help="a per-pixel share learned by python -m training.gate (an NCC core)")
    parser.add_argument("--texture-energy", type=float, metavar="E0",
                        help="(NCC core) make the share w * E / (E + E0), E the window's zero-mean energy "
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
        options = dict(learned=args.learned, window=args.window, core=args.core, core_weight=args.core_weight,
                       texture_energy=args.texture_energy, gate=args.gate, command=command)
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
