"""The right view's cost volume re-indexed from the left one, against a NumPy loop and the inner check."""

from __future__ import annotations

import numpy as np
import pytest

from service.cost import right_view_volume
from service.disparity import left_right_winners, winner_takes_all

SCALE = 128.0


def naive_right_view(volume: np.ndarray, min_disparity: int, scale: float) -> np.ndarray:
    height, width, disparities = volume.shape
    right = np.empty_like(volume)
    for y in range(height):
        for x in range(width):
            for k in range(disparities):
                match = x + min_disparity + k
                right[y, x, k] = volume[y, match, k] if 0 <= match < width else np.int16(scale)
    return right


def random_volume(rng: np.random.Generator, shape: tuple[int, int, int]) -> np.ndarray:
    return rng.integers(-SCALE, SCALE, size=shape).astype(np.int16)  # below +scale: no cell ties the outside


@pytest.mark.parametrize("min_disparity", [-5, -1, 0, 3])
@pytest.mark.parametrize("shape", [(3, 17, 6), (1, 4, 9), (2, 1, 1), (4, 30, 12)])
def test_matches_a_numpy_loop_in_place_or_not(rng, shape: tuple[int, int, int], min_disparity: int) -> None:
    volume = random_volume(rng, shape)
    expected = naive_right_view(volume, min_disparity, SCALE)
    right = right_view_volume(volume, scale=SCALE, min_disparity=min_disparity)
    assert right.dtype == np.int16 and right.flags.c_contiguous
    np.testing.assert_array_equal(right, expected)
    in_place = volume.copy()
    assert right_view_volume(in_place, scale=SCALE, min_disparity=min_disparity, out=in_place) is in_place
    np.testing.assert_array_equal(in_place, expected)


@pytest.mark.parametrize("min_disparity", [-4, 0, 2])
def test_its_winners_are_the_inner_checks_right_winners(rng, min_disparity: int) -> None:
    # Without SGM both frames hold the same costs, so the right view's own winner-takes-all equals the
    # right winners the inner check reads off the left volume (ties to the smaller disparity in both).
    volume = random_volume(rng, (6, 40, 10))
    _, right_winners = left_right_winners(volume, min_disparity=min_disparity)
    own = winner_takes_all(right_view_volume(volume, scale=SCALE, min_disparity=min_disparity))
    # Right pixels whose every cell lies outside the left view: 0 in the check, a tie of +scale here (0 too).
    np.testing.assert_array_equal(own, right_winners)


@pytest.mark.parametrize(
    ("volume", "settings", "message"),
    [
        (np.zeros((2, 3), np.int16), {}, "non-empty"),
        (np.zeros((2, 0, 3), np.int16), {}, "non-empty"),
        (np.zeros((2, 3, 4), np.float32), {}, "int16"),
        (np.zeros((2, 3, 4), np.int16), {"min_disparity": True}, "min_disparity"),
        (np.zeros((2, 3, 4), np.int16), {"min_disparity": 1.5}, "min_disparity"),
        (np.zeros((2, 3, 4), np.int16), {"scale": 0.0}, "cost scale"),
        (np.zeros((2, 3, 4), np.int16), {"scale": float("nan")}, "cost scale"),
        (np.zeros((2, 3, 4), np.int16), {"out": np.zeros((2, 3, 5), np.int16)}, "out must be"),
        (np.zeros((2, 3, 4), np.int16), {"out": np.zeros((2, 3, 4), np.int32)}, "out must be"),
    ],
)
def test_rejects_bad_arguments(volume: np.ndarray, settings: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        right_view_volume(volume, **{"scale": SCALE, **settings})
