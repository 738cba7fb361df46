"""Tower scale: accuracy on the synthetic split and the real pairs, and KITTI-size predict time, per scale.

    python -m bench tower_scale [--models service/models/adsm-fast ...] [--scales 1 2] [--pairs 20]
                                [--repeats 3] [--threads 2] [--no-accuracy] [--no-time]

Every model folder runs the whole Matcher at each ``MatchOptions.tower_scale`` (service/features/scale.py)
at the folder's own P1/P2, scored like ``adsm eval`` (every ground-truth pixel; ``accepted``: the
accepted-pixel bad-2 of the error breakdown), then times a KITTI-size pair (375x1242, D = 192, the
suite's textured pair, ``bench.runtime.realistic_images``) in one process, warm: the scales interleaved,
``--repeats`` rounds, the median of the whole call and of its ``towers`` stage. The real pairs, Cones and
Motorcycle (the SPEC ``motorcycle``), are printed, never chosen on (docs/training.md, "Tower scale").
"""

from __future__ import annotations

import argparse
import statistics

import numpy as np

from bench import positive_int
from bench.runtime import realistic_images
from bench.suite import SIZES
from service.datasets import open_dataset
from service.evaluation.evaluate import evaluate
from service.features.scale import MAX_TOWER_SCALE
from service.matcher import Matcher, MatchOptions
from training.data.evaluation_only import CONES_SPEC, MOTORCYCLE_SPEC

KITTI_SIZE, KITTI_DISPARITIES = SIZES["kitti"][:2], SIZES["kitti"][2]  # the suite's KITTI-size pair


def accuracy(matcher: Matcher, scale: int, spec: str, max_disparity: int | None) -> dict[str, float]:
    """bad-2, bad-1 and accepted-pixel bad-2 of one folder at one scale on one data set."""
    report = evaluate(matcher, open_dataset(spec), max_disparity=max_disparity,
                      options=MatchOptions(tower_scale=scale))
    return {"bad2": report["all"]["bad2"], "bad1": report["all"]["bad1"],
            "accepted": report["breakdown"]["regions"]["accepted"]["bad2"]}


def kitti_times(matcher: Matcher, scales: list[int], repeats: int) -> dict[int, tuple[float, float]]:
    """Median (call seconds, towers seconds) per scale on a KITTI-size pair, scales interleaved."""
    left, right = realistic_images(*KITTI_SIZE, KITTI_DISPARITIES, np.random.default_rng(0))
    runs: dict[int, list[tuple[float, float]]] = {scale: [] for scale in scales}
    for round_ in range(repeats + 1):
        for scale in scales:
            result = matcher(left, right,
                             MatchOptions(max_disparity=KITTI_DISPARITIES, tower_scale=scale))
            if round_:  # the first round warms every scale's shapes
                runs[scale].append((result.timings["total"], result.timings["towers"]))
    return {scale: (statistics.median(t for t, _ in times), statistics.median(t for _, t in times))
            for scale, times in runs.items()}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench tower_scale", description=__doc__.splitlines()[0])
    parser.add_argument("--models", nargs="+", default=["service/models/adsm-fast"], metavar="DIR")
    parser.add_argument("--scales", type=int, nargs="+", default=[1, 2], metavar="S",
                        help=f"tower scales to compare, 1..{MAX_TOWER_SCALE} (default: 1 2)")
    parser.add_argument("--pairs", type=positive_int, default=20, help="synthetic validation pairs (20)")
    parser.add_argument("--repeats", type=positive_int, default=3, help="timed rounds (3)")
    parser.add_argument("--threads", type=positive_int, default=2, help="matcher threads (2)")
    parser.add_argument("--no-accuracy", dest="accuracy", action="store_false", help="times only")
    parser.add_argument("--no-time", dest="time", action="store_false", help="accuracy only")
    args = parser.parse_args(argv)
    if not all(1 <= scale <= MAX_TOWER_SCALE for scale in args.scales):
        parser.error(f"every scale must be in 1..{MAX_TOWER_SCALE}")
    data = ((f"synthetic:{args.pairs}", None), (CONES_SPEC, 64), (MOTORCYCLE_SPEC, 64))
    print(f"{'model':18}{'scale':>6}{'synthetic bad-2/1 %':>21}{'Cones bad-2/1 %':>17}{'accepted %':>12}"
          f"{'Motorcycle bad-2/1 %':>22}{'KITTI s':>9}{'towers s':>10}")
    for folder in args.models:
        matcher = Matcher.from_folder(folder, threads=args.threads)
        matcher.warmup()
        times = kitti_times(matcher, args.scales, args.repeats) if args.time else {}
        for scale in args.scales:
            row = f"{folder.rstrip('/').split('/')[-1]:18}{scale:6d}"
            if args.accuracy:
                synthetic, cones, motorcycle = (accuracy(matcher, scale, spec, search)
                                                for spec, search in data)
                row += (f"{synthetic['bad2']:12.2f} / {synthetic['bad1']:5.2f}{cones['bad2']:8.2f} / "
                        f"{cones['bad1']:5.2f}{cones['accepted']:12.2f}"
                        f"{motorcycle['bad2']:13.2f} / {motorcycle['bad1']:5.2f}")
            else:
                row += " " * 72
            if scale in times:
                row += f"{times[scale][0]:9.2f}{times[scale][1]:10.2f}"
            print(row, flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
