"""service.evaluation.comparison: the paired bootstrap that says whether the pairs tell two matchers apart."""

from __future__ import annotations

import numpy as np
import pytest

from service.evaluation.comparison import compare_reports, pair_errors, paired_difference, pool_reports


def _report(percent: list[float], pixels: int = 1000, names: list[str] | None = None) -> dict:
    names = names or [f"pair-{index}" for index in range(len(percent))]
    return {"per_pair": [{"name": name, "all": {"bad2": value, "pixels": pixels}}
                         for name, value in zip(names, percent, strict=True)]}


def test_a_consistent_gap_is_resolved_and_equal_matchers_are_not():
    rng = np.random.default_rng(3)
    base = rng.uniform(50, 150, 40)
    pixels = np.full(40, 1000.0)
    better = paired_difference(base, base - rng.uniform(5, 15, 40), pixels)
    assert better.resolved and better.high < 0 and better.other_better_pairs == 40
    assert better.low <= better.difference <= better.high
    same = paired_difference(base, base + rng.normal(0, 10, 40), pixels)
    assert not same.resolved and same.low < 0 < same.high


def test_one_outlier_pair_does_not_resolve_a_pooled_gap():
    # The split's case: level on 19 pairs, one scene 100 points worse; the pooled gap is 5 points, but
    # a resample without that scene shows none, so the interval reaches 0.
    base = np.full(20, 100.0)
    other = base.copy()
    other[7] += 1000
    result = paired_difference(base, other, np.full(20, 1000.0))
    assert result.difference == pytest.approx(5.0)
    assert not result.resolved and result.low == 0.0


def test_the_pooled_difference_weighs_pairs_by_their_ground_truth_pixels():
    result = paired_difference([0, 0], [10, 0], [100, 900])
    assert result.difference == pytest.approx(1.0)  # 10 errors over 1000 pixels, not the mean of 10 % and 0 %


def test_a_fixed_seed_gives_the_same_interval():
    rng = np.random.default_rng(0)
    base, other = rng.uniform(0, 100, 30), rng.uniform(0, 100, 30)
    pixels = np.full(30, 500.0)
    assert paired_difference(base, other, pixels, seed=4) == paired_difference(base, other, pixels, seed=4)


@pytest.mark.parametrize(("base", "other", "pixels", "kwargs", "message"), [
    ([1, 2], [1], [5, 5], {}, "one length"),
    ([], [], [], {}, "one length"),
    ([1], [1], [0], {}, "ground-truth pixels"),
    ([1], [1], [5], {"level": 1.0}, "level"),
    ([1], [1], [5], {"resamples": 0}, "resamples"),
])
def test_bad_arguments_are_refused(base, other, pixels, kwargs, message):
    with pytest.raises(ValueError, match=message):
        paired_difference(base, other, pixels, **kwargs)


def test_reports_are_compared_pair_by_pair_and_must_hold_the_same_pairs():
    base, other = _report([10.0, 20.0, 30.0]), _report([11.0, 21.0, 31.0])
    names, errors, _ = pair_errors(base)
    assert names == ["pair-0", "pair-1", "pair-2"] and errors.tolist() == [100, 200, 300]
    assert compare_reports(base, other).difference == pytest.approx(1.0)
    with pytest.raises(ValueError, match="same pairs"):
        compare_reports(base, _report([1.0, 2.0, 3.0], names=["x", "y", "z"]))
    with pytest.raises(ValueError, match="same pairs"):
        compare_reports(base, _report([1.0, 2.0, 3.0], pixels=999))


def _full_report(percent: list[float], pixels: int = 1000) -> dict:
    report = _report(percent, pixels)
    for pair in report["per_pair"]:
        pair["all"]["epe"] = pair["all"]["bad2"] / 10
    mean = float(np.mean(percent))
    return report | {"all": {"bad2": mean, "epe": mean / 10, "pixels": pixels * len(percent)},
                     "seconds_per_pair": 0.5}


def test_pooling_seeds_sums_each_pairs_counts_so_the_bootstrap_still_resamples_scenes():
    rng = np.random.default_rng(5)
    control = [_full_report(list(rng.uniform(5, 30, 25))) for _ in range(2)]
    lever = [_full_report(list(np.array([p["all"]["bad2"] for p in c["per_pair"]]) - 1)) for c in control]
    base, other = pool_reports(control), pool_reports(lever)
    assert base["pooled"] == 2 and len(base["per_pair"]) == 25
    assert base["per_pair"][0]["all"]["pixels"] == 2000 and base["all"]["pixels"] == 50_000
    # One point lower on every pair of both seeds: the pooled difference is -1 with no spread.
    pooled = compare_reports(base, other)
    assert pooled.difference == pytest.approx(-1.0) and pooled.standard_error == pytest.approx(0, abs=1e-3)
    assert pooled.pairs == 25
    # The pooled rate is the mean of the seeds' rates, pair by pair and in total.
    expected = (control[0]["per_pair"][3]["all"]["bad2"] + control[1]["per_pair"][3]["all"]["bad2"]) / 2
    assert base["per_pair"][3]["all"]["bad2"] == pytest.approx(expected, abs=1e-4)
    assert base["all"]["bad2"] == pytest.approx((control[0]["all"]["bad2"] + control[1]["all"]["bad2"]) / 2,
                                                abs=1e-4)
    assert base["seconds_per_pair"] == 0.5


def test_pooling_refuses_reports_over_other_pairs_and_nothing():
    with pytest.raises(ValueError, match="same pairs"):
        pool_reports([_full_report([1.0, 2.0]), _full_report([1.0, 2.0], pixels=999)])
    with pytest.raises(ValueError, match="same pairs"):
        pool_reports([_full_report([1.0, 2.0]), _full_report([1.0, 2.0, 3.0])])
    with pytest.raises(ValueError, match="nothing"):
        pool_reports([])
