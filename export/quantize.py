"""int8 twin of an exported model folder: static QDQ quantization and its measured accuracy against fp32.

    python -m export.quantize --model DIR --out DIR-int8 [--calibration SPEC] [--no-measure] [--threads N]

(``python -m export.to_onnx --int8`` calls the same ``quantize_folder`` right after the fp32 export; this
command quantises a folder that is already exported, e.g. after the recipe below changed.)

ONNX Runtime's ``quantize_static`` inserts QuantizeLinear/DequantizeLinear around every Conv: int8
weights per output channel, uint8 activations per tensor (each conv's ReLU folded into its output
range: ``float_nodes``) with MinMax ranges calibrated on stereo-like views (an image and the same
image seen 8 pixels further right, or the project's synthetic stereo pairs). The padding and the final
L2 normalisation stay fp32. No stereo data set exists on these machines, so the default calibration uses
photographs and textures shipped inside scikit-image; the evaluation pair (Cones) is refused.

The accuracy is measured on a held-out photograph (never in the calibration set), warped by a known
disparity ramp into a right view: per-pixel cosine between fp32 and int8 features, and the share of
pixels whose disparity from the Matcher agrees within 1 px. Both go into the int8 manifest.

The int8 manifest's ``metrics`` are measured on the int8 folder itself (``export.measure``: its own ONNX
files through the runtime), on the data sets the fp32 twin's metrics were measured on; nothing is copied
from the fp32 manifest.
"""

from __future__ import annotations

import argparse
import glob
import importlib.util
import json
import shlex
import shutil
import sys
import tempfile
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import onnx
from onnxruntime.quantization import (
    CalibrationDataReader,
    CalibrationMethod,
    QuantFormat,
    QuantType,
    quantize_static,
)
from onnxruntime.quantization.shape_inference import quant_pre_process

from export.measure import datasets_of, measure_command, measure_folder
from service.features.manifest import TOWER_FILES, ModelError, load_manifest, write_manifest
from service.features.towers import FeatureTowers
from service.io import read_image
from training.data.evaluation_only import EVALUATION_ONLY, EVALUATION_ONLY_FILES
from training.data.photos import data_folder

DEFAULT_CALIBRATION = "skimage:astronaut,chelsea,rocket,brick,gravel"
HELD_OUT = "skimage:coffee"          # accuracy image, never part of the default calibration
CALIBRATION_SHIFT = 8                # px between the two calibration views
CROP = (192, 256)                    # calibration crop (H, W): large enough for the 45 px receptive fields
# Smallest calibration view side: below ~8 px ONNX Runtime's calibrator fails inside (a traceback), and
# views much smaller than a receptive field teach the activation ranges little.
MIN_CALIBRATION_SIDE = 32
QUANTIZED_OPS = ["Conv", "Relu"]     # see float_nodes: a conv's ReLU is quantised with it
SYNTHETIC_SEED = 900_000_000         # calibration pairs: below the synthetic validation seeds (1e9 on)
CALIBRATION_HELP = (
    "calibration images for --int8: 'skimage' or 'skimage:NAME,NAME' (images shipped in scikit-image's "
    "data folder, by file stem), a folder of images, or a glob pattern: each image gives a left view and "
    f"a right view {CALIBRATION_SHIFT} px to the right; or 'synthetic:N', N pairs of the project's "
    "synthetic stereo generator (default: %(default)s). The accuracy check uses "
    f"{HELD_OUT}, which must not be among them."
)


def calibration_images(spec: str) -> list[tuple[str, np.ndarray]]:
    """(name, uint8 HxWx3) for a calibration SPEC (see ``CALIBRATION_HELP``)."""
    if spec == "skimage" or spec.startswith("skimage:"):
        try:
            folder = data_folder()
        except ModuleNotFoundError:
            raise ValueError("calibration 'skimage' needs scikit-image (pip install -e '.[train]')") from None
        stems = [s for s in spec.partition(":")[2].split(",") if s] or DEFAULT_CALIBRATION[8:].split(",")
        paths = []
        for stem in stems:
            found = sorted(folder.glob(f"{stem}.*"))
            if not found:
                known = sorted({p.stem for p in folder.iterdir() if p.suffix in {".png", ".jpg"}})
                raise ValueError(f"no scikit-image data image {stem!r}; known: {', '.join(known)}")
            paths.append(found[0])
    elif Path(spec).is_dir():
        paths = sorted(p for p in Path(spec).iterdir() if p.suffix.lower() in
                       {".png", ".jpg", ".jpeg", ".ppm", ".pgm", ".tif", ".tiff", ".bmp"})
    else:
        paths = sorted(Path(p) for p in glob.glob(spec))
    if not paths:
        raise ValueError(f"calibration spec {spec!r} names no images")
    if refused := [p for p in paths if p.name in EVALUATION_ONLY_FILES
                   or any(part in EVALUATION_ONLY for part in p.resolve().parts)]:
        raise ValueError(f"{refused[0]} belongs to an evaluation-only data set; never calibrate on it")
    return [(p.stem, read_image(p, name=str(p))) for p in paths]


def calibration_pairs(spec: str) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """(name, left view, right view) for a calibration SPEC, cropped to at most ``CROP``."""
    if spec == "synthetic" or spec.startswith("synthetic:"):
        from training.data.synthetic import SyntheticConfig, generate

        count = spec.partition(":")[2]
        if count and (not count.isdigit() or int(count) < 1):
            raise ValueError(f"calibration 'synthetic:N' needs a positive pair count, got {count!r}")
        config = SyntheticConfig(height=CROP[0], width=CROP[1], max_disparity=48)
        samples = [generate(SYNTHETIC_SEED + i, config) for i in range(int(count or 6))]
        return [(sample.name, sample.left, sample.right) for sample in samples]
    pairs = []
    for name, image in calibration_images(spec):
        if image.shape[0] < MIN_CALIBRATION_SIDE or image.shape[1] < MIN_CALIBRATION_SIDE + CALIBRATION_SHIFT:
            least = f"{MIN_CALIBRATION_SIDE + CALIBRATION_SHIFT}x{MIN_CALIBRATION_SIDE}"
            raise ValueError(f"calibration image {name!r} is {image.shape[1]}x{image.shape[0]} px; each "
                             f"needs at least {least}")
        pairs.append((name, *stereo_views(image)))
    return pairs


def stereo_views(image: np.ndarray, *, shift: int = CALIBRATION_SHIFT) -> tuple[np.ndarray, np.ndarray]:
    """A centred crop and the same crop taken ``shift`` px further right (a right camera's view)."""
    height, width = min(CROP[0], image.shape[0]), min(CROP[1], image.shape[1] - shift)
    top, left = (image.shape[0] - height) // 2, (image.shape[1] - shift - width) // 2
    return (image[top:top + height, left:left + width],
            image[top:top + height, left + shift:left + shift + width])


def ramp_pair(image: np.ndarray, *, low: float = 4.0, high: float = 12.0) -> tuple[np.ndarray, np.ndarray]:
    """A right view whose disparity grows row by row from ``low`` to ``high`` px (linear interpolation)."""
    left = image[:CROP[0], :CROP[1] + int(high) + 1].astype(np.float32)
    columns = np.arange(left.shape[1], dtype=np.float32)
    right = np.empty_like(left)
    for row, disparity in enumerate(np.linspace(low, high, left.shape[0], dtype=np.float32)):
        for channel in range(3):  # right(x) = left(x + d): the right camera sees the scene shifted left
            right[row, :, channel] = np.interp(columns + disparity, columns, left[row, :, channel])
    keep = CROP[1]
    return (left[:, :keep].round().astype(np.uint8), right[:, :keep].round().astype(np.uint8))


class _Views(CalibrationDataReader):
    """Feeds normalised [1, 3, H, W] views to the calibrator, as the runtime would."""

    def __init__(self, views: list[np.ndarray], input_spec: dict[str, Any]) -> None:
        low, high = input_spec["range"]
        mean = np.asarray(input_spec["mean"], np.float32)[:, None, None]
        std = np.asarray(input_spec["std"], np.float32)[:, None, None]
        scale = (high - low) / 255.0
        self._batches: Iterator[dict[str, np.ndarray]] = iter(
            {"image": ((v.transpose(2, 0, 1) * scale + low - mean) / std)[None].astype(np.float32)}
            for v in views)

    def get_next(self) -> dict[str, np.ndarray] | None:
        return next(self._batches, None)


def quantize_folder(fp32_folder: str | Path, out: str | Path, *, calibration: str = DEFAULT_CALIBRATION,
                    datasets: Mapping[str, str] | None = None, threads: int | None = None,
                    command: str | None = None, log: Callable[[str], Any] = lambda _: None) -> Path:
    """Write the int8 twin of ``fp32_folder`` into ``out``; returns its manifest path.

    ``datasets`` (NAME -> ``adsm eval`` SPEC) are measured on the int8 folder for its ``metrics``; None:
    the data sets the fp32 manifest's metrics record (``export.measure.datasets_of``), {}: none.
    ``command``, the command line that made the folder, is recorded in ``onnx.quantization.command``.
    """
    fp32_folder, out = Path(fp32_folder), Path(out)
    manifest = load_manifest(fp32_folder)
    if manifest["onnx"].get("precision") == "int8":
        raise ValueError(f"{fp32_folder} is already int8; quantise its fp32 twin")
    pairs = calibration_pairs(calibration)
    held_out_name, held_out = calibration_images(HELD_OUT)[0]
    if any(name == held_out_name for name, _, _ in pairs):
        raise ValueError(f"{HELD_OUT} is the accuracy image; leave it out of the calibration set")
    # Both towers are quantised into a scratch folder first: a failure on the second no longer leaves
    # ``out`` with a new left tower beside an old right one (and an old manifest that matches neither).
    with tempfile.TemporaryDirectory(prefix="adsm-quantize-") as scratch:
        for index, file_name in enumerate(TOWER_FILES):
            views = [pair[1 + index] for pair in pairs]
            # ONNX Runtime's recommended pre-pass: shape inference and graph clean-up before QDQ insertion.
            prepared = Path(scratch) / f"prepared-{file_name}"
            quant_pre_process(str(fp32_folder / file_name), str(prepared))
            quantize_static(prepared, Path(scratch) / file_name, _Views(views, manifest["input"]),
                            quant_format=QuantFormat.QDQ, op_types_to_quantize=QUANTIZED_OPS,
                            per_channel=True, activation_type=QuantType.QUInt8,
                            weight_type=QuantType.QInt8, calibrate_method=CalibrationMethod.MinMax,
                            nodes_to_exclude=float_nodes(prepared))
            onnx.checker.check_model(str(Path(scratch) / file_name), full_check=True)
            log(f"quantized {file_name}: {len(views)} calibration views from {calibration}")
        out.mkdir(parents=True, exist_ok=True)
        for file_name in TOWER_FILES:
            shutil.copyfile(Path(scratch) / file_name, out / file_name)
    name = manifest["name"][:60] + "-int8"
    # Figures of the fp32 towers say nothing about these: metrics are measured below, on this folder.
    int8 = {**manifest, "name": name, "description": manifest.get("description", "") + "; int8 QDQ",
            "metrics": {}}
    int8["onnx"] = {**manifest["onnx"], "precision": "int8", "quantization": {
        "method": "onnxruntime static QDQ: per-channel int8 weights, per-tensor uint8 activations (MinMax), "
                  "each conv's ReLU folded into its output range; the first conv stays float32",
        "calibration": calibration, "calibration_images": [name for name, _, _ in pairs],
        "calibration_views": f"up to {CROP[0]}x{CROP[1]}; an image's right view is its crop "
                             f"{CALIBRATION_SHIFT} px to the right"}}
    if command:
        int8["onnx"]["quantization"]["command"] = command
    write_manifest(out, int8)
    accuracy = measure_accuracy(fp32_folder, out, held_out, held_out_name)
    int8["onnx"]["quantization"]["accuracy_vs_fp32"] = accuracy
    log(f"int8 vs fp32 on held-out {held_out_name}: {json.dumps(accuracy)}")
    datasets = datasets_of(manifest) if datasets is None else dict(datasets)
    if datasets:
        write_manifest(out, int8)
        int8["metrics"] = measure_folder(out, datasets, command=measure_command(out, datasets),
                                         threads=threads, log=log)
    return write_manifest(out, int8)


def float_nodes(model_path: Path) -> list[str]:
    """Nodes quantisation leaves in float32: the first Conv, and every Relu that does not follow a Conv.

    The Relus that do follow a Conv are quantised with it: ONNX Runtime then drops them and gives the
    conv's output the ReLU's range (uint8, zero point 0, so the clamp at 0 is exact). Quantising the Conv
    alone had quantised each conv's output to its own range, half of whose 256 levels went to negative
    values the ReLU discards, and then requantised it to the ReLU's range through float32
    (DequantizeLinear -> QuantizeLinear between every two convs, two roundings). Folding the ReLU made
    the int8 features 2.2-3.8x closer to fp32 (1 - cosine on the held-out pair: 0.0018 -> 0.0007 for
    adsm-rf11, 0.0078 -> 0.0027 for adsm-fast) and the int8 towers faster, most at 48 channels, where
    the old graph was slower than fp32 (docs/training.md, "int8 towers with the ReLU folded"). A Relu
    elsewhere (the standardisation's variance) stays float32.
    """
    graph = onnx.load(str(model_path)).graph
    producers = {output: node for node in graph.node for output in node.output}
    keep = [first_conv(graph, model_path)]
    for node in graph.node:
        producer = producers.get(node.input[0]) if node.input else None
        if node.op_type == "Relu" and (producer is None or producer.op_type != "Conv"):
            keep.append(node.name)
    return keep


def first_conv(graph: onnx.GraphProto, model_path: Path) -> str:
    """Name of the graph's first Conv, which quantisation leaves in float32.

    Its outputs are differences of neighbouring pixels, small on low-contrast surfaces next to the
    per-tensor range set by high-contrast ones, so uint8 crushed them: with every conv quantised the
    13-1deconv3-4conv 32-channel towers lost 15.83 -> 19.34 % bad-2 on synthetic:8 (Cones 9.10 -> 9.18);
    with the first left in float32, 16.08 % (Cones 9.09). It has 3 input channels: a small share of the
    tower's work. (Percentile calibration: 19.69 %; the last conv left in float32: 19.36 %.)
    """
    for node in graph.node:
        if node.op_type == "Conv":
            return node.name
    raise ValueError(f"{model_path} has no Conv to quantise")


def measure_accuracy(fp32_folder: Path, int8_folder: Path, image: np.ndarray, name: str) -> dict[str, Any]:
    """Feature cosine (per tower) and 1-px disparity agreement of int8 against fp32 on a ramp pair."""
    left, right = ramp_pair(image)
    fp32, int8 = FeatureTowers(fp32_folder, threads=None), FeatureTowers(int8_folder, threads=None)
    result: dict[str, Any] = {"pair": f"{name} {left.shape[0]}x{left.shape[1]}, right view warped by a "
                                      "4..12 px disparity ramp"}
    for side, reference, quantized in zip(("left", "right"), fp32(left, right), int8(left, right),
                                          strict=True):
        cosine = (reference * quantized).sum(axis=0)  # both unit vectors per pixel
        result[f"feature_cosine_{side}"] = {"mean": round(float(cosine.mean()), 5),
                                            "p01": round(float(np.percentile(cosine, 1)), 5)}
    if importlib.util.find_spec("service.matcher") is None:
        result["disparity_agreement_1px"] = None  # runtime without a matcher: features only
        return result
    from service.matcher import Matcher

    disparities = [Matcher.from_folder(f)(left, right).disparity for f in (fp32_folder, int8_folder)]
    both = np.isfinite(disparities[0]) & np.isfinite(disparities[1])
    agree = both & (np.abs(disparities[0] - disparities[1]) <= 1.0)
    result["disparity_agreement_1px"] = round(float(agree.sum() / max(both.sum(), 1)), 5)
    result["disparity_both_defined"] = round(float(both.mean()), 5)
    return result


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m export.quantize", description=__doc__.split("\n\n")[0])
    parser.add_argument("--model", required=True, type=Path, help="fp32 model folder to quantise")
    parser.add_argument("--out", required=True, type=Path,
                        help="int8 model folder to write (created if needed)")
    parser.add_argument("--calibration", default=DEFAULT_CALIBRATION, help=CALIBRATION_HELP)
    parser.add_argument("--no-measure", action="store_true",
                        help="write empty metrics (default: measure the data sets the fp32 folder's metrics "
                             "record; later: python -m export.measure --model DIR --write)")
    parser.add_argument("--threads", type=int, metavar="N",
                        help="runtime threads for the metrics (default: all CPUs)")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    command = shlex.join(["python", "-m", "export.quantize", *(sys.argv[1:] if argv is None else argv)])
    if args.model.resolve() == args.out.resolve():
        print("export.quantize: error: --out must differ from --model (the fp32 folder is the source)",
              file=sys.stderr)
        return 1
    try:
        manifest_path = quantize_folder(args.model, args.out, calibration=args.calibration,
                                        datasets={} if args.no_measure else None, threads=args.threads,
                                        command=command, log=print)
    except (OSError, ValueError, ModelError) as error:
        print(f"export.quantize: error: {error}", file=sys.stderr)
        return 1
    print(f"wrote {manifest_path.parent} (int8)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
