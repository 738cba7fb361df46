"""Cost volume against a naive NumPy computation, including out-of-range cells."""

from __future__ import annotations

import numpy as np
import pytest

from service.cost import cost_volume
from tests.helpers import unit_features


def naive_cost_volume(left: np.ndarray, right: np.ndarray, disparities: int, scale: float) -> np.ndarray:
    _, height, width = left.shape
    volume = np.empty((height, width, disparities), np.float64)
    for y in range(height):
        for x in range(width):
            for d in range(disparities):
                inside = x - d >= 0
                volume[y, x, d] = -scale * float(left[:, y, x] @ right[:, y, x - d]) if inside else scale
    return volume


@pytest.mark.parametrize(
    ("channels", "height", "width", "disparities"),
    # 57 and 49 are not multiples of the kernel's LANES: the zero-padded channels must add nothing.
    [(8, 5, 12, 4), (64, 3, 20, 7), (3, 1, 1, 1), (5, 2, 3, 6), (1, 4, 9, 9), (57, 3, 21, 9), (49, 2, 17, 5)],
)
def test_matches_naive(rng, channels: int, height: int, width: int, disparities: int) -> None:
    left = unit_features(rng, channels, height, width)
    right = unit_features(rng, channels, height, width)
    volume = cost_volume(left, right, disparities, scale=128.0)
    assert volume.shape == (height, width, disparities) and volume.dtype == np.int16
    assert volume.flags.c_contiguous
    expected = naive_cost_volume(left, right, disparities, 128.0)
    # Rounded to whole cost units; float32 sums may land on the other side of a .5 only.
    assert np.abs(volume - expected).max() <= 0.5 + 1e-3
    assert np.mean(volume == np.rint(expected)) > 0.99


def test_out_of_range_cells_hold_the_maximum_cost(rng) -> None:
    left = unit_features(rng, 4, 2, 6)
    volume = cost_volume(left, left, 10, scale=64.0)
    x, d = np.meshgrid(np.arange(6), np.arange(10), indexing="ij")
    assert np.all(volume[:, x < d] == 64)
    assert np.all(volume <= 64) and np.all(volume >= -64)
    # Identical features: a perfect match at d = 0 costs -scale.
    np.testing.assert_array_equal(volume[:, :, 0], -64)


def test_features_that_are_not_unit_norm_are_clipped_to_the_scale(rng) -> None:
    left = 100.0 * unit_features(rng, 4, 2, 6)
    volume = cost_volume(left, left, 3, scale=1024.0)
    assert volume.dtype == np.int16 and volume.min() == -1024 and volume.max() <= 1024


def test_shifted_features_have_their_minimum_at_the_shift(rng) -> None:
    right = unit_features(rng, 16, 3, 30)
    left = np.zeros_like(right)
    left[:, :, 5:] = right[:, :, :-5]
    left[:, :, :5] = right[:, :, :5]
    volume = cost_volume(left, right, 8, scale=128.0)
    assert np.all(volume[:, 5:].argmin(axis=2) == 5)


def test_accepts_non_contiguous_float64_features(rng) -> None:
    left = unit_features(rng, 6, 4, 7)
    right = unit_features(rng, 6, 4, 7)
    expected = cost_volume(left, right, 3, scale=128.0)
    strided = np.asfortranarray(left.astype(np.float64))
    np.testing.assert_array_equal(cost_volume(strided, right, 3, scale=128.0), expected)


def test_rejects_bad_arguments(rng) -> None:
    features = unit_features(rng, 2, 3, 4)
    with pytest.raises(ValueError, match="one shape"):
        cost_volume(features, features[:, :2], 2, scale=1.0)
    with pytest.raises(ValueError, match="max_disparity"):
        cost_volume(features, features, 0, scale=1.0)
    with pytest.raises(ValueError, match="scale"):
        cost_volume(features, features, 2, scale=0.0)
    with pytest.raises(ValueError, match="scale"):
        cost_volume(features, features, 2, scale=2048.0)
    with pytest.raises(ValueError, match="out"):
        cost_volume(features, features, 2, scale=1.0, out=np.empty((3, 4, 3), np.int16))
    with pytest.raises(ValueError, match="out"):
        cost_volume(features, features, 2, scale=1.0, out=np.empty((3, 4, 2), np.float32))
