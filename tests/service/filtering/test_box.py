"""Box filters against windows summed one by one (edges repeated)."""

from __future__ import annotations

import numpy as np
import pytest

from service.filtering.box import box_sum, local_std


def _windows(image: np.ndarray, radius: int) -> np.ndarray:
    padded = np.pad(image, radius, mode="edge")
    size = 2 * radius + 1
    height, width = image.shape
    return np.stack([padded[dy : dy + height, dx : dx + width] for dy in range(size) for dx in range(size)])


@pytest.mark.parametrize("radius", [1, 2, 4])
def test_box_sum_and_local_std_equal_the_windows(rng, radius):
    image = rng.integers(0, 256, (13, 17)).astype(np.float64)
    windows = _windows(image, radius)
    np.testing.assert_allclose(box_sum(image, radius), windows.sum(axis=0), rtol=1e-12)
    np.testing.assert_allclose(local_std(image, radius), windows.std(axis=0), atol=1e-9)


def test_box_sum_keeps_the_dtype_and_shape(rng):
    image = rng.random((5, 7)).astype(np.float32)
    assert box_sum(image, 2).dtype == np.float32 and box_sum(image, 2).shape == (5, 7)


def test_flat_image_has_no_texture():
    assert not local_std(np.full((6, 6), 42.0), 1).any()
