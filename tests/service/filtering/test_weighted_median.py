"""The image-guided weighted median (service/filtering): against a sort-based NumPy reference, at edges
only, NaN-safe, and what it is for: a fattened depth edge moves back to the image edge."""

from __future__ import annotations

import numpy as np
import pytest

from service.filtering import weighted_median
from service.filtering.weighted_median import EDGE_SPREAD, RADIUS, SIGMA_COLOUR, SIGMA_SPACE


def reference(disparity: np.ndarray, image: np.ndarray, radius: int = RADIUS) -> np.ndarray:
    """The definition, written plainly: sort the window, walk the weights to half the total."""
    height, width = disparity.shape
    out = disparity.copy()
    grey = image.astype(np.int64)
    for y in range(height):
        for x in range(width):
            if np.isnan(disparity[y, x]):
                continue
            near = disparity[max(0, y - 2):y + 3, max(0, x - 2):x + 3]
            if np.nanmax(near) - np.nanmin(near) < EDGE_SPREAD:
                continue
            rows = slice(max(0, y - radius), min(height, y + radius + 1))
            columns = slice(max(0, x - radius), min(width, x + radius + 1))
            yy, xx = np.mgrid[rows, columns]
            values = disparity[rows, columns].ravel()
            colour = np.abs(grey[rows, columns] - grey[y, x]).sum(axis=2).ravel()
            weights = (np.exp(-colour / (3 * SIGMA_COLOUR))
                       * np.exp(-np.hypot(yy - y, xx - x).ravel() / SIGMA_SPACE))
            keep = ~np.isnan(values)
            values, weights = values[keep], weights[keep]
            order = np.argsort(values, kind="stable")
            cumulative = np.cumsum(weights[order])
            out[y, x] = values[order][np.searchsorted(cumulative, cumulative[-1] / 2 * (1 - 1e-6))]
    return out


def test_equals_the_reference_on_random_maps(rng):
    disparity = rng.uniform(0, 40, (37, 53)).astype(np.float32)
    disparity[rng.random(disparity.shape) < 0.5] = 20.0  # ties, as integer winners give
    image = rng.integers(0, 256, (37, 53, 3), dtype=np.uint8)
    expected = reference(disparity, image)
    assert np.allclose(weighted_median(disparity, image), expected, atol=1e-6)


def test_nan_pixels_stay_nan_and_do_not_vote(rng):
    disparity = rng.uniform(0, 40, (30, 40)).astype(np.float32)
    disparity[10:20, 5:25] = np.nan
    image = rng.integers(0, 256, (30, 40, 3), dtype=np.uint8)
    filtered = weighted_median(disparity, image)
    assert np.array_equal(np.isnan(filtered), np.isnan(disparity))
    assert np.allclose(filtered, reference(disparity, image), atol=1e-6, equal_nan=True)


def test_smooth_surfaces_keep_their_subpixel_values(rng):
    # A slanted plane: neighbours within 1.5 px everywhere, so nothing is touched.
    disparity = (10 + 0.1 * np.arange(60)[None, :] + 0.05 * np.arange(40)[:, None]).astype(np.float32)
    image = rng.integers(0, 256, (40, 60, 3), dtype=np.uint8)
    assert np.array_equal(weighted_median(disparity, image), disparity)


def test_a_fattened_edge_moves_to_the_image_edge():
    image = np.zeros((30, 40, 3), np.uint8)
    image[:, 20:] = 180  # the object starts at x = 20
    truth = np.where(np.arange(40) >= 20, 12.0, 3.0).astype(np.float32)[None].repeat(30, axis=0)
    fattened = truth.copy()
    fattened[:, 18:20] = 12.0  # the foreground bled 2 px over the background
    filtered = weighted_median(fattened, image)
    assert np.array_equal(filtered, truth)


def test_colour_differences_do_not_wrap_around():
    # 0 vs 255 in uint8 arithmetic would wrap to a small difference and give full weight across the edge.
    image = np.zeros((20, 30, 3), np.uint8)
    image[:, 15:] = 255
    disparity = np.where(np.arange(30) >= 14, 9.0, 2.0).astype(np.float32)[None].repeat(20, axis=0)
    assert weighted_median(disparity, image)[10, 14] == 2.0


def test_bad_input_is_refused():
    with pytest.raises(ValueError, match="uint8"):
        weighted_median(np.zeros((4, 5), np.float32), np.zeros((4, 5, 3), np.float32))
    with pytest.raises(ValueError, match="uint8"):
        weighted_median(np.zeros((4, 5), np.float32), np.zeros((5, 4, 3), np.uint8))
    with pytest.raises(ValueError, match="radius"):
        weighted_median(np.zeros((4, 5), np.float32), np.zeros((4, 5, 3), np.uint8), radius=0)


def test_read_only_images_use_the_same_compiled_kernel(rng):
    # A decoded file is a read-only array; numba would compile a second specialisation for it on the
    # first real request, after warm-up.
    from service.filtering.weighted_median import _filter_rows

    disparity = rng.uniform(0, 9, (12, 16)).astype(np.float32)
    image = rng.integers(0, 256, (12, 16, 3), dtype=np.uint8)
    weighted_median(disparity, image)
    compiled = len(_filter_rows.signatures)
    image.flags.writeable = False
    disparity.flags.writeable = False
    weighted_median(disparity, image)
    weighted_median(disparity.copy(), np.asfortranarray(image))
    assert len(_filter_rows.signatures) == compiled
