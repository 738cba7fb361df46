"""Export a checkpoint to a model folder: left.onnx + right.onnx + manifest.json (+ an int8 twin folder).

    python -m export.to_onnx --checkpoint CKPT --out DIR [--int8 --calibration SPEC] [--opset N]

Writes DIR/left.onnx, DIR/right.onnx and DIR/manifest.json (schema adsm-model/1, validated): config,
channels, receptive field, input normalisation, cost scale, SGM P1/P2, disparity range, opset, sha256 of
each file, the training provenance copied from the checkpoint, and metrics measured on the written
folder (its ONNX files through the runtime, as ``python -m export.measure --write`` does: Cones when
--cones exists, the synthetic validation split's --synthetic pairs; --no-measure leaves them empty).
Settings the checkpoint does not record (its ``deploy`` dict) fall back to the runtime defaults
(``service.features.defaults.RUNTIME_DEFAULTS``), or come from the options above. With --int8, DIR-int8
holds the int8 twin, measured on the same data sets; the export log prints its accuracy against fp32,
which its manifest records (onnx.quantization.accuracy_vs_fp32).

Each tower becomes one ONNX graph built from the folded PyTorch weights: ``image`` [1, 3, H, W] ->
edge padding by (P - 1) / 2 for patch size P (so H, W are kept) -> [the image and its local
standardisation, when the model has one: training.networks.standardization] -> convs (+ ReLU) -> L2
normalisation over C -> ``features`` [1, C, H, W]. BN is folded into each conv's weights and bias.
Stride-1 transposed convs are written as the equivalent convs (kernel flipped, in/out swapped, zero
padding k - 1): ONNX Runtime ran the 3->64 Deconv5 at 375x1242 in 0.11 s as a Conv against 0.34 s as a
ConvTranspose.
"""

from __future__ import annotations

import argparse
import dataclasses
import shlex
import sys
from collections.abc import Callable, Mapping
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
import onnx
import torch
from onnx import TensorProto, helper, numpy_helper
from torch import nn

from export.folder import write_folder
from export.measure import (
    DEFAULT_CONES,
    DEFAULT_SYNTHETIC_PAIRS,
    default_datasets,
    measure_command,
    measure_folder,
)
from service.features.defaults import RUNTIME_DEFAULTS
from service.features.manifest import SCHEMA_ID, TOWER_FILES, ModelError, write_manifest
from training.checkpoint import Checkpoint, load_checkpoint
from training.networks import FeatureTower, TowerPair, same_padding
from training.networks.adaptive_support import stacked_weight, taps
from training.networks.standardization import LocalStandardization
from training.networks.tower import NORM_EPS

DEFAULT_OPSET = 17
SUPPORTED_OPSETS = range(13, 22)


@dataclasses.dataclass(frozen=True)
class FoldedConv:
    """One deploy-time conv: weight [Cout, Cin, kh, kw], optional bias, zero padding (rows, columns) on
    each side, ReLU after it."""

    weight: np.ndarray
    bias: np.ndarray | None
    padding: tuple[int, int]
    relu: bool


def fold_tower(tower: FeatureTower) -> list[FoldedConv]:
    """The tower as plain convs: deconvs rewritten as convs, each BN folded into the conv before it."""
    folded: list[FoldedConv] = []
    modules = list(tower.layers)
    for index, module in enumerate(modules):
        if not isinstance(module, nn.Conv2d | nn.ConvTranspose2d):
            continue
        weight = module.weight.detach().double()
        padding = (0, 0)
        if isinstance(module, nn.ConvTranspose2d):
            # A stride-1, unpadded transposed conv is the full convolution with the flipped kernel.
            weight = weight.transpose(0, 1).flip(2, 3)
            padding = (module.kernel_size[0] - 1, module.kernel_size[1] - 1)
        bias = None
        following = modules[index + 1:index + 3]
        if following and isinstance(following[0], nn.BatchNorm2d):
            bn = following[0]
            scale = bn.weight.detach().double() / torch.sqrt(bn.running_var.double() + bn.eps)
            weight = weight * scale[:, None, None, None]
            bias = (bn.bias.detach().double() - bn.running_mean.double() * scale).float().numpy()
        relu = any(isinstance(m, nn.ReLU) for m in following)
        folded.append(FoldedConv(weight.float().numpy(), bias, padding, relu))
    return folded


def tower_to_onnx(tower: FeatureTower, *, opset: int = DEFAULT_OPSET, name: str = "tower") -> onnx.ModelProto:
    """One tower as an ONNX model with dynamic height and width (checked with onnx.checker)."""
    if opset not in SUPPORTED_OPSETS:
        first, last = SUPPORTED_OPSETS.start, SUPPORTED_OPSETS.stop - 1
        raise ValueError(f"opset {opset} not supported (choose {first}..{last})")
    left, right, top, bottom = same_padding(tower.patch_shape)
    pads = np.array([0, 0, top, left, 0, 0, bottom, right], np.int64)
    initializers = [numpy_helper.from_array(pads, "pads"),
                    numpy_helper.from_array(np.array([NORM_EPS], np.float32), "norm_eps")]
    nodes = [helper.make_node("Pad", ["image", "pads"], ["x0"], mode="edge", name="edge_pad")]
    current = "x0"
    if tower.standardize is not None:
        current = _standardization_nodes(current, tower.standardize, nodes, initializers)
    offset = 0  # adaptive support: the input image's rows and columns cut off before this conv
    for index, conv in enumerate(fold_tower(tower)):
        weight, kernel = conv.weight, conv.weight.shape[2:]
        if tower.adaptive_support and kernel != (1, 1):
            gain = float(tower.support_log_gain[index].detach().exp())
            current = _adaptive_support_nodes(current, "x0", offset, kernel, gain, index, nodes, initializers)
            weight = stacked_weight(torch.from_numpy(weight)).numpy()
        offset += kernel[0] // 2
        inputs = [current, f"w{index}"]
        initializers.append(numpy_helper.from_array(weight, f"w{index}"))
        if conv.bias is not None:
            initializers.append(numpy_helper.from_array(conv.bias, f"b{index}"))
            inputs.append(f"b{index}")
        output = f"conv{index}"
        nodes.append(helper.make_node("Conv", inputs, [output], pads=[*conv.padding, *conv.padding],
                                      name=f"conv{index}"))
        if conv.relu:
            nodes.append(helper.make_node("Relu", [output], [f"relu{index}"], name=f"relu{index}"))
            output = f"relu{index}"
        current = output
    # features / max(||features||, eps), as training.networks.l2_normalize; kept fp32 in int8 models.
    if opset >= 18:
        initializers.append(numpy_helper.from_array(np.array([1], np.int64), "channel_axis"))
        nodes.append(helper.make_node("ReduceL2", [current, "channel_axis"], ["norm"], keepdims=1,
                                      name="norm"))
    else:
        nodes.append(helper.make_node("ReduceL2", [current], ["norm"], axes=[1], keepdims=1, name="norm"))
    nodes += [helper.make_node("Max", ["norm", "norm_eps"], ["norm_floor"], name="norm_floor"),
              helper.make_node("Div", [current, "norm_floor"], ["features"], name="l2_normalise")]
    image = helper.make_tensor_value_info("image", TensorProto.FLOAT, [1, 3, "height", "width"])
    features = helper.make_tensor_value_info("features", TensorProto.FLOAT,
                                             [1, tower.channels, "height", "width"])
    graph = helper.make_graph(nodes, name, [image], [features], initializer=initializers)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", opset)],
                              producer_name="adsm export.to_onnx",
                              doc_string=f"ADSM {tower.config.name} tower")
    model.ir_version = 8  # the oldest IR that opset 13..21 allow, so older ONNX Runtime builds load it
    onnx.checker.check_model(model, full_check=True)
    return model


def _slice(tensor: str, name: str, starts: list[int], ends: list[int], axes: list[int],
           nodes: list[onnx.NodeProto], initializers: list[onnx.TensorProto]) -> str:
    """``tensor[starts:ends]`` along ``axes`` (a 0 end: to the last element), as one Slice node."""
    last = np.iinfo(np.int64).max
    values = {"starts": starts, "ends": [end if end else last for end in ends], "axes": axes}
    for key, value in values.items():
        initializers.append(numpy_helper.from_array(np.array(value, np.int64), f"{name}_{key}"))
    nodes.append(helper.make_node("Slice", [tensor, *(f"{name}_{key}" for key in values)], [name], name=name))
    return name


def _tap_distances(image: str, kernel: tuple[int, int], nodes: list[onnx.NodeProto],
                   initializers: list[onnx.TensorProto]) -> str:
    """``[1, kh * kw, H - kh + 1, W - kw + 1]``: each tap's squared colour distance to its window's
    centre over the whole padded image; every adaptive conv of this kernel slices its part."""
    kh, kw = kernel
    prefix = f"distances{kh}x{kw}"
    if any(node.name == prefix for node in nodes):
        return prefix

    def window(name: str, row: int, column: int) -> str:
        return _slice(image, name, [row, column], [-(kh - 1 - row), -(kw - 1 - column)], [2, 3], nodes,
                      initializers)

    centre = window(f"{prefix}_centre", kh // 2, kw // 2)
    initializers.append(numpy_helper.from_array(np.array([1], np.int64), f"{prefix}_channel_axis"))
    distances = []
    for tap, (row, column) in enumerate(taps((kh, kw))):
        name = f"{prefix}_t{tap}"
        nodes += [helper.make_node("Sub", [window(f"{name}_image", row, column), centre], [f"{name}_diff"],
                                   name=f"{name}_diff"),
                  helper.make_node("Mul", [f"{name}_diff", f"{name}_diff"], [f"{name}_sq"],
                                   name=f"{name}_sq"),
                  helper.make_node("ReduceSum", [f"{name}_sq", f"{prefix}_channel_axis"], [f"{name}_dist"],
                                   keepdims=1, name=f"{name}_dist")]
        distances.append(f"{name}_dist")
    nodes.append(helper.make_node("Concat", distances, [prefix], axis=1, name=prefix))
    return prefix


def _adaptive_support_nodes(source: str, image: str, offset: int, kernel: tuple[int, int], gain: float,
                            index: int, nodes: list[onnx.NodeProto],
                            initializers: list[onnx.TensorProto]) -> str:
    """Conv ``index``'s taps of ``source`` weighted by their colour likeness to the centre in ``image``
    (training.networks.adaptive_support), stacked along channels for a 1 x 1 conv; returns their name.

    The softmax is written as exp / sum: every window's centre tap has distance 0, so the largest logit
    is 0 and nothing overflows (ONNX Runtime's Softmax over channels was a fifth of the tower's time)."""
    kh, kw = kernel
    prefix = f"support{index}"
    distances = _tap_distances(image, kernel, nodes, initializers)
    if offset:
        distances = _slice(distances, f"{prefix}_dist", [offset, offset], [-offset, -offset], [2, 3], nodes,
                           initializers)
    initializers += [numpy_helper.from_array(np.array([1], np.int64), f"{prefix}_channel_axis"),
                     numpy_helper.from_array(np.array([-gain], np.float32), f"{prefix}_neg_gain"),
                     numpy_helper.from_array(np.array([float(kh * kw)], np.float32), f"{prefix}_taps")]
    nodes += [helper.make_node("Mul", [distances, f"{prefix}_neg_gain"], [f"{prefix}_logits"],
                               name=f"{prefix}_logits"),
              helper.make_node("Exp", [f"{prefix}_logits"], [f"{prefix}_exp"], name=f"{prefix}_exp"),
              helper.make_node("ReduceSum", [f"{prefix}_exp", f"{prefix}_channel_axis"], [f"{prefix}_total"],
                               keepdims=1, name=f"{prefix}_total"),
              helper.make_node("Div", [f"{prefix}_taps", f"{prefix}_total"], [f"{prefix}_scale"],
                               name=f"{prefix}_scale"),
              helper.make_node("Mul", [f"{prefix}_exp", f"{prefix}_scale"], [f"{prefix}_weights"],
                               name=f"{prefix}_weights")]
    products = []
    for tap, (row, column) in enumerate(taps((kh, kw))):
        name = f"{prefix}_t{tap}"
        weight = _slice(f"{prefix}_weights", f"{name}_w", [tap], [tap + 1], [1], nodes, initializers)
        shifted = _slice(source, f"{name}_x", [row, column], [-(kh - 1 - row), -(kw - 1 - column)], [2, 3],
                         nodes, initializers)
        nodes.append(helper.make_node("Mul", [shifted, weight], [f"{name}_wx"], name=f"{name}_wx"))
        products.append(f"{name}_wx")
    nodes.append(helper.make_node("Concat", products, [f"{prefix}_taps_stacked"], axis=1,
                                  name=f"{prefix}_taps_stacked"))
    return f"{prefix}_taps_stacked"


def _standardization_nodes(source: str, standardize: LocalStandardization, nodes: list[onnx.NodeProto],
                           initializers: list[onnx.TensorProto]) -> str:
    """Append :class:`LocalStandardization`'s operations (same order, same formulas); returns the output
    name: the image and its standardisation concatenated over channels."""
    window, radius = standardize.window, standardize.window // 2
    pads = np.array([0, 0, radius, radius, 0, 0, radius, radius], np.int64)
    initializers += [numpy_helper.from_array(pads, "std_pads"),
                     numpy_helper.from_array(np.array([standardize.eps ** 2], np.float32), "std_eps2")]
    pool = {"kernel_shape": [window, window], "strides": [1, 1]}
    nodes += [
        helper.make_node("Pad", [source, "std_pads"], ["std_padded"], mode="edge", name="std_pad"),
        helper.make_node("AveragePool", ["std_padded"], ["std_mean"], name="std_mean", **pool),
        helper.make_node("Mul", ["std_padded", "std_padded"], ["std_squares"], name="std_squares"),
        helper.make_node("AveragePool", ["std_squares"], ["std_mean_sq"], name="std_mean_sq", **pool),
        helper.make_node("Mul", ["std_mean", "std_mean"], ["std_mean2"], name="std_mean2"),
        helper.make_node("Sub", ["std_mean_sq", "std_mean2"], ["std_var_raw"], name="std_var_raw"),
        helper.make_node("Relu", ["std_var_raw"], ["std_var"], name="std_var"),
        helper.make_node("Add", ["std_var", "std_eps2"], ["std_var_eps"], name="std_var_eps"),
        helper.make_node("Sqrt", ["std_var_eps"], ["std_dev"], name="std_dev"),
        helper.make_node("Sub", [source, "std_mean"], ["std_centred"], name="std_centred"),
        helper.make_node("Div", ["std_centred", "std_dev"], ["std_z"], name="std_z"),
        helper.make_node("Concat", [source, "std_z"], ["std_input"], axis=1, name="std_input"),
    ]
    return "std_input"


def build_manifest(checkpoint: Checkpoint, model: TowerPair, *, name: str, opset: int,
                   command: str, checkpoint_path: str, overrides: dict[str, Any]) -> dict[str, Any]:
    """The manifest (write_manifest fills ``files``), provenance copied from the checkpoint.

    ``metrics`` start empty: the checkpoint's figures come from the PyTorch towers, and a manifest carries
    only figures measured on its own folder (:func:`export_folder` with ``datasets``).
    """
    deploy = {**checkpoint.deploy_settings(), **{k: v for k, v in overrides.items() if v is not None}}
    trained_range = deploy.get("trained_range")
    if trained_range is None:
        if checkpoint.training is not None:
            raise ValueError("the checkpoint records training but no deploy['trained_range']; pass "
                             "--trained-range LOW HIGH")
        trained_range = [0, 0]  # untrained: it has seen no disparity at all
    low, high = (int(value) for value in trained_range)
    if not 0 <= low <= high:
        raise ValueError(f"the trained disparity range must be LOW HIGH with 0 <= LOW <= HIGH, got {low} "
                         f"{high}")
    sgm: dict[str, Any] = {"p1": float(deploy["p1"]), "p2": float(deploy["p2"]), "paths": 4}
    paper = RUNTIME_DEFAULTS
    untuned = (f"not tuned: the paper's P1 = {paper.p1:g}, P2 = {paper.p2:g} at cost scale "
               f"{paper.cost_scale:g}")
    sgm["tuned_on"] = deploy.get("sgm_tuned_on", untuned)
    return {
        "schema": SCHEMA_ID,
        "name": name,
        "description": f"ADSM {model.config.name} towers ({model.config.table} of the paper), "
                       f"{model.channels} features, {'shared' if model.shared else 'separate'} "
                       "left/right weights"
                       + (f", input standardised over {model.standardize_window}x{model.standardize_window} "
                          "windows in the graph" if model.standardize_window else "")
                       + (", conv taps weighted by colour likeness to the centre (adaptive support)"
                          if model.adaptive_support else ""),
        "config": model.config.name,
        "channels": model.channels,
        "receptive_field": model.receptive_field,
        "shared_towers": model.shared,
        "input": deploy["input"],
        "cost": {"scale": float(deploy["cost_scale"]), "dtype": "int16",
                 "definition": "CL[y, x, d] = -scale * <FL[:, y, x], FR[:, y, x - d]> (features "
                               "L2-normalised over C); x - d < 0 -> +scale"},
        "sgm": sgm,
        "disparity": {"default_max": int(deploy["default_max"]),
                      "trained_range": [int(v) for v in trained_range]},
        "onnx": {"opset": opset, "precision": "fp32",
                 "exporter": f"export.to_onnx (onnx {onnx.__version__} helper API, "
                             f"torch {torch.__version__})",
                 **({"adaptive_support": True} if model.adaptive_support else {})},
        "training": checkpoint.training,
        "build": {"command": command, "date": datetime.now(UTC).isoformat(timespec="seconds"),
                  "checkpoint": checkpoint_path, "step": checkpoint.step,
                  "temperature": round(model.temperature, 6), "trainer_config": checkpoint.config},
        "metrics": {},
    }


def export_folder(checkpoint_path: str | Path, out: str | Path, *, opset: int = DEFAULT_OPSET,
                  name: str | None = None, command: str = "", datasets: Mapping[str, str] | None = None,
                  threads: int | None = None, log: Callable[[str], Any] = lambda _: None,
                  **overrides: Any) -> Path:
    """Write ``out``/left.onnx, right.onnx, manifest.json from a checkpoint; returns the manifest path.

    ``overrides`` (cost_scale, p1, p2, default_max, trained_range) replace the checkpoint's deploy values.
    ``datasets`` (NAME -> ``adsm eval`` SPEC) are measured on the written folder for ``metrics``
    (:func:`export.measure.measure_folder`); None or {}: ``metrics`` stay empty.
    """
    checkpoint = load_checkpoint(checkpoint_path)
    model = checkpoint.build_model()
    out = Path(out)
    towers = {file_name: tower_to_onnx(tower, opset=opset, name=f"adsm_{model.config.name}_{file_name[:-5]}"
                                       ).SerializeToString(deterministic=True)
              for file_name, tower in zip(TOWER_FILES, (model.left, model.right), strict=True)}
    manifest = build_manifest(checkpoint, model, name=name or _folder_name(out), opset=opset,
                              command=command, checkpoint_path=str(checkpoint_path), overrides=overrides)
    path = write_folder(out, towers, manifest)  # validated before an existing folder is touched
    if datasets:
        manifest["metrics"] = measure_folder(out, datasets, command=measure_command(out, datasets),
                                             threads=threads, log=log)
        path = write_manifest(out, manifest)
    return path


def _folder_name(folder: Path) -> str:
    """A manifest name (lower case, [a-z0-9._-]) from the folder name."""
    cleaned = "".join(c if c.isalnum() or c in "._-" else "-" for c in folder.resolve().name.lower())
    return cleaned.lstrip("._-") or "adsm"


def build_parser() -> argparse.ArgumentParser:
    from export.quantize import CALIBRATION_HELP, DEFAULT_CALIBRATION

    parser = argparse.ArgumentParser(prog="python -m export.to_onnx", description=__doc__.split("\n\n")[0],
                                     epilog=__doc__.split("\n\n", 2)[2],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--checkpoint", required=True, type=Path,
                        help="checkpoint written by training.checkpoint.save_checkpoint")
    parser.add_argument("--out", required=True, type=Path, help="model folder to write (created if needed)")
    parser.add_argument("--name", help="manifest name (default: the folder name, lower case)")
    parser.add_argument("--opset", type=int, default=DEFAULT_OPSET,
                        help="ONNX opset, 13..21 (default: %(default)s)")
    parser.add_argument("--int8", action="store_true",
                        help="also write an int8 copy to OUT-int8: static QDQ quantization, per-channel int8 "
                             "weights, uint8 activations; its accuracy against fp32 is measured and recorded")
    parser.add_argument("--calibration", default=DEFAULT_CALIBRATION, help=CALIBRATION_HELP)
    defaults = RUNTIME_DEFAULTS
    parser.add_argument("--cost-scale", type=float,
                        help=f"manifest cost.scale (default: checkpoint, else {defaults.cost_scale:g})")
    parser.add_argument("--p1", type=float,
                        help=f"SGM P1 in cost units (default: checkpoint, else {defaults.p1:g})")
    parser.add_argument("--p2", type=float,
                        help=f"SGM P2 in cost units (default: checkpoint, else {defaults.p2:g})")
    parser.add_argument("--max-disparity", type=int, dest="default_max",
                        help="manifest disparity.default_max "
                             f"(default: checkpoint, else {defaults.default_max})")
    parser.add_argument("--trained-range", type=int, nargs=2, metavar=("LOW", "HIGH"),
                        help="disparities seen in training (default: checkpoint; [0, 0] if untrained)")
    parser.add_argument("--cones", type=Path, default=DEFAULT_CONES, metavar="PATH",
                        help="Cones folder measured into metrics, if it exists (default: %(default)s)")
    parser.add_argument("--synthetic", type=int, default=DEFAULT_SYNTHETIC_PAIRS, metavar="N",
                        help="synthetic validation pairs measured into metrics (default: %(default)s; "
                             "0: none)")
    parser.add_argument("--no-measure", action="store_true",
                        help="write empty metrics (measure later: python -m export.measure --model DIR "
                             "--write)")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    command = shlex.join(["python", "-m", "export.to_onnx", *(sys.argv[1:] if argv is None else argv)])
    datasets = {} if args.no_measure else default_datasets({}, cones=args.cones,
                                                            synthetic_pairs=args.synthetic)
    if not args.no_measure and not args.cones.is_dir():
        print(f"export.to_onnx: no Cones folder at {args.cones}: metrics without it", file=sys.stderr)
    try:
        manifest_path = export_folder(args.checkpoint, args.out, opset=args.opset, name=args.name,
                                      command=command, datasets=datasets, log=print,
                                      cost_scale=args.cost_scale, p1=args.p1, p2=args.p2,
                                      default_max=args.default_max, trained_range=args.trained_range)
        print(f"wrote {manifest_path.parent} (fp32)")
        if args.int8:
            from export.quantize import quantize_folder

            int8_path = quantize_folder(args.out, Path(f"{args.out}-int8"), calibration=args.calibration,
                                        datasets=datasets, command=command, log=print)
            print(f"wrote {int8_path.parent} (int8)")
    except (OSError, ValueError, ModelError) as error:
        print(f"export.to_onnx: error: {error}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
