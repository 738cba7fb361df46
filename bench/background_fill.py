"""Accuracy of the fill's background bias on the synthetic split and Cones (a runtime experiment).

    python -m bench background_fill [--model service/models/adsm-fast-int8] [--pairs 20] [--runs 1 2 4 12]
                                    [--fractions 1/2 1/3 1/4]

Each pair runs once through the Matcher up to the left-right check (``fill``, ``border`` and the weighted
median off); every variant then finishes it as the Matcher does (``fill_invalid`` with an occlusion run K
and a mismatch fraction n/d, the border band, the weighted median) and is scored like ``adsm eval``: every
ground-truth pixel, the accepted-pixel bad-2 of the error breakdown, and the pixels the check called
occluded (median error and bad-2, weighted median off, as tests/service/filling/test_filling_cones.py
measures them). The variants: each run with the shipped fraction, each fraction with the shipped run.
K = 1 and 1/2 are MC-CNN's rules; the shipped ones (``service.filling.BACKGROUND_RUN``,
``MISMATCH_FRACTION``) were chosen from this table by the synthetic split, confirmed by Cones
(docs/training.md, "What the check rejects").
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass, field

import numpy as np

from bench import positive_int
from service.datasets import open_dataset
from service.evaluation import count_errors
from service.evaluation.breakdown import Breakdown
from service.evaluation.metrics import ErrorCounts
from service.filling import BACKGROUND_RUN, MISMATCH_FRACTION, fill_border_band, fill_invalid
from service.filtering import weighted_median
from service.matcher import Matcher, MatchOptions, Validity
from training.data.evaluation_only import CONES_SPEC


@dataclass
class Score:
    counts: ErrorCounts = field(default_factory=ErrorCounts)
    breakdown: Breakdown = field(default_factory=Breakdown)
    occluded_errors: list[np.ndarray] = field(default_factory=list)


Variant = tuple[int, tuple[int, int]]  # (occlusion run, mismatch fraction)


def sweep(matcher: Matcher, spec: str, max_disparity: int | None,
          variants: list[Variant]) -> dict[Variant, Score]:
    scores = {variant: Score() for variant in variants}
    for sample in open_dataset(spec):
        search = max_disparity or sample.max_disparity
        options = MatchOptions(max_disparity=search, fill=False, border=False, weighted_median=False)
        checked = matcher(sample.left, sample.right, options)
        # Occluded as the check said, outside the left border band (that step overwrites the band).
        _, unfilled_codes = fill_border_band(checked.disparity, checked.validity)
        occluded = (unfilled_codes == Validity.OCCLUDED) & np.isfinite(sample.disparity)
        for (run, fraction), score in scores.items():
            filled, validity = fill_invalid(checked.disparity, checked.validity, background_run=run,
                                            mismatch_fraction=fraction)
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
    parser.add_argument("--pairs", type=positive_int, default=20,
                        help="synthetic validation pairs (default 20)")
    parser.add_argument("--runs", type=positive_int, nargs="+", default=[1, BACKGROUND_RUN, 4, 12],
                        metavar="K",
                        help="occlusion runs to compare (default: MC-CNN's 1, the shipped one, 4, 12)")
    parser.add_argument("--fractions", nargs="+", default=["1/2", "1/3", "1/4"], metavar="N/D",
                        help="mismatch fractions to compare (default: MC-CNN's 1/2, 1/3, 1/4)")
    args = parser.parse_args(argv)
    if min(args.runs) < 1:
        parser.error("every run must be >= 1")
    try:
        fractions = [(int(text.split("/")[0]), int(text.split("/")[1])) for text in args.fractions]
    except (IndexError, ValueError):
        parser.error(f"fractions are N/D, got {args.fractions}")
    if any(not 0 <= n < d for n, d in fractions):
        parser.error("every fraction N/D needs 0 <= N < D")
    variants = sorted({*((run, MISMATCH_FRACTION) for run in args.runs),
                       *((BACKGROUND_RUN, fraction) for fraction in fractions)})
    matcher = Matcher.from_folder(args.model)
    matcher.warmup()
    print(f"{'run K':>6}{'fraction':>9}{'data':>10}{'bad-2 %':>9}{'bad-1 %':>9}{'accepted bad-2 %':>18}"
          f"{'occluded: median px':>21}{'bad-2 %':>9}")
    for label, spec, search in (("synthetic", f"synthetic:{args.pairs}", None), ("cones", CONES_SPEC, 64)):
        for (run, (n, d)), score in sweep(matcher, spec, search, variants).items():
            figures = score.counts.summary()
            accepted = score.breakdown.summary()["regions"]["accepted"]["bad2"]
            errors = np.concatenate(score.occluded_errors)
            print(f"{run:6d}{f'{n}/{d}':>9}{label:>10}{figures['bad2']:9.2f}{figures['bad1']:9.2f}{accepted:18.2f}"
                  f"{np.median(errors):21.2f}{100 * np.mean(errors > 2):9.1f}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
