"""Scene statistics (``adsm stats``): each figure on pairs whose answer is known by construction."""

from __future__ import annotations

import numpy as np
import pytest

from service.evaluation.scene_statistics import FLAT, SceneStatistics, match_residual


def _shifted_pair(rng, disparity: int, shape=(30, 50)):
    right = rng.integers(0, 256, (*shape, 3), dtype=np.uint8)
    left = np.roll(right, disparity, axis=1)
    return left, right, np.full(shape, float(disparity), np.float32)


def test_a_perfect_match_has_no_residual(rng):
    left, right, truth = _shifted_pair(rng, 5)
    residual = match_residual(left, right, truth)
    # Up to x = 5 some pixel of the 3x3 window has its match left of the right image.
    assert np.isnan(residual[:, :6]).all()
    np.testing.assert_allclose(residual[:, 6:], 0.0, atol=1e-9)


def test_noise_and_gain_between_the_views(rng):
    left, right, truth = _shifted_pair(rng, 3)
    # Gain and bias leave ZNCC at 1: the residual measures what a window correlation cannot normalise away.
    brighter = np.clip(right.astype(float) * 0.5 + 40, 0, 255).astype(np.uint8)
    assert np.nanmedian(match_residual(left, brighter, truth)) < 0.01
    medians = [np.nanmedian(match_residual(left, np.clip(right + rng.normal(0, sigma, right.shape), 0, 255)
                                           .astype(np.uint8), truth)) for sigma in (0, 10, 30)]
    assert medians[0] == 0.0 and 0.005 < medians[1] < medians[2]


def test_fractional_disparity_is_sampled_linearly():
    ramp = np.tile(np.arange(60, dtype=float) ** 2 / 10, (20, 1))        # smooth, textured along x
    right = np.repeat(ramp[..., None], 3, axis=2)
    left = np.repeat(((np.arange(60) - 2.5) ** 2 / 10)[None, :, None], 20, axis=0).repeat(3, axis=2)
    truth = np.full((20, 60), 2.5, np.float32)
    residual = match_residual(left.astype(np.float64), right, truth)
    assert np.nanmax(residual[:, 5:-2]) < 1e-3


def test_flat_windows_are_not_counted(rng):
    left, right, truth = _shifted_pair(rng, 2)
    left[:, 20:30] = right[:, 18:28] = 128
    residual = match_residual(left, right, truth)
    assert np.isnan(residual[:, 21:29]).all() and np.isfinite(residual[:, 35:]).all()


def test_depth_edges_texture_and_the_summary(rng):
    left, right, _ = _shifted_pair(rng, 0, shape=(40, 60))
    truth = np.where(np.arange(60) < 30, 10.0, 20.0).astype(np.float32)[None, :].repeat(40, axis=0)
    truth[:, :2] = np.nan                           # unknown pixels are not counted
    statistics = SceneStatistics()
    textured = statistics.add(left, right, truth)
    # The jump lies between columns 29 and 30: columns 26..33 are within 3 px.
    assert textured["pixels"] == 40 * 58 and textured["depth_edges"] == pytest.approx(100 * 8 / 58, abs=0.01)
    assert textured["texture_flat"] < 5 and textured["texture_median"] > 30
    flat = statistics.add(np.full_like(left, 90), np.full_like(right, 90), truth)
    assert flat["texture_flat"] == 100.0 and flat["texture_median"] == 0.0
    assert flat["residual_median"] is None and flat["residual_pixels"] == 0
    total = statistics.summary()
    assert total["pixels"] == 2 * 40 * 58 and total["depth_edges"] == textured["depth_edges"]
    assert total["texture_flat"] == pytest.approx((textured["texture_flat"] + 100) / 2, abs=0.01)
    assert total["residual_pixels"] == textured["residual_pixels"]
    assert FLAT == 2.0


def test_nothing_counted_gives_none():
    assert SceneStatistics().summary()["depth_edges"] is None
