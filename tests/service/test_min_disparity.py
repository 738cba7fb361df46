"""Search range offset (issue 12, item 3): ``[min_disparity, min_disparity + D)`` through every stage."""

from __future__ import annotations

import numpy as np
import pytest

from service.cli import main
from service.cost import cost_volume
from service.disparity import left_right_winners
from service.filling import fill_border_band, fill_invalid
from service.limits import DisparityRangeError, SearchRange, search_range
from service.matcher import Matcher, MatchOptions, Validity
from service.validation import LR_CHECK_THRESHOLD, inner_check
from tests.helpers import slanted_plane_pair, unit_features


@pytest.fixture(scope="module")
def matcher() -> Matcher:
    return Matcher.from_folder(threads=2)


def naive_volume(left: np.ndarray, right: np.ndarray, first: int, count: int, scale: float) -> np.ndarray:
    """Cell k of pixel x: disparity first + k; +scale where x - d lies outside the right image."""
    _, height, width = left.shape
    volume = np.full((height, width, count), scale, np.float64)
    for x in range(width):
        for k in range(count):
            if 0 <= x - first - k < width:
                volume[:, x, k] = -scale * np.einsum("cy,cy->y", left[:, :, x], right[:, :, x - first - k])
    return volume


@pytest.mark.parametrize(("first", "count"), [(0, 6), (3, 5), (-4, 7), (-9, 4), (9, 3), (-2, 12)])
def test_cost_volume_with_an_offset_matches_naive(rng, first: int, count: int) -> None:
    left, right = unit_features(rng, 8, 3, 12), unit_features(rng, 8, 3, 12)
    volume = cost_volume(left, right, count, scale=128.0, min_disparity=first)
    assert volume.shape == (3, 12, count) and volume.dtype == np.int16
    assert np.abs(volume - naive_volume(left, right, first, count, 128.0)).max() <= 0.5 + 1e-3


def test_an_offset_volume_is_a_slice_of_the_plain_one(rng) -> None:
    left, right = unit_features(rng, 16, 4, 30), unit_features(rng, 16, 4, 30)
    plain = cost_volume(left, right, 20, scale=128.0)
    np.testing.assert_array_equal(cost_volume(left, right, 13, scale=128.0, min_disparity=7), plain[..., 7:])


def naive_right_winners(volume: np.ndarray, first: int) -> np.ndarray:
    """Right pixel x: argmin over k of the left cell (x + first + k, k) inside the image; 0 when none."""
    height, width, count = volume.shape
    right_costs = np.full((height, width, count), np.inf)
    for x in range(width):
        for k in range(count):
            if 0 <= x + first + k < width:
                right_costs[:, x, k] = volume[:, x + first + k, k]
    winners = right_costs.argmin(axis=2)
    winners[np.isinf(right_costs).all(axis=2)] = 0
    return winners


@pytest.mark.parametrize("first", [0, 3, -3, -8])
def test_right_winners_with_an_offset_match_numpy(rng, first: int) -> None:
    volume = rng.integers(0, 4, (5, 11, 6)).astype(np.int16)  # many ties: both keep the smallest k
    left, right = left_right_winners(volume, min_disparity=first)
    np.testing.assert_array_equal(left, volume.argmin(axis=2))
    np.testing.assert_array_equal(right, naive_right_winners(volume, first))


def naive_inner_check(left: np.ndarray, right: np.ndarray, first: int, count: int,
                      threshold: float = LR_CHECK_THRESHOLD) -> np.ndarray:
    height, width = left.shape
    validity = np.empty(left.shape, np.uint8)
    for y in range(height):
        for x in range(width):
            matched = x - int(np.floor(left[y, x] + 0.5))
            if 0 <= matched < width and abs(left[y, x] - right[y, matched]) <= threshold:
                validity[y, x] = Validity.VALID
                continue
            consistent = any(0 <= x - d < width and abs(d - right[y, x - d]) <= 1
                             for d in range(first, first + count))
            validity[y, x] = Validity.MISMATCH if consistent else Validity.OCCLUDED
    return validity


@pytest.mark.parametrize("threshold", [LR_CHECK_THRESHOLD, 0.0, 1.0, 2.5])
@pytest.mark.parametrize("first", [0, 4, -5])
def test_inner_check_with_an_offset_matches_numpy(rng, first: int, threshold: float) -> None:
    count = 6
    left = (first + rng.uniform(0, count - 1, (4, 15))).astype(np.float32)
    right = (first + rng.integers(0, count, (4, 15))).astype(np.int32)
    expected = naive_inner_check(left, right, first, count, threshold)
    np.testing.assert_array_equal(
        inner_check(left, right, count, min_disparity=first, threshold=threshold), expected)
    assert {Validity.VALID, Validity.OCCLUDED, Validity.MISMATCH} & set(np.unique(expected))


def test_filling_and_the_border_band_keep_negative_disparities() -> None:
    # Occlusion filling found a negative disparity as "no pixel" when -1 was its sentinel.
    disparity = np.array([[-3.0, np.nan, -2.0]], np.float32)
    validity = np.array([[Validity.VALID, Validity.OCCLUDED, Validity.VALID]], np.uint8)
    filled, codes = fill_invalid(disparity, validity)
    assert filled[0, 1] == -3.0 and codes[0, 1] == Validity.FILLED_OCCLUSION
    # A pixel whose negative disparity puts its match right of the right image (x - d >= W) takes the
    # surface it continues, mirrored from the left band.
    width = 8
    disparity = np.full((1, width), -2.0, np.float32)
    validity = np.zeros((1, width), np.uint8)
    validity[0, 6:] = Validity.MISMATCH
    banded, codes = fill_border_band(disparity, validity)
    assert codes[0, 6:].tolist() == [Validity.FILLED_OCCLUSION] * 2 and banded[0, 6:].tolist() == [-2.0, -2.0]
    assert codes[0, :6].tolist() == [Validity.VALID] * 6


def _shifted(shift: int) -> tuple[np.ndarray, ...]:
    """(left, right) of a slanted plane and the same scene with every disparity ``shift`` larger: the
    left image kept, the right one cropped ``shift`` columns further right."""
    left, right, truth, _ = slanted_plane_pair(height=48, width=200)
    plain = (np.ascontiguousarray(left[:, :-shift]), np.ascontiguousarray(right[:, :-shift]))
    shifted = (np.ascontiguousarray(left[:, :-shift]), np.ascontiguousarray(right[:, shift:]))
    return plain, shifted, truth[:, :-shift]


def test_a_shifted_pair_searched_from_the_shift_gives_the_plain_result_plus_the_shift(matcher) -> None:
    shift = 8
    plain, shifted, _ = _shifted(shift)
    inner = slice(40, -20)  # away from the towers' padding at the cropped borders
    # Without SGM every stage is per pixel: equal to float rounding (offset added to the winners).
    bare = {"max_disparity": 32, "sgm": False, "fill": False, "border": False}
    a = matcher(*plain, MatchOptions(**bare))
    b = matcher(*shifted, MatchOptions(**bare, min_disparity=shift))
    np.testing.assert_array_equal(a.validity[:, inner], b.validity[:, inner])
    np.testing.assert_allclose(b.disparity[:, inner] - shift, a.disparity[:, inner], atol=1e-5)
    # SGM paths start at the image borders, whose costs differ, so agreement is near, not exact.
    a = matcher(*plain, MatchOptions(max_disparity=32))
    b = matcher(*shifted, MatchOptions(max_disparity=32, min_disparity=shift))
    difference = np.abs(b.disparity[:, inner] - shift - a.disparity[:, inner])
    assert np.mean(difference < 0.05) > 0.98 and np.nanmax(difference) < 0.5


def test_matcher_against_a_numpy_reference(matcher) -> None:
    _, shifted, _ = _shifted(6)
    features = matcher.towers(*shifted)
    scale = float(matcher.manifest["cost"]["scale"])
    expected = 6 + np.rint(naive_volume(*features, 6, 24, scale)).argmin(axis=2)
    options = MatchOptions(max_disparity=24, min_disparity=6, sgm=False, subpixel=False, lr_check=False,
                           fill=False, border=False, weighted_median=False, shiftable_windows=False)
    np.testing.assert_array_equal(matcher(*shifted, options).disparity, expected)


def test_a_negative_range_finds_negative_disparities(matcher) -> None:
    # The left crop moved right by 12 columns: every true disparity (6..~17 px) drops by 12.
    left, right, truth, _ = slanted_plane_pair(height=48, width=200)
    left, truth = np.ascontiguousarray(left[:, 12:]), truth[:, 12:] - 12
    right = np.ascontiguousarray(right[:, :-12])
    result = matcher(left, right, MatchOptions(max_disparity=24, min_disparity=-12))
    assert np.nanmin(result.disparity) < -3 and np.nanmax(result.disparity) <= 11.5
    assert np.mean(np.abs(result.disparity - truth) <= 1.0) > 0.95


def test_the_range_rule() -> None:
    assert search_range(100, default_max=128) == SearchRange(0, 100)
    assert search_range(100, min_disparity=30, default_max=128) == SearchRange(30, 70)
    assert search_range(100, min_disparity=-30, max_disparity=130, default_max=64).maximum == 99
    with pytest.raises(DisparityRangeError, match="exceeds the image width 100: at most 70 disparities from "
                       "min_disparity 30"):
        search_range(100, min_disparity=30, max_disparity=71, default_max=64)
    for bad in (100, -100):
        with pytest.raises(DisparityRangeError, match="min_disparity"):
            search_range(100, min_disparity=bad, default_max=64)
    with pytest.raises(ValueError, match="min_disparity must be an integer"):
        MatchOptions(min_disparity=1.5)


def test_cli_min_disparity(capsys, tmp_path, matcher) -> None:
    from PIL import Image

    _, (left, right), _ = _shifted(8)
    Image.fromarray(left).save(tmp_path / "l.png")
    Image.fromarray(right).save(tmp_path / "r.png")
    out = tmp_path / "d.npy"
    code = main(["predict", str(tmp_path / "l.png"), str(tmp_path / "r.png"), "-o", str(out),
                 "--max-disparity", "32", "--min-disparity", "8", "--no-check"])
    assert code == 0, capsys.readouterr().err
    expected = matcher(left, right, MatchOptions(max_disparity=32, min_disparity=8)).disparity
    np.testing.assert_array_equal(np.load(out), expected)
    code = main(["predict", str(tmp_path / "l.png"), str(tmp_path / "r.png"), "-o", str(out),
                 "--max-disparity", "190", "--min-disparity", "8"])
    err = capsys.readouterr().err
    assert code == 1 and err.startswith("adsm: error: max_disparity 190 exceeds the image width 192"), err
