"""The GPU kernels (service/cuda) against their CPU twins, on random volumes and maps (issue 16).

They run where ``numba.cuda`` finds a GPU, and on Numba's CUDA simulator (``NUMBA_ENABLE_CUDASIM=1``,
test_simulated.py), which executes every GPU thread in Python: there the shapes are tiny, on a GPU they
span several blocks and warps. Everything is compared exactly except the sub-pixel offsets and the peak
ratios (float32 division, to 1e-6) and the cost of random features (one unit, where the CPU kernel's
fastmath sum rounds the other way).
"""

from __future__ import annotations

import numpy as np
import pytest
from numba import config, cuda

from service.aggregation import shiftable_windows
from service.cost import cost_volume, right_view_volume
from service.disparity import left_right_winners, winner_takes_all
from service.filling import fill_invalid
from service.filling.rays import _DIRECTIONS
from service.optimization import aggregate
from service.refinement import refine_subpixel
from service.validation import inner_check
from service.validation.codes import MISMATCH, OCCLUDED, VALID
from service.validation.confidence import cost_confidence
from tests.helpers import require_gpu

require_gpu()

SIMULATED = bool(config.ENABLE_CUDASIM)
# (H, W, D): the simulator runs each thread in Python; a GPU gets lines of several warps and D > 256
# threads' worth of looping in the SGM test.
SHAPE = (3, 7, 5) if SIMULATED else (41, 157, 96)
SCALE = 128.0


def _random_volume(rng: np.random.Generator, shape: tuple[int, int, int] = SHAPE, spread: int = 128
                   ) -> np.ndarray:
    return rng.integers(-spread, spread + 1, shape).astype(np.int16)


@pytest.mark.parametrize("min_disparity", [0, 2, -3])
def test_cost_volume_equals_the_cpu_to_the_bit_where_the_sums_are_exact(min_disparity: int) -> None:
    from service.cuda import volume

    rng = np.random.default_rng(0)
    height, width, disparities = SHAPE
    # Multiples of 1/16: every product and sum is exact in float32, and many land on .5 (rint's ties).
    left, right = (rng.integers(-16, 17, (4, height, width)).astype(np.float32) / 16 for _ in range(2))
    expected = cost_volume(left, right, disparities, scale=SCALE, min_disparity=min_disparity)
    out = cuda.device_array(expected.shape, np.int16)
    volume.cost_volume(cuda.to_device(left), cuda.to_device(right), disparities, scale=SCALE,
                       min_disparity=min_disparity, out=out)
    np.testing.assert_array_equal(out.copy_to_host(), expected)


def test_cost_volume_of_unit_features_is_within_one_unit() -> None:
    from service.cuda import volume

    rng = np.random.default_rng(1)
    height, width, disparities = SHAPE
    left, right = (rng.normal(size=(32, height, width)).astype(np.float32) for _ in range(2))
    left /= np.linalg.norm(left, axis=0)
    right /= np.linalg.norm(right, axis=0)
    expected = cost_volume(left, right, disparities, scale=SCALE)
    out = cuda.device_array(expected.shape, np.int16)
    volume.cost_volume(cuda.to_device(left), cuda.to_device(right), disparities, scale=SCALE, min_disparity=0,
                       out=out)
    difference = np.abs(out.copy_to_host().astype(np.int32) - expected)
    assert difference.max() <= 1
    assert np.mean(difference == 0) >= 0.99


@pytest.mark.parametrize("min_disparity", [0, 2, -3])
def test_right_view_volume_equals_the_cpu(min_disparity: int) -> None:
    from service.cuda import volume

    raw = _random_volume(np.random.default_rng(2))
    out = cuda.device_array(raw.shape, np.int16)
    volume.right_view_volume(cuda.to_device(raw), scale=SCALE, min_disparity=min_disparity, out=out)
    np.testing.assert_array_equal(out.copy_to_host(),
                                  right_view_volume(raw, scale=SCALE, min_disparity=min_disparity))


def test_shiftable_windows_equal_the_cpu() -> None:
    from service.cuda import volume

    raw = _random_volume(np.random.default_rng(3))
    out = cuda.device_array(raw.shape, np.int16)
    volume.shiftable_windows(cuda.to_device(raw), radius=1, out=out)
    np.testing.assert_array_equal(out.copy_to_host(), shiftable_windows(raw.copy(), radius=1))


@pytest.mark.parametrize(("p1", "p2", "adaptive"), [(10, 120, False), (30, 540, True), (0, 0, False)])
def test_sgm_equals_the_cpu_to_the_bit(p1: float, p2: float, adaptive: bool) -> None:
    from service.cuda import sgm

    rng = np.random.default_rng(4)
    raw = _random_volume(rng)
    guide = rng.integers(0, 256, raw.shape[:2]).astype(np.float32) if adaptive else None
    expected = aggregate(raw, p1=p1, p2=p2, guide=guide)
    out = cuda.device_array(raw.shape, np.int16)
    sgm.aggregate(cuda.to_device(raw), p1=p1, p2=p2, out=out,
                  guide=None if guide is None else cuda.to_device(guide), edge=8.0 if adaptive else 0.0)
    np.testing.assert_array_equal(out.copy_to_host(), expected)


@pytest.mark.parametrize("threads", [None, 32])
def test_sgm_loops_over_more_disparities_than_a_block_has_threads(threads: int | None) -> None:
    from service.cuda import sgm

    shape = (1, 3, 260) if SIMULATED else (7, 33, 300)  # 256 threads per line at most
    assert shape[2] > (threads or sgm.threads_for(shape[2]))
    raw = _random_volume(np.random.default_rng(5), shape)
    out = cuda.device_array(raw.shape, np.int16)
    sgm.aggregate(cuda.to_device(raw), p1=20, p2=300, out=out, threads=threads)
    np.testing.assert_array_equal(out.copy_to_host(), aggregate(raw, p1=20, p2=300))
    with pytest.raises(ValueError, match="threads per SGM line must be one of"):
        sgm.aggregate(cuda.to_device(raw), p1=20, p2=300, out=out, threads=48)


@pytest.mark.parametrize("min_disparity", [0, 2, -3])
def test_both_views_winners_equal_the_cpu_ties_included(min_disparity: int) -> None:
    from service.cuda import pixels

    aggregated = _random_volume(np.random.default_rng(6), spread=2)  # five cost values: many ties
    height, width, _ = aggregated.shape
    left_expected, right_expected = left_right_winners(aggregated, min_disparity=min_disparity)
    left, right = (cuda.device_array((height, width), np.int32) for _ in range(2))
    device_volume = cuda.to_device(aggregated)
    blocks = pixels.blocks(height * width)
    pixels.winners[blocks, pixels.THREADS](device_volume, left)
    pixels.right_winners[blocks, pixels.THREADS](device_volume, min_disparity, right)
    np.testing.assert_array_equal(left.copy_to_host(), left_expected)
    np.testing.assert_array_equal(left.copy_to_host(), winner_takes_all(aggregated))
    np.testing.assert_array_equal(right.copy_to_host(), right_expected)


def test_subpixel_and_confidence_equal_the_cpu() -> None:
    from service.cuda import pixels

    aggregated = _random_volume(np.random.default_rng(7), spread=40)
    height, width, _ = aggregated.shape
    winners = winner_takes_all(aggregated)
    device_volume, device_winners = cuda.to_device(aggregated), cuda.to_device(winners)
    refined = cuda.device_array((height, width), np.float32)
    peak = cuda.device_array((height, width), np.float32)
    blocks = pixels.blocks(height * width)
    pixels.refine[blocks, pixels.THREADS](device_volume, device_winners, refined)
    pixels.confidence[blocks, pixels.THREADS](device_volume, device_winners, np.int32(-4 * 128), peak)
    np.testing.assert_allclose(refined.copy_to_host(), refine_subpixel(aggregated, winners), rtol=0,
                               atol=1e-6)
    np.testing.assert_allclose(peak.copy_to_host(), cost_confidence(aggregated, winners, lowest=-4 * 128),
                               rtol=0, atol=1e-6)


@pytest.mark.parametrize(("min_disparity", "threshold"), [(0, 0.75), (2, 1.0), (-3, 0.5)])
def test_inner_check_equals_the_cpu(min_disparity: int, threshold: float) -> None:
    from service.cuda import pixels

    rng = np.random.default_rng(8)
    height, width, disparities = SHAPE
    span = (min_disparity, min_disparity + disparities - 1)
    left = (rng.integers(*span, (height, width), endpoint=True) + rng.uniform(-0.5, 0.5, (height, width)))
    left = left.astype(np.float32)
    right = rng.integers(*span, (height, width), endpoint=True).astype(np.int32)
    validity = cuda.device_array((height, width), np.uint8)
    pixels.check[pixels.blocks(height * width), pixels.THREADS](
        cuda.to_device(left), cuda.to_device(right), min_disparity, disparities, np.float32(threshold),
        validity)
    np.testing.assert_array_equal(
        validity.copy_to_host(),
        inner_check(left, right, disparities, min_disparity=min_disparity, threshold=threshold))


@pytest.mark.parametrize(("run", "fraction"), [(2, (1, 3)), (1, (1, 2))])
def test_fill_equals_the_cpu(run: int, fraction: tuple[int, int]) -> None:
    from service.cuda import pixels

    rng = np.random.default_rng(9)
    height, width, disparities = SHAPE
    disparity = rng.uniform(0, disparities, (height, width)).astype(np.float32)
    validity = rng.choice(np.array([VALID, OCCLUDED, MISMATCH], np.uint8), (height, width), p=[0.6, 0.2, 0.2])
    validity[0, :] = OCCLUDED  # a row with no valid pixel: nothing to fill from on the horizontal rays
    expected_disparity, expected_validity = fill_invalid(disparity, validity, background_run=run,
                                                         mismatch_fraction=fraction)
    filled = cuda.device_array((height, width), np.float32)
    filled_validity = cuda.device_array((height, width), np.uint8)
    pixels.fill[pixels.blocks(height * width), pixels.THREADS](
        cuda.to_device(disparity), cuda.to_device(validity), cuda.to_device(_DIRECTIONS), run, *fraction,
        filled, filled_validity)
    np.testing.assert_array_equal(filled_validity.copy_to_host(), expected_validity)
    np.testing.assert_array_equal(filled.copy_to_host(), expected_disparity)  # NaN where NaN
