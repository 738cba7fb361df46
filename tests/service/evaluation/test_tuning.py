"""The shared SGM penalty rule (service.evaluation.tuning): lowest all-pixel bad-2, EPE breaking ties."""

from __future__ import annotations

import numpy as np
import pytest

from service.datasets import StereoSample
from service.evaluation.tuning import tune_penalties
from service.matcher import MatchOptions, StereoResult


def _dataset() -> list[StereoSample]:
    rng = np.random.default_rng(0)
    disparity = rng.uniform(1, 20, (12, 16)).astype(np.float32)
    image = rng.integers(0, 255, (12, 16, 3), dtype=np.uint8)
    return [StereoSample(name="plane", left=image, right=image, disparity=disparity, max_disparity=24)]


def _matcher_best_at(p1: float, p2: float, truth: np.ndarray):
    def match(left: np.ndarray, right: np.ndarray, options: MatchOptions) -> StereoResult:
        # Exact at the target penalties; 3 px off on a third of the pixels elsewhere, more so for larger P1.
        disparity = truth.copy()
        if (options.p1, options.p2) != (p1, p2):
            disparity[:4] += 3 + options.p1 / 100
        validity = np.zeros(truth.shape, np.uint8)
        return StereoResult(disparity, validity, {"total": 0.0})

    return match


def test_picks_the_lowest_bad2_and_reports_every_grid_pair() -> None:
    dataset = _dataset()
    choice, rows = tune_penalties(_matcher_best_at(20.0, 240.0, dataset[0].disparity), dataset)
    assert choice == {"p1": 20.0, "p2": 240.0}
    assert len(rows) == 25 and all(row["p2"] >= row["p1"] for row in rows)
    assert min(rows, key=lambda row: row["bad2"])["bad2"] == 0.0


def test_epe_breaks_ties_and_p2_below_p1_is_skipped() -> None:
    dataset = _dataset()
    choice, rows = tune_penalties(_matcher_best_at(-1, -1, dataset[0].disparity), dataset,
                                  p1_grid=(10.0, 50.0, 400.0), p2_grid=(100.0, 300.0))
    assert {(row["p1"], row["p2"]) for row in rows} == {(10, 100), (10, 300), (50, 100), (50, 300)}
    assert choice["p1"] == 10.0  # every pair has the same bad-2; the smallest P1 has the smallest EPE


def test_an_empty_grid_is_an_error() -> None:
    with pytest.raises(ValueError, match="P2 >= P1"):
        dataset = _dataset()
        tune_penalties(_matcher_best_at(1, 1, dataset[0].disparity), dataset, p1_grid=(9.0,), p2_grid=(1.0,))
