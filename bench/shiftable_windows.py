"""Accuracy of the shiftable-window radius on the synthetic split and Cones (a runtime experiment).

    python -m bench shiftable_windows [--models service/models/adsm-rf11 ...] [--radii 0 1 2 3]
                                      [--pairs 20] [--p1 P1 --p2 P2]

Every model folder runs the whole Matcher once per radius (0: the step off, ``shiftable_windows=False``;
r > 0: ``service.aggregation.shiftable_windows`` with that radius in place of :data:`SHIFT_RADIUS`), at the
folder's own P1/P2 unless given, and is scored like ``adsm eval``: every ground-truth pixel, and the
accepted-pixel bad-2 of the error breakdown. The shipped radius was chosen on the synthetic split with
each folder's P1/P2 tuned again by the rule (``python -m export.tune``); Cones is printed, never chosen
on (docs/training.md, "Shiftable windows").
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
from unittest import mock

import service.matcher
from bench import positive_int
from service.aggregation import SHIFT_RADIUS, shiftable_windows
from service.datasets import open_dataset
from service.evaluation.evaluate import evaluate
from service.matcher import Matcher, MatchOptions
from training.data.evaluation_only import CONES_SPEC


def score(matcher: Matcher, radius: int, spec: str, max_disparity: int | None,
          options: MatchOptions) -> dict[str, float]:
    """bad-2, bad-1, EPE and accepted-pixel bad-2 of one folder at one radius on one data set."""
    options = dataclasses.replace(options, shiftable_windows=radius > 0)
    step = functools.partial(shiftable_windows, radius=max(radius, 0))
    with mock.patch.object(service.matcher, "shiftable_windows", step):
        report = evaluate(matcher, open_dataset(spec), max_disparity=max_disparity, options=options)
    return {**{key: report["all"][key] for key in ("bad2", "bad1", "epe")},
            "accepted": report["breakdown"]["regions"]["accepted"]["bad2"]}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench shiftable_windows",
                                     description=__doc__.splitlines()[0])
    parser.add_argument("--models", nargs="+", default=["service/models/adsm-fast"], metavar="DIR")
    parser.add_argument("--radii", type=int, nargs="+", default=[0, SHIFT_RADIUS, 2], metavar="R",
                        help=f"radii to compare, 0 = off (default: 0, the shipped {SHIFT_RADIUS}, 2)")
    parser.add_argument("--pairs", type=positive_int, default=20,
                        help="synthetic validation pairs (default 20)")
    parser.add_argument("--p1", type=float, help="SGM P1 for every folder (default: each folder's own)")
    parser.add_argument("--p2", type=float, help="SGM P2 for every folder (default: each folder's own)")
    args = parser.parse_args(argv)
    if min(args.radii) < 0:
        parser.error("every radius must be >= 0")
    options = MatchOptions(p1=args.p1, p2=args.p2)
    data = (("synthetic", f"synthetic:{args.pairs}", None), ("cones", CONES_SPEC, 64))
    print(f"{'model':24}{'radius':>7}{'data':>10}{'bad-2 %':>9}{'bad-1 %':>9}{'EPE px':>8}"
          f"{'accepted bad-2 %':>18}")
    for folder in args.models:
        matcher = Matcher.from_folder(folder)
        matcher.warmup()
        for radius in args.radii:
            for label, spec, search in data:
                figures = score(matcher, radius, spec, search, options)
                print(f"{folder.rstrip('/').split('/')[-1]:24}{radius:7d}{label:>10}{figures['bad2']:9.2f}"
                      f"{figures['bad1']:9.2f}{figures['epe']:8.3f}{figures['accepted']:18.2f}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
