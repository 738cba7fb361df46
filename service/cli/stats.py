"""`adsm stats --data SPEC [--data SPEC ...]`: what each dataset's scenes and cameras are like.

No model: per dataset, the share of ground-truth pixels at depth edges, the left view's texture and the
photometric residual at the true match (service/evaluation/scene_statistics.py), one row per dataset, so
that a user's KITTI or Middlebury copy can be set beside the synthetic validation split that chose the
shipped models (docs/data.md, "What the split's scenes are like"). One progress line per pair goes to
stderr; ``--json OUT`` writes every pair's figures (``-``: to stdout instead of the table).
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

from service.cli.reports import emit_report, report_path
from service.datasets import open_dataset
from service.evaluation.scene_statistics import EDGE_REACH, FLAT, WEAK, SceneStatistics

REPORT_SCHEMA = "adsm-stats/1"


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "stats", help="describe datasets: depth edges, texture, photometric residual at the true match",
        description="Describe datasets with ground truth beside each other (no model): the share of pixels "
                    f"within {EDGE_REACH} px of a depth edge, the left view's 3x3 texture (median grey "
                    f"levels, share below {FLAT:g} and {WEAK:g}) and the median 1 - ZNCC of 3x3 windows at "
                    "the true match.",
    )
    parser.add_argument("--data", required=True, action="append", metavar="SPEC",
                        help="a dataset, as for adsm eval (repeat to compare: --data synthetic:20 --data "
                             "kitti2015:PATH)")
    parser.add_argument("--json", metavar="OUT",
                        help="write every pair's figures as JSON to OUT ('-': stdout)")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    report_path(args.json)  # before the work: a bad path would lose it
    datasets = [(spec, open_dataset(spec)) for spec in args.data]  # every SPEC checked before any work
    report: dict[str, Any] = {"schema": REPORT_SCHEMA, "datasets": []}
    for spec, dataset in datasets:
        statistics = SceneStatistics()
        pairs = []
        for index in range(len(dataset)):
            sample = dataset[index]
            figures = statistics.add(sample.left, sample.right, sample.disparity)
            pairs.append({"name": sample.name, **figures})
            print(f"[{spec} {index + 1}/{len(dataset)}] {sample.name}: depth edges "
                  f"{figures['depth_edges']} %, texture median {figures['texture_median']}", file=sys.stderr)
        report["datasets"].append({"dataset": spec, "pairs": len(dataset), "all": statistics.summary(),
                                   "per_pair": pairs})
    emit_report(report, args.json, format_table)
    return 0


def format_table(report: dict[str, Any]) -> str:
    """One row per dataset; '-' where a figure had no pixel to count."""
    headers = ("pairs", f"edges<={EDGE_REACH}px %", "texture median", f"texture<{FLAT:g} %",
               f"texture<{WEAK:g} %", "residual median")
    keys = (("depth_edges", ".2f"), ("texture_median", ".2f"), ("texture_flat", ".2f"),
            ("texture_weak", ".2f"), ("residual_median", ".3f"))
    width = max(12, *(len(entry["dataset"]) for entry in report["datasets"])) + 2
    lines = [f"{'dataset':<{width}}" + "".join(f"{h:>16}" for h in headers)]
    for entry in report["datasets"]:
        figures = entry["all"]
        cells = [f"{entry['pairs']:>16}"] + [
            f"{'-' if figures[key] is None else format(figures[key], spec):>16}" for key, spec in keys]
        lines.append(f"{entry['dataset']:<{width}}" + "".join(cells))
    return "\n".join(lines)
