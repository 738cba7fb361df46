"""Confidence (issue 12, item 4): the peak-ratio kernel, the matcher option, the sparsification curve and
the CLI."""

from __future__ import annotations

import itertools
import json

import numpy as np
import pytest
from PIL import Image

from service.cli import main
from service.evaluation.sparsification import FRACTIONS, Sparsification
from service.matcher import Matcher, MatchOptions, Validity
from service.validation.confidence import REJECTED_WEIGHT, cost_confidence, weigh_by_check
from tests.helpers import CONES, require, slanted_plane_pair


@pytest.fixture(scope="module")
def matcher() -> Matcher:
    return Matcher.from_folder(threads=2)


def naive_confidence(volume: np.ndarray, winners: np.ndarray, lowest: int) -> np.ndarray:
    height, width, count = volume.shape
    expected = np.empty((height, width), np.float64)
    for y in range(height):
        for x in range(width):
            winner = winners[y, x]
            rivals = [int(volume[y, x, d]) for d in range(count) if abs(d - winner) >= 2]
            if not rivals:
                expected[y, x] = 1.0
                continue
            best, rival = int(volume[y, x, winner]), min(rivals)
            expected[y, x] = np.clip((rival - best) / max(rival - lowest, 1), 0.0, 1.0)
    return expected


@pytest.mark.parametrize("count", [1, 2, 3, 4, 9, 40])
def test_peak_ratio_matches_numpy(rng, count: int) -> None:
    volume = rng.integers(-512, 600, (5, 7, count)).astype(np.int16)
    winners = volume.argmin(axis=2).astype(np.int32)
    confidence = cost_confidence(volume, winners, lowest=-512)
    assert confidence.dtype == np.float32 and confidence.shape == (5, 7)
    np.testing.assert_allclose(confidence, naive_confidence(volume, winners, -512), atol=1e-6)
    assert confidence.min() >= 0 and confidence.max() <= 1


def test_the_rival_is_non_adjacent_and_a_clear_winner_is_confident() -> None:
    # Cells 1 and 3 are the winner's own valley; the rival is cell 5 (cost 0) or, far, cell 0 (100).
    valley = np.array([[[100, -300, -400, -350, 100, 0]]], np.int16)
    winners = np.array([[2]], np.int32)
    assert cost_confidence(valley, winners, lowest=-512)[0, 0] == pytest.approx(400 / 512)
    flat = np.full((1, 1, 6), -100, np.int16)
    assert cost_confidence(flat, np.array([[0]], np.int32), lowest=-512)[0, 0] == 0.0
    with pytest.raises(ValueError, match="winners"):
        cost_confidence(flat, np.array([[6]], np.int32), lowest=-512)


def test_rejected_pixels_rank_below_and_missing_ones_get_zero() -> None:
    confidence = np.array([[0.9, 0.8, 0.7, 0.6]], np.float32)
    validity = np.array([[Validity.VALID, Validity.FILLED_OCCLUSION, Validity.MISMATCH, Validity.NO_DATA]],
                        np.uint8)
    disparity = np.array([[3.0, 4.0, np.nan, np.nan]], np.float32)
    weighed = weigh_by_check(confidence, validity, disparity)
    np.testing.assert_allclose(weighed, [[0.9, 0.8 * REJECTED_WEIGHT, 0.0, 0.0]], rtol=1e-6)


def test_only_computed_when_asked_and_changes_nothing_else(matcher) -> None:
    left, right, _, _ = slanted_plane_pair(height=48, width=120)
    plain = matcher(left, right, MatchOptions(max_disparity=32))
    assert plain.confidence is None and "confidence" not in plain.timings
    asked = matcher(left, right, MatchOptions(max_disparity=32, confidence=True))
    np.testing.assert_array_equal(asked.disparity, plain.disparity)
    np.testing.assert_array_equal(asked.validity, plain.validity)
    confidence = asked.confidence
    assert confidence.dtype == np.float32 and confidence.shape == left.shape[:2]
    assert "confidence" in asked.timings
    assert confidence.min() >= 0 and confidence.max() <= 1
    rejected = asked.validity != Validity.VALID
    assert rejected.any() and np.all(confidence[rejected] <= REJECTED_WEIGHT)
    assert np.median(confidence[asked.validity == Validity.VALID]) > 0.05
    # Without SGM the raw volume's own floor (-scale) is used: still within [0, 1].
    raw = matcher(left, right, MatchOptions(max_disparity=32, sgm=False, confidence=True)).confidence
    assert raw.min() >= 0 and raw.max() <= 1 and not np.array_equal(raw, confidence)
    with pytest.raises(ValueError, match="confidence"):
        MatchOptions(confidence="yes")


def exact_curve(disparity, truth, confidence) -> list[float]:
    counted = np.isfinite(truth)
    bad = ~(np.abs(disparity - truth)[counted] <= 2)
    order = np.argsort(-confidence[counted], kind="stable")
    cumulative = np.cumsum(bad[order])
    return [100 * cumulative[round(f / 100 * bad.size) - 1] / round(f / 100 * bad.size) for f in FRACTIONS]


def test_sparsification_counts(rng) -> None:
    truth = rng.uniform(0, 50, (60, 80))
    truth[0, :10] = np.nan  # no ground truth: not counted
    error = rng.exponential(2.0, truth.shape)
    confidence = np.exp(-error / 3)  # ranks the pixels by their error: a falling curve, no ties
    disparity = truth + error
    disparity[5, :5] = np.nan  # missing predictions count as errors
    curve = Sparsification().add(disparity, truth, confidence).curve()
    np.testing.assert_allclose(curve, exact_curve(disparity, truth, confidence), atol=0.3)
    assert curve[-1] == pytest.approx(100 * np.mean(~(np.abs(disparity - truth)[np.isfinite(truth)] <= 2)))
    # All tied: every fraction has the all-pixel error (the expected value of a random order).
    tied = Sparsification().add(disparity, truth, np.zeros_like(truth)).curve()
    np.testing.assert_allclose(tied, curve[-1], atol=1e-9)
    both = Sparsification().add(disparity, truth, confidence)
    both += Sparsification().add(disparity, truth, confidence)
    np.testing.assert_allclose(both.curve(), curve, atol=1e-9)


@pytest.mark.slow
def test_on_cones_the_curve_is_monotone_and_the_confident_half_is_far_better(capsys) -> None:
    require((CONES / "left.png").is_file(), f"the Cones pair in {CONES}")
    code = main(["eval", "--data", f"cones:{CONES}", "--max-disparity", "64", "--confidence", "--json", "-"])
    assert code == 0
    curve = json.loads(capsys.readouterr().out)["sparsification"]["bad"]
    assert all(later >= earlier - 0.1 for earlier, later in itertools.pairwise(curve)), curve
    half, every = curve[FRACTIONS.index(50)], curve[-1]
    assert half < every / 5, curve  # measured: 0.27 % against 8.32 %


def test_cli_writes_the_confidence_map(capsys, tmp_path, matcher) -> None:
    left, right, _, _ = slanted_plane_pair(height=40, width=96)
    Image.fromarray(left).save(tmp_path / "l.png")
    Image.fromarray(right).save(tmp_path / "r.png")
    common = [str(tmp_path / "l.png"), str(tmp_path / "r.png"), "-o", str(tmp_path / "d.npy"),
              "--max-disparity", "32", "--no-check"]
    assert main(["predict", *common, "--confidence", str(tmp_path / "c.npy")]) == 0
    assert main(["predict", *common, "--confidence", str(tmp_path / "c.png")]) == 0
    expected = matcher(left, right, MatchOptions(max_disparity=32, confidence=True)).confidence
    stored = np.load(tmp_path / "c.npy")
    assert stored.dtype == np.float32
    np.testing.assert_array_equal(stored, expected)
    levels = np.asarray(Image.open(tmp_path / "c.png"))
    assert levels.dtype == np.uint8 and np.abs(levels / 255.0 - expected).max() <= 0.5 / 255 + 1e-6
    capsys.readouterr()
    assert main(["predict", *common, "--confidence", str(tmp_path / "c.tif")]) == 1
    assert capsys.readouterr().err.startswith("adsm: error: --confidence must name a .png or .npy file")
