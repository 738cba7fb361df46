"""Shiftable windows (service/aggregation): the row min filter against NumPy, in place, and what it is
for: next to a depth edge a centred window's cost picks the foreground, a shiftable one the background."""

from __future__ import annotations

import numpy as np
import pytest

from service.aggregation import SHIFT_RADIUS, shiftable_windows
from service.disparity import winner_takes_all


def reference(volume: np.ndarray, radius: int) -> np.ndarray:
    """The definition: the lowest of the row's cells x - radius .. x + radius (clipped to the image)."""
    width = volume.shape[1]
    out = volume.copy()
    for x in range(width):
        out[:, x] = volume[:, max(0, x - radius):min(width, x + radius + 1)].min(axis=1)
    return out


@pytest.mark.parametrize("radius", [1, 2, 3, 40])
def test_equals_the_reference_on_random_volumes(rng, radius):
    volume = rng.integers(-32768, 32768, (9, 23, 7)).astype(np.int16)
    expected = reference(volume, radius)
    assert shiftable_windows(volume, radius=radius) is volume  # in place
    np.testing.assert_array_equal(volume, expected)


def test_the_default_radius_is_one_pixel_each_side(rng):
    volume = rng.integers(-128, 129, (4, 11, 5)).astype(np.int16)
    assert SHIFT_RADIUS == 1
    np.testing.assert_array_equal(shiftable_windows(volume.copy()), reference(volume, 1))


def test_radius_zero_and_empty_volumes_change_nothing(rng):
    volume = rng.integers(-128, 129, (3, 5, 4)).astype(np.int16)
    np.testing.assert_array_equal(shiftable_windows(volume.copy(), radius=0), volume)
    assert shiftable_windows(np.zeros((0, 5, 4), np.int16)).shape == (0, 5, 4)


@pytest.mark.parametrize(("volume", "radius", "message"), [
    (np.zeros((3, 4), np.int16), 1, "int16"),
    (np.zeros((3, 4, 2), np.float32), 1, "int16"),
    (np.zeros((3, 4, 2), np.int16)[:, ::2], 1, "C-contiguous"),
    (np.zeros((3, 4, 2), np.int16), -1, "radius"),
    (np.zeros((3, 4, 2), np.int16), True, "radius"),
    (np.zeros((3, 4, 2), np.int16), 1.5, "radius"),
])
def test_bad_input_is_refused(volume, radius, message):
    with pytest.raises(ValueError, match=message):
        shiftable_windows(volume, radius=radius)


def test_a_centred_window_fattens_the_foreground_and_a_shiftable_one_does_not():
    # One row: a strongly textured foreground at disparity 6 left of x = 30, a faintly textured background
    # at disparity 2 right of it. Costs are the sum of absolute differences over a centred 7-px window, so
    # the first background pixels right of the edge see the foreground's texture, whose mismatch outweighs
    # their own, and take its disparity.
    rng = np.random.default_rng(3)
    width, edge, near, far, half = 64, 30, 6, 2, 3
    foreground = rng.integers(0, 256, width + 16).astype(np.int64)
    background = rng.integers(110, 146, width + 16).astype(np.int64)
    left = np.where(np.arange(width) < edge, foreground[:width], background[:width])
    # The right view: the foreground moved by 6 px, the background by 2 px, which it uncovers in between.
    right = np.array([foreground[x + near] if x < edge - near else background[x + far] for x in range(width)])
    truth = np.where(np.arange(width) < edge, near, far)
    disparities = 10
    volume = np.zeros((1, width, disparities), np.int16)
    for x in range(width):
        for d in range(disparities):
            columns = np.clip(np.arange(x - half, x + half + 1), 0, width - 1)
            volume[0, x, d] = np.abs(left[columns] - right[np.clip(columns - d, 0, width - 1)]).sum()
    region = slice(edge, edge + half)  # background pixels whose centred window reaches the foreground
    centred = winner_takes_all(volume)[0]
    shifted = winner_takes_all(shiftable_windows(volume.copy(), radius=half))[0]
    assert np.count_nonzero(centred[region] != truth[region]) >= 2
    np.testing.assert_array_equal(shifted[region], truth[region])
    visible = np.r_[near + half:edge, edge:width - half]  # the rest, away from the image borders
    np.testing.assert_array_equal(shifted[visible], truth[visible])
