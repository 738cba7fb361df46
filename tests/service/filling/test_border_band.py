"""The left border band step (service.filling.border) and its switch in the Matcher."""

from __future__ import annotations

import numpy as np
import pytest

from service.evaluation.breakdown import Breakdown
from service.filling import fill_border_band
from service.matcher import Matcher, MatchOptions
from service.validation.codes import Validity
from training.data.synthetic import SyntheticConfig, generate


def test_band_takes_the_disparity_of_the_surface_it_continues():
    disparity = np.array([[1.0, 2.0, 1.0, 6.0, 6.0, 6.0, 6.0, 2.0]], np.float32)
    validity = np.zeros(disparity.shape, np.uint8)
    validity[0, 3] = Validity.MISMATCH            # rejected pixels are never a reference
    disparity[0, 3] = 30.0
    filled, codes = fill_border_band(disparity, validity)
    # Walking left: x=7 passes the check (reference 2), x=6 (6 >= 2, reference 6), then every x < 6.
    assert filled[0].tolist() == [6.0, 6.0, 6.0, 6.0, 6.0, 6.0, 6.0, 2.0]
    assert codes[0].tolist() == [5, 5, 5, 5, 5, 5, 0, 0]
    assert disparity[0, 3] == 30.0 and validity[0, 3] == Validity.MISMATCH    # inputs untouched


def test_rows_without_a_reference_stay_and_missing_pixels_in_the_band_are_filled():
    disparity = np.array([[np.nan, 0.2, 1.0], [np.nan, np.nan, np.nan]], np.float32)
    validity = np.array([[Validity.NO_DATA, 0, 0], [3, 3, 3]], np.uint8)
    filled, codes = fill_border_band(disparity, validity)
    assert filled[0].tolist() == pytest.approx([0.2, 0.2, 1.0])          # x=0 < 0.2: in the band
    assert codes[0].tolist() == [Validity.FILLED_OCCLUSION, 0, 0]
    assert np.isnan(filled[1]).all() and (codes[1] == Validity.NO_DATA).all()


def test_shapes_are_checked():
    with pytest.raises(ValueError, match="same shape"):
        fill_border_band(np.zeros((2, 3), np.float32), np.zeros((3, 2), np.uint8))


@pytest.mark.torch
def test_the_band_step_cuts_the_border_error_of_a_synthetic_pair():
    # With the check's right winners read off the left-aggregated volume, which accepts many wrong strip
    # pixels (57.5 -> 23.4 % here). The right view's own SGM pass (the default) rejects most of them
    # itself, and then the band changes the strip's bad-2 by about a point either way on such pairs
    # (docs/training.md, "The right view aggregated in its own frame").
    pair = generate(11, SyntheticConfig(height=96, width=192, max_disparity=40))
    matcher = Matcher.from_folder("service/models/ncc-baseline", threads=1)
    border = {}
    for enabled in (False, True):
        options = MatchOptions(max_disparity=48, border=enabled, right_sgm=False)
        result = matcher(pair.left, pair.right, options)
        summary = Breakdown().add(result.disparity, pair.disparity, result.validity).summary()
        border[enabled] = summary["regions"]["border"]["bad2"]
        assert ("border" in result.timings) == enabled
    assert border[True] < border[False] - 10.0


def test_the_band_ends_at_a_farther_surface_matched_inside_the_right_image():
    # Walking left from a near surface (disparity 9 at x = 9..14): x = 8 is in its band (8 < 9) and starts a
    # run of accepted pixels at 3 (within the tolerance: 3.4, 2.6) that reaches x = 3, a farther surface
    # matched inside the right image, so the band now continues 3 and only x < 3 gets it.
    disparity = np.array([[0.0, 1.0, 2.0, 3.0, 3.0, 3.4, 2.6, 3.0, 3.0, 9.0, 9.0, 9.0, 9.0, 9.0, 9.0]],
                         np.float32)
    validity = np.zeros(disparity.shape, np.uint8)
    filled, codes = fill_border_band(disparity, validity, surface_run=6)
    assert filled[0].tolist() == pytest.approx([3, 3, 3, 3, 3, 3.4, 2.6, 3, 3, 9, 9, 9, 9, 9, 9])
    assert codes[0].tolist() == [5, 5, 5] + [0] * 12
    # surface_run 0: the band of the near surface reaches the border, as MC-CNN's constant rule.
    filled, codes = fill_border_band(disparity, validity, surface_run=0)
    assert filled[0].tolist() == [9.0] * 15 and codes[0].tolist() == [5] * 9 + [0] * 6


@pytest.mark.parametrize(("code", "value", "why"), [
    (Validity.MISMATCH, 3.0, "a rejected pixel breaks the run"),
    (Validity.VALID, 4.5, "a disparity off by more than the tolerance breaks the run"),
])
def test_a_short_or_broken_run_inside_the_band_is_overwritten(code, value, why):
    disparity = np.array([[3.0] * 9 + [9.0] * 6], np.float32)
    validity = np.zeros(disparity.shape, np.uint8)
    validity[0, 3], disparity[0, 3] = code, value
    filled, _ = fill_border_band(disparity, validity, surface_run=6)
    # The band starts at x = 8; the longest run in it (x = 8 .. 4) holds 5 pixels: x = 3 breaks it.
    assert filled[0].tolist() == [9.0] * 15, why
    # At surface_run 5 that run ends the band, and x = 3 lies outside the new one (3 >= 3): kept.
    filled, _ = fill_border_band(disparity, validity, surface_run=5)
    assert filled[0, 4:9].tolist() == [3.0] * 5 and filled[0, 3] == value


def test_a_run_whose_match_lies_left_of_the_right_image_is_no_surface():
    # Accepted pixels at 8 from x = 7 down to 2 hold a run of 6, but x = 7 < 8: the right camera never saw
    # them, they cannot end a band (a check of the function's own input: the inner check keeps no such pixel).
    disparity = np.array([[8.0] * 8 + [12.0] * 4], np.float32)
    filled, _ = fill_border_band(disparity, np.zeros(disparity.shape, np.uint8), surface_run=6)
    assert filled[0].tolist() == [12.0] * 12


def test_the_right_band_ends_at_a_surface_as_the_left_one_mirrored():
    # Negative disparities: the band lies along the right border (x - d >= W = 15), the first test mirrored.
    disparity = -np.array([[9.0] * 6 + [3.0, 3.0, 2.6, 3.4, 3.0, 3.0, 2.0, 1.0, 0.0]], np.float32)
    validity = np.zeros(disparity.shape, np.uint8)
    filled, codes = fill_border_band(disparity, validity, surface_run=6)
    assert filled[0].tolist() == pytest.approx([-9] * 6 + [-3, -3, -2.6, -3.4, -3, -3] + [-3] * 3)
    assert codes[0].tolist() == [0] * 12 + [5, 5, 5]
    filled, codes = fill_border_band(disparity, validity, surface_run=0)
    assert filled[0].tolist() == [-9.0] * 15 and codes[0].tolist() == [0] * 6 + [5] * 9


@pytest.mark.parametrize("run", [-1, 2.5, True, "6"])
def test_surface_run_is_checked(run):
    with pytest.raises(ValueError, match="surface_run"):
        fill_border_band(np.zeros((2, 3), np.float32), np.zeros((2, 3), np.uint8), surface_run=run)


def _near_object_at_the_border(width: int = 128, height: int = 40, seed: int = 3) -> tuple[np.ndarray, ...]:
    """A background at disparity 6 and a near object at 36 over x = 50..89 of the left view. The right view
    sees the background at x - 6 except where the object, at x - 36 (14..53), hides it: left x = 20..49
    is occluded, x = 6..19 is background both cameras saw, and it lies inside the object's band (x < 36)."""
    rng = np.random.default_rng(seed)

    def texture() -> np.ndarray:
        noise = rng.uniform(0, 255, (height, width + 2, 3))
        return (noise[:, :-2] + noise[:, 1:-1] + noise[:, 2:]) / 3.0

    background, near = texture(), texture()
    right = background.copy()
    right[:, 14:54] = near[:, 14:54]
    left = np.empty_like(right)
    left[:, 6:] = background[:, :-6]
    left[:, :6] = texture()[:, :6]
    left[:, 50:90] = near[:, 14:54]
    return left.round().astype(np.uint8), right.round().astype(np.uint8)


def test_the_matcher_keeps_the_background_the_right_camera_saw_beside_a_near_object():
    left, right = _near_object_at_the_border()
    matcher = Matcher.from_folder("service/models/ncc-baseline", threads=1)
    kept = matcher(left, right, MatchOptions(max_disparity=48)).disparity[:, 8:18]
    carried = matcher(left, right, MatchOptions(max_disparity=48, border_surface_run=0)).disparity[:, 8:18]
    assert np.mean(np.abs(kept - 6.0) < 1.0) > 0.9          # the background's own disparity
    assert np.mean(np.abs(carried - 36.0) < 1.0) > 0.9      # the near object's band carried over it
