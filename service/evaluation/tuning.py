"""SGM penalty tuning: the one rule by which every shipped model's P1 and P2 are chosen.

A grid of (P1, P2) runs through the runtime's own Matcher on the fixed synthetic validation split
(``synthetic:20``; never on a real pair with ground truth), and the pair with the lowest bad-2 over every
ground-truth pixel wins, EPE breaking ties. Trained models (``python -m training.validate --tune``) and
the NCC baseline (``python -m export.baseline --measure``) use this same function, so "a trained model
beats the baseline" compares models tuned alike.

Only P1 / scale and P2 / scale change SGM's winners, so the cost scale stays at the contract's 128 and
the penalties move.

Not run as a doctest: it needs the train extra's generator and minutes of matching. The shipped NCC
baseline's 7x7 window, as its manifest records it (``build.selection``, where each window from 3x3 to
13x13 went through this rule and the lowest bad-2 chose the window):

>>> matcher = Matcher.from_folder("service/models/ncc-baseline")       # a model  # doctest: +SKIP
>>> choice, rows = tune_penalties(matcher, open_dataset(TUNING_DATA))  # 25 x 20 runs  # doctest: +SKIP
>>> choice                                                             # its result  # doctest: +SKIP
{'p1': 45.0, 'p2': 540.0}
"""

from __future__ import annotations

import dataclasses
import itertools
import json
from collections.abc import Callable, Sequence
from typing import Any

from service.datasets import StereoSample
from service.matcher import MatchOptions

from .evaluate import StereoFunction, evaluate

P1_GRID = (10.0, 20.0, 30.0, 45.0, 65.0)
P2_GRID = (80.0, 160.0, 240.0, 360.0, 540.0)
TUNING_DATA = "synthetic:20"


def tune_penalties(matcher: StereoFunction, dataset: Sequence[StereoSample], *,
                   p1_grid: Sequence[float] = P1_GRID, p2_grid: Sequence[float] = P2_GRID,
                   log: Callable[[str], Any] | None = None,
                   options: MatchOptions | None = None) -> tuple[dict[str, float], list[dict[str, Any]]]:
    """The (P1, P2) of the grid (P2 >= P1) with the lowest all-pixel bad-2 on ``dataset``, and every row.

    ``options`` sets the other steps (default: the model's); its P1 and P2 are replaced by the grid's.
    Only the stages after the towers depend on P1 and P2: a matcher whose towers are
    :class:`~service.features.CachedTowers` runs them once per pair.
    """
    options = MatchOptions() if options is None else options
    # Every grid point reads every pair: a generated split renders each pair once, not 25 times.
    samples = [dataset[index] for index in range(len(dataset))]
    rows = []
    for p1, p2 in itertools.product(p1_grid, p2_grid):
        if p2 < p1:
            continue
        report = evaluate(matcher, samples, options=dataclasses.replace(options, p1=p1, p2=p2))
        rows.append({"p1": p1, "p2": p2, "bad2": report["all"]["bad2"], "bad3": report["all"]["bad3"],
                     "epe": report["all"]["epe"]})
        if log is not None:
            log(json.dumps(rows[-1]))
    if not rows:
        raise ValueError("the P1/P2 grid has no pair with P2 >= P1")
    best = min(rows, key=lambda row: (row["bad2"], row["epe"]))
    return {"p1": best["p1"], "p2": best["p2"]}, rows
