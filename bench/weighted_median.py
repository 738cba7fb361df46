"""Accuracy of the weighted-median step's constants on the synthetic split and Cones (a runtime experiment).

    python -m bench weighted_median [--model service/models/adsm-fast-int8] [--pairs 20]

Each pair runs once through the Matcher without the step; every variant then filters that disparity map
(``service.filtering.weighted_median`` with its radius and weights; ``t``: keep a pixel's value unless the
median moves it by more than t px) and is scored like ``adsm eval`` (every ground-truth pixel, plus the
accepted-pixel bad-2 of the error breakdown). The step's constants were chosen from this table on the
synthetic split (docs/training.md, "Image-guided weighted median"); Cones is printed, never chosen on.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable

import numpy as np
from scipy import ndimage

from bench import positive_int
from service.datasets import open_dataset
from service.evaluation import count_errors
from service.evaluation.breakdown import Breakdown
from service.evaluation.metrics import ErrorCounts
from service.filtering import weighted_median
from service.filtering.weighted_median import EDGE_SPREAD
from service.matcher import Matcher, MatchOptions
from training.data.evaluation_only import CONES_SPEC

Filter = Callable[[np.ndarray, np.ndarray], np.ndarray]


def _weighted(radius: int, sigma_colour: float, sigma_space: float, change: float = 0.0,
              spread: float = EDGE_SPREAD, passes: int = 1) -> Filter:
    def apply(disparity: np.ndarray, left: np.ndarray) -> np.ndarray:
        filtered = disparity
        for _ in range(passes):
            filtered = weighted_median(filtered, left, radius=radius, sigma_colour=sigma_colour,
                                       sigma_space=sigma_space, edge_spread=spread)
        return np.where(np.abs(filtered - disparity) > change, filtered, disparity) if change else filtered
    return apply


VARIANTS: dict[str, Filter] = {
    "none": lambda disparity, left: disparity,
    "plain 5x5 median": lambda disparity, left: ndimage.median_filter(disparity, 5, mode="nearest"),
    "weighted r 3, 10 / 5": _weighted(3, 10.0, 5.0),
    "weighted r 5, 10 / 5": _weighted(5, 10.0, 5.0),
    "weighted r 5, 20 / 5 (shipped)": _weighted(5, 20.0, 5.0),
    "weighted r 5, 20 / 5, t 1 px": _weighted(5, 20.0, 5.0, change=1.0),
    "weighted r 5, 20 / 5, spread 0.5": _weighted(5, 20.0, 5.0, spread=0.5),
    "weighted r 5, 20 / 5, spread 1.0": _weighted(5, 20.0, 5.0, spread=1.0),
    "weighted r 5, 20 / 5, spread 2.5": _weighted(5, 20.0, 5.0, spread=2.5),
    "weighted r 5, 20 / 5, two passes": _weighted(5, 20.0, 5.0, passes=2),
    "weighted r 5, 20 / 10": _weighted(5, 20.0, 10.0),
    "weighted r 7, 10 / 5": _weighted(7, 10.0, 5.0),
    "weighted r 7, 10 / inf": _weighted(7, 10.0, 1e6),
}


def sweep(matcher: Matcher, spec: str, max_disparity: int | None) -> dict[str, tuple[ErrorCounts, Breakdown]]:
    scores = {name: (ErrorCounts(), Breakdown()) for name in VARIANTS}
    for sample in open_dataset(spec):
        search = max_disparity or sample.max_disparity
        result = matcher(sample.left, sample.right, MatchOptions(max_disparity=search, weighted_median=False))
        for name, apply in VARIANTS.items():
            disparity = apply(result.disparity, sample.left).astype(np.float32)
            counts, breakdown = scores[name]
            counts += count_errors(disparity, sample.disparity)
            breakdown += Breakdown().add(disparity, sample.disparity, result.validity)
    return scores


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench weighted_median",
                                     description=__doc__.splitlines()[0])
    parser.add_argument("--model", default="service/models/adsm-fast-int8")
    parser.add_argument("--pairs", type=positive_int, default=20,
                        help="synthetic validation pairs (default 20)")
    args = parser.parse_args(argv)
    matcher = Matcher.from_folder(args.model)
    matcher.warmup()
    print(f"{'variant':34}{'data':>10}{'bad-2 %':>9}{'bad-1 %':>9}{'EPE px':>8}{'accepted bad-2 %':>18}")
    for label, spec, search in (("synthetic", f"synthetic:{args.pairs}", None),
                                ("cones", CONES_SPEC, 64)):
        for name, (counts, breakdown) in sweep(matcher, spec, search).items():
            figures = counts.summary()
            accepted = breakdown.summary()["regions"]["accepted"]["bad2"]
            print(f"{name:34}{label:>10}{figures['bad2']:9.2f}{figures['bad1']:9.2f}{figures['epe']:8.3f}"
                  f"{accepted:18.2f}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
