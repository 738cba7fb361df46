"""Accuracy of the occlusion fill's background run on the synthetic split and Cones (a runtime experiment).

    python -m bench background_fill [--model service/models/adsm-fast-int8] [--pairs 20] [--runs 1 2 4 12]

Each pair runs once through the Matcher up to the left-right check (``fill``, ``border`` and the weighted
median off); every run K then finishes it as the Matcher does (``fill_invalid`` with ``background_run=K``,
the border band, the weighted median) and is scored like ``adsm eval``: every ground-truth pixel, the
accepted-pixel bad-2 of the error breakdown, and the pixels the check called occluded (median error and
bad-2, weighted median off, as tests/service/filling/test_filling_cones.py measures them). K = 1 is
MC-CNN's rule; the shipped run (``service.filling.BACKGROUND_RUN``) was chosen from this table by the
synthetic split, confirmed by Cones (docs/training.md, "What the check rejects").
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass, field

import numpy as np

from service.datasets import open_dataset
from service.evaluation import count_errors
from service.evaluation.breakdown import Breakdown
from service.evaluation.metrics import ErrorCounts
from service.filling import BACKGROUND_RUN, fill_border_band, fill_invalid
from service.filtering import weighted_median
from service.matcher import Matcher, MatchOptions, Validity
from training.data.evaluation_only import CONES_SPEC


@dataclass
class Score:
    counts: ErrorCounts = field(default_factory=ErrorCounts)
    breakdown: Breakdown = field(default_factory=Breakdown)
    occluded_errors: list[np.ndarray] = field(default_factory=list)


def sweep(matcher: Matcher, spec: str, max_disparity: int | None, runs: list[int]) -> dict[int, Score]:
    scores = {run: Score() for run in runs}
    for sample in open_dataset(spec):
        search = max_disparity or sample.max_disparity
        options = MatchOptions(max_disparity=search, fill=False, border=False, weighted_median=False)
        checked = matcher(sample.left, sample.right, options)
        # Occluded as the check said, outside the left border band (that step overwrites the band).
        _, unfilled_codes = fill_border_band(checked.disparity, checked.validity)
        occluded = (unfilled_codes == Validity.OCCLUDED) & np.isfinite(sample.disparity)
        for run, score in scores.items():
            filled, validity = fill_invalid(checked.disparity, checked.validity, background_run=run)
            banded, validity = fill_border_band(filled, validity)
            score.occluded_errors.append(np.abs(banded - sample.disparity)[occluded])
            disparity = weighted_median(banded, sample.left)
            score.counts += count_errors(disparity, sample.disparity)
            score.breakdown += Breakdown().add(disparity, sample.disparity, validity)
    return scores


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench background_fill",
                                     description=__doc__.splitlines()[0])
    parser.add_argument("--model", default="service/models/adsm-fast-int8")
    parser.add_argument("--pairs", type=int, default=20, help="synthetic validation pairs (default 20)")
    parser.add_argument("--runs", type=int, nargs="+", default=[1, BACKGROUND_RUN, 4, 12], metavar="K",
                        help="background runs to compare (default: MC-CNN's 1, the shipped one, 4, 12)")
    args = parser.parse_args(argv)
    if min(args.runs) < 1:
        parser.error("every run must be >= 1")
    matcher = Matcher.from_folder(args.model)
    matcher.warmup()
    print(f"{'run K':>6}{'data':>10}{'bad-2 %':>9}{'bad-1 %':>9}{'accepted bad-2 %':>18}"
          f"{'occluded: median px':>21}{'bad-2 %':>9}")
    for label, spec, search in (("synthetic", f"synthetic:{args.pairs}", None), ("cones", CONES_SPEC, 64)):
        for run, score in sweep(matcher, spec, search, sorted(set(args.runs))).items():
            figures = score.counts.summary()
            accepted = score.breakdown.summary()["regions"]["accepted"]["bad2"]
            errors = np.concatenate(score.occluded_errors)
            print(f"{run:6d}{label:>10}{figures['bad2']:9.2f}{figures['bad1']:9.2f}{accepted:18.2f}"
                  f"{np.median(errors):21.2f}{100 * np.mean(errors > 2):9.1f}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
