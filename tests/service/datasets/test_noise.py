"""NoisyViews (``adsm eval --noise``): noise of the asked size on both views, the truth untouched, the same
pixels however the dataset is read, bad sizes refused."""

from __future__ import annotations

import numpy as np
import pytest

from service.datasets import StereoSample
from service.datasets.noise import MAX_NOISE_SIGMA, NoisyViews


def _pairs(count: int = 3) -> list[StereoSample]:
    view = np.full((60, 80, 3), 128, np.uint8)
    truth = np.full((60, 80), 5.0, np.float32)
    mask = np.ones((60, 80), bool)
    return [StereoSample(f"pair{i}", view, view.copy(), truth, mask, 32) for i in range(count)]


def test_noise_has_the_asked_size_and_leaves_the_rest():
    pairs = _pairs()
    noisy = NoisyViews(pairs, sigma=3.0)
    sample = noisy[1]
    for view in (sample.left, sample.right):
        assert view.dtype == np.uint8 and abs(float(view.astype(float).std()) - 3.0) < 0.1
    assert not np.array_equal(sample.left, sample.right)        # each view its own noise
    assert sample.disparity is pairs[1].disparity and sample.nonoccluded is pairs[1].nonoccluded
    assert sample.max_disparity == 32 and sample.name == "pair1" and len(noisy) == 3


def test_a_pair_reads_the_same_in_any_order_and_pairs_differ():
    noisy = NoisyViews(_pairs(), sigma=2.0, seed=5)
    first = noisy[2].left
    assert np.array_equal(noisy[-1].left, first) and np.array_equal(list(noisy)[2].left, first)
    assert np.array_equal(noisy[1:][1].left, first)
    assert not np.array_equal(noisy[0].left, first)
    assert not np.array_equal(NoisyViews(_pairs(), sigma=2.0, seed=6)[2].left, first)
    with pytest.raises(IndexError):
        noisy[3]


def test_zero_noise_is_the_dataset_itself():
    pairs = _pairs()
    assert NoisyViews(pairs, sigma=0)[0] is pairs[0]


def test_clipping_keeps_8_bits():
    dark = StereoSample("dark", np.zeros((8, 8, 3), np.uint8), np.full((8, 8, 3), 255, np.uint8),
                        np.zeros((8, 8), np.float32))
    sample = NoisyViews([dark], sigma=40.0)[0]
    assert sample.left.min() == 0 and sample.right.max() == 255


@pytest.mark.parametrize("sigma", [-1.0, float("nan"), float("inf"), MAX_NOISE_SIGMA + 1, True, "2"])
def test_bad_sigma_is_refused(sigma):
    with pytest.raises(ValueError, match="noise sigma"):
        NoisyViews(_pairs(), sigma=sigma)
