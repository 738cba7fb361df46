"""`adsm eval --model DIR --data SPEC`: a model's accuracy and speed on a dataset, as the paper tabulates.

Prints bad-1..5 (the paper's N-pixel errors, %), EPE, D1 and density over every ground-truth pixel and
over the non-occluded ones where the dataset has a mask, the error breakdown (border strip, rejected by
the check, accepted pixels by distance to a disparity jump: service/evaluation/breakdown.py), plus
seconds per pair; one progress line per
pair goes to stderr. ``--json OUT`` writes the full report (``-``: to stdout instead of the table).
SPEC: synthetic[:N] | synthetic-clean[:N] | synthetic-curved[:N] | synthetic-fine[:N] |
synthetic-downsampled[:N] | motorcycle | kitti2012:PATH | kitti2015:PATH | middlebury:PATH | cones:PATH |
PATH.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path
from typing import Any

from service.cli.match_flags import add_match_flags, match_options
from service.cli.reports import emit_report, report_path
from service.cuda import DEVICE_HELP, DEVICES
from service.datasets import open_dataset
from service.datasets.noise import NoisyViews
from service.evaluation import BAD_THRESHOLDS
from service.evaluation.breakdown import format_breakdown
from service.evaluation.sparsification import format_sparsification


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "eval", help="measure a model's bad-N, EPE, D1 and speed on a dataset",
        description="Measure a model on a dataset with ground truth: bad-1..5 %, EPE, D1, density and "
                    "seconds per pair, over every ground-truth pixel (dense output).",
    )
    add = parser.add_argument
    add("--model", type=Path, metavar="DIR", help="model folder (default: $ADSM_MODEL_DIR or the shipped)")
    add("--data", required=True, metavar="SPEC",
        help="synthetic[:N] | synthetic-clean[:N] (the same scenes without camera effects) | "
             "synthetic-curved[:N] | synthetic-fine[:N] (with those training levers at 0.5) | "
             "synthetic-downsampled[:N] (photographed at 2x, averaged 2 x 2) | motorcycle "
             "(Middlebury 2014's Motorcycle as scikit-image ships it; these six need the train extra) | "
             "kitti2012:PATH | kitti2015:PATH | middlebury:PATH | cones:PATH | PATH")
    add("--max-disparity", type=int, metavar="D",
        help="disparity range D (default: the dataset's recommendation, else the model's)")
    add_match_flags(add, steps=("adaptive_p2", "right_sgm", "background_fill", "weighted_median"))
    add("--confidence", action="store_true",
        help="also compute the confidence map and print its sparsification curve (bad-2 of the most "
        "confident 10..100 %% of the pixels)")
    add("--noise", type=float, default=0.0, metavar="SIGMA",
        help="add Gaussian noise of SIGMA grey levels (0-255) to both views of every pair, seeded per pair: "
             "how the model degrades with noisier cameras (service/datasets/noise.py)")
    add("--threads", type=int, metavar="N", help="ONNX Runtime and Numba threads (default: all CPUs)")
    add("--device", choices=DEVICES, help=DEVICE_HELP)
    add("--json", metavar="OUT", help="write the full report as JSON to OUT ('-': stdout, no table)")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    report_path(args.json)  # before the evaluation: a bad path would lose the whole run
    dataset = open_dataset(args.data)
    if args.noise:
        dataset = NoisyViews(dataset, sigma=args.noise)
    # Imported here so that `adsm --help` does not pay for Numba and ONNX Runtime.
    from service.evaluation.evaluate import evaluate
    from service.matcher import Matcher

    matcher = Matcher.from_folder(args.model, threads=args.threads, device=args.device)
    options = dataclasses.replace(match_options(args), confidence=args.confidence)
    matcher.warmup()

    def progress(index: int, pair: dict[str, Any]) -> None:
        print(f"[{index + 1}/{len(dataset)}] {pair['name']}: bad-2 {pair['all']['bad2']:.2f} %, "
              f"{pair['seconds']:.3f} s", file=sys.stderr)

    report = evaluate(matcher, dataset, max_disparity=args.max_disparity, options=options, on_pair=progress)
    report["model_folder"] = str(args.model) if args.model is not None else None
    report["noise_sigma"] = args.noise
    emit_report(report, args.json, format_table)
    return 0


def format_table(report: dict[str, Any]) -> str:
    """The paper's table shape: one row per pixel subset, error rates in %."""
    columns = [f"bad{t}" for t in BAD_THRESHOLDS] + ["epe", "d1", "density"]
    headers = [f"bad-{t} %" for t in BAD_THRESHOLDS] + ["EPE px", "D1 %", "density %"]
    lines = [f"model {report['model']} on {report['dataset']}: {report['pairs']} pair(s)",
             f"{'pixels':<12}" + "".join(f"{h:>11}" for h in headers)]
    for subset in ("all", "nonoccluded"):
        figures = report[subset]
        if figures is None:
            continue
        cells = "".join(f"{'-' if figures[c] is None else format(figures[c], '.2f'):>11}" for c in columns)
        lines.append(f"{subset:<12}{cells}")
    if "breakdown" in report:
        lines.append(format_breakdown(report["breakdown"]))
    if "sparsification" in report:
        lines.append(format_sparsification(report["sparsification"]))
    lines.append(f"seconds per pair: {report['seconds_per_pair']:.3f}  (stages: "
                 + ", ".join(f"{k} {v:.3f}" for k, v in report["stage_seconds"].items()) + ")")
    return "\n".join(lines)
