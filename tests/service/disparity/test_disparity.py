"""Winner-takes-all, sub-pixel fit, inner left-right check and ray filling on hand-made cases."""

from __future__ import annotations

import numpy as np
import pytest

from service.disparity import left_right_winners, winner_takes_all
from service.filling import MC_CNN_FRACTION, fill_invalid
from service.refinement import refine_subpixel
from service.validation import Validity, inner_check


def naive_right_winners(volume: np.ndarray) -> np.ndarray:
    height, width, disparities = volume.shape
    right_costs = np.full((height, width, disparities), np.inf)
    for x in range(width):
        for d in range(min(disparities, width - x)):
            right_costs[:, x, d] = volume[:, x + d, d]
    return right_costs.argmin(axis=2)


@pytest.mark.parametrize("shape", [(6, 17, 5), (3, 4, 9), (1, 1, 1), (2, 9, 1)])
def test_winners_match_numpy(rng, shape: tuple[int, int, int]) -> None:
    # Integer costs make ties frequent: both must keep the smallest disparity, as argmin does.
    volume = rng.integers(0, 4, shape).astype(np.int16)
    left, right = left_right_winners(volume)
    np.testing.assert_array_equal(left, volume.argmin(axis=2))
    np.testing.assert_array_equal(winner_takes_all(volume), volume.argmin(axis=2))
    np.testing.assert_array_equal(right, naive_right_winners(volume))


def test_subpixel_recovers_a_parabola_minimum(rng) -> None:
    height, width, disparities = 4, 6, 12
    minimum = rng.uniform(1.0, disparities - 2.0, (height, width)).astype(np.float32)
    d = np.arange(disparities, dtype=np.float32)
    # Steep enough that rounding to int16 cost units moves the vertex by < 0.005 px.
    volume = np.rint(200.0 * (d - minimum[..., None]) ** 2 - 5000.0).astype(np.int16)
    refined = refine_subpixel(volume, winner_takes_all(volume))
    np.testing.assert_allclose(refined, minimum, atol=5e-3)


def test_subpixel_keeps_integers_without_both_neighbours_or_curvature() -> None:
    volume = np.array([[[0, 1, 2], [2, 1, 0], [1, 1, 1], [5, 0, 0]]], np.int16)
    winners = np.array([[0, 2, 1, 1]], np.int32)
    # Last pixel: a tie between 1 and 2 puts the vertex half-way.
    np.testing.assert_array_equal(refine_subpixel(volume, winners), [[0.0, 2.0, 1.0, 1.5]])


def test_subpixel_offset_is_clamped_to_half_a_pixel() -> None:
    # A winner that is not the minimum (cost rising to the left) would move by more than 0.5.
    volume = np.array([[[0, 1, 10]]], np.int16)
    assert refine_subpixel(volume, np.array([[1]], np.int32))[0, 0] == pytest.approx(0.5)


def test_consistent_maps_are_valid() -> None:
    left = np.full((3, 10), 2.0, np.float32)
    right = np.full((3, 10), 2, np.int32)
    validity = inner_check(left, right, 5)
    # The first two columns would match left of the right image. Column 0: no disparity is consistent
    # (occluded); column 1: d = 1 is within 1 px of DR(0) = 2 (a mismatch by MC-CNN's rule).
    assert np.all(validity[:, 2:] == Validity.VALID)
    assert np.all(validity[:, 0] == Validity.OCCLUDED) and np.all(validity[:, 1] == Validity.MISMATCH)


def _foreground_scene() -> tuple[np.ndarray, np.ndarray]:
    """Background at disparity 2, a foreground object at disparity 6 on columns 20..29, all rows.

    The object hides right-view columns 14..23, so background pixels 16..19 of the left view are
    occluded; their (wrong) WTA disparity is 9.
    """
    left = np.full((5, 40), 2.0, np.float32)
    left[:, 20:30] = 6.0
    left[:, 16:20] = 9.0
    right = np.full((5, 40), 2, np.int32)
    right[:, 14:24] = 6
    return left, right


def test_occluded_strip_left_of_a_foreground_object_is_filled_from_the_background() -> None:
    left, right = _foreground_scene()
    validity = inner_check(left, right, 12)
    strip = validity[:, 16:20]
    assert np.all(strip != Validity.VALID)
    # Deep inside the strip no disparity is consistent: occlusion. At its ends a disparity 1 px off is
    # (MC-CNN's tolerance), so those pixels are classed as mismatches.
    assert np.all(strip[:, 1:3] == Validity.OCCLUDED)
    assert np.all(validity[:, 20:] == Validity.VALID) and np.all(validity[:, 2:16] == Validity.VALID)

    filled, filled_validity = fill_invalid(left, validity)
    assert np.all(filled_validity[:, 17:19] == Validity.FILLED_OCCLUSION)
    np.testing.assert_array_equal(filled[:, 17:19], 2.0)  # the background, not the foreground's 6
    valid = validity == Validity.VALID
    np.testing.assert_array_equal(filled[valid], left[valid])
    np.testing.assert_array_equal(filled_validity[valid], Validity.VALID)


def test_occlusion_takes_the_left_ray_even_when_other_rays_see_smaller_values() -> None:
    # Background 5 to the left, foreground 9 to the right, an outlier 1 above: MC-CNN's left ray wins.
    disparity = np.array([[5, 5, 1, 9], [5, 5, 0, 9], [5, 5, 9, 9]], np.float32)
    validity = np.full(disparity.shape, Validity.VALID, np.uint8)
    validity[1, 2] = Validity.OCCLUDED
    filled, filled_validity = fill_invalid(disparity, validity)
    assert filled[1, 2] == 5.0 and filled_validity[1, 2] == Validity.FILLED_OCCLUSION


def test_occlusion_at_the_left_border_takes_the_right_ray() -> None:
    disparity = np.array([[0, 0, 7, 3], [4, 4, 4, 4]], np.float32)
    validity = np.full(disparity.shape, Validity.VALID, np.uint8)
    validity[0, :2] = Validity.OCCLUDED  # the band the right camera never sees
    filled, filled_validity = fill_invalid(disparity, validity)
    np.testing.assert_array_equal(filled[0], [7, 7, 7, 3])
    assert np.all(filled_validity[0, :2] == Validity.FILLED_OCCLUSION)


def test_lone_mismatch_is_filled_from_its_neighbours() -> None:
    left = np.full((9, 30), 7.0, np.float32)
    left[4, 15] = 15.0
    right = np.full((9, 30), 7, np.int32)
    validity = inner_check(left, right, 20)
    assert validity[4, 15] == Validity.MISMATCH
    assert np.count_nonzero(validity[:, 7:] != Validity.VALID) == 1
    filled, filled_validity = fill_invalid(left, validity)
    assert filled[4, 15] == 7.0 and filled_validity[4, 15] == Validity.FILLED_MISMATCH


def test_mismatch_takes_the_median_of_the_rays() -> None:
    # A plane rising with y: the horizontal rays see the centre's own value, other rays pair up around it.
    y = np.arange(11, dtype=np.float32)[:, None]
    disparity = np.broadcast_to(20.0 + 0.5 * y, (11, 11)).copy()
    validity = np.zeros((11, 11), np.uint8)
    validity[5, 5] = Validity.MISMATCH
    disparity[5, 5] = 99.0
    filled, _ = fill_invalid(disparity, validity, mismatch_fraction=MC_CNN_FRACTION)  # MC-CNN's median
    assert filled[5, 5] == 22.5


def test_unfillable_pixels_are_nan_no_data() -> None:
    disparity = np.ones((3, 4), np.float32)
    validity = np.full((3, 4), Validity.MISMATCH, np.uint8)
    validity[0, 0] = Validity.OCCLUDED
    filled, filled_validity = fill_invalid(disparity, validity)
    assert np.all(np.isnan(filled)) and np.all(filled_validity == Validity.NO_DATA)
    # One valid pixel a knight's move from (0, 0): the half-slope ray (1, 0.5) reaches it via (1, 1).
    validity[:] = Validity.MISMATCH
    validity[1, 2] = Validity.VALID
    filled, filled_validity = fill_invalid(disparity, validity)
    assert filled_validity[1, 2] == Validity.VALID
    assert filled_validity[0, 0] == Validity.FILLED_MISMATCH


def test_rejects_mismatched_shapes() -> None:
    with pytest.raises(ValueError):
        inner_check(np.zeros((2, 3), np.float32), np.zeros((2, 4), np.int32), 3)
    with pytest.raises(ValueError):
        fill_invalid(np.zeros((2, 3), np.float32), np.zeros((3, 2), np.uint8))
    with pytest.raises(ValueError):
        refine_subpixel(np.zeros((2, 3, 4), np.int16), np.zeros((2, 3), np.int32) + 4)
    with pytest.raises(ValueError, match="int16"):
        refine_subpixel(np.zeros((2, 3, 4), np.float32), np.zeros((2, 3), np.int32))
    with pytest.raises(ValueError):
        winner_takes_all(np.zeros((2, 3), np.int16))
    with pytest.raises(ValueError, match="int16"):
        left_right_winners(np.zeros((2, 3, 4), np.float32))
