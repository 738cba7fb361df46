"""Numba SGM against the NumPy reference, on random int16 volumes and edge shapes: equal, not close,
because integer costs and penalties make every path cost an exact integer."""

from __future__ import annotations

import numpy as np
import pytest

from service.optimization import aggregate
from tests.service.optimization.reference_sgm import reference_sgm

SCALE = 128


def _random_cost(shape: tuple[int, int, int], seed: int) -> np.ndarray:
    return np.random.default_rng(seed).integers(-SCALE, SCALE, shape, endpoint=True).astype(np.int16)


@pytest.mark.parametrize(
    "shape",
    [(7, 9, 5), (13, 40, 16), (1, 12, 6), (10, 1, 6), (8, 11, 1), (5, 4, 9), (1, 1, 1), (1, 1, 7),
     (40, 3, 2)],
    ids=lambda shape: "x".join(map(str, shape)),
)
@pytest.mark.parametrize(("p1", "p2"), [(30.0, 160.0), (0.0, 0.0), (5.0, 300.0)])
def test_matches_reference(shape: tuple[int, int, int], p1: float, p2: float) -> None:
    cost = _random_cost(shape, seed=sum(shape))
    expected = reference_sgm(cost, p1, p2)
    result = aggregate(cost, p1=p1, p2=p2)
    assert result.shape == shape and result.dtype == np.int16
    np.testing.assert_array_equal(result, expected)


def test_wide_column_blocks_match_reference() -> None:
    # More columns than one vertical task holds, and a ragged last block.
    cost = _random_cost((6, 75, 4), seed=3)
    expected = reference_sgm(cost, 30, 160)
    np.testing.assert_array_equal(aggregate(cost, p1=30, p2=160), expected)


def test_first_pixel_of_every_path_is_its_cost() -> None:
    # A single pixel is the first pixel of all 4 paths: the sum is 4 C.
    cost = _random_cost((1, 1, 5), seed=1)
    np.testing.assert_array_equal(aggregate(cost, p1=30, p2=160), 4 * cost.astype(np.int32))


def test_smooths_a_noisy_winner() -> None:
    # A constant-disparity scene with one pixel whose raw minimum is wrong: SGM restores the majority.
    cost = np.full((9, 9, 8), 50, np.int16)
    cost[:, :, 3] = -50
    cost[4, 4, 3] = 60
    cost[4, 4, 6] = 40
    assert cost[4, 4].argmin() != 3
    assert aggregate(cost, p1=30, p2=160)[4, 4].argmin() == 3


def test_out_argument_is_used() -> None:
    cost = _random_cost((4, 5, 3), seed=2)
    out = np.empty_like(cost)
    assert aggregate(cost, p1=30, p2=160, out=out) is out


def test_penalties_are_whole_cost_units() -> None:
    cost = _random_cost((5, 6, 7), seed=4)
    np.testing.assert_array_equal(aggregate(cost, p1=29.6, p2=160.4), aggregate(cost, p1=30, p2=160))


def test_largest_costs_and_penalties_stay_inside_int16() -> None:
    # |C| = 1024 (the largest cost scale) and P2 = 4096 (the largest penalty): no wrap-around.
    rng = np.random.default_rng(5)
    cost = rng.choice(np.array([-1024, 1024], np.int16), (12, 15, 6))
    result = aggregate(cost, p1=4096, p2=4096)
    np.testing.assert_array_equal(result, reference_sgm(cost, 4096, 4096))
    assert np.abs(result).max() <= 4 * (1024 + 4096)


def test_sums_saturate_instead_of_wrapping() -> None:
    # Out-of-contract costs (beyond the largest scale) clip at the int16 bounds rather than flip sign.
    cost = np.full((3, 3, 2), 30000, np.int16)
    assert aggregate(cost, p1=0, p2=0).min() == 32767


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [({"p1": -1.0, "p2": 1.0}, "p1"), ({"p1": 1.0, "p2": float("nan")}, "p2"),
     ({"p1": 1.0, "p2": 4097}, "p2")],
)
def test_rejects_bad_penalties(kwargs: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        aggregate(_random_cost((2, 2, 2), seed=0), **kwargs)


def test_rejects_bad_shapes() -> None:
    with pytest.raises(ValueError, match="cost volume"):
        aggregate(np.zeros((3, 4), np.int16), p1=1, p2=2)
    with pytest.raises(ValueError, match="int16"):
        aggregate(np.zeros((3, 4, 2), np.float32), p1=1, p2=2)
    with pytest.raises(ValueError, match="out"):
        aggregate(np.zeros((3, 4, 2), np.int16), p1=1, p2=2, out=np.zeros((3, 4, 3), np.int16))


@pytest.mark.parametrize("shape", [(7, 9, 5), (13, 40, 16), (1, 12, 6), (10, 1, 6), (6, 75, 4)],
                         ids=lambda shape: "x".join(map(str, shape)))
@pytest.mark.parametrize("edge", [8.0, 0.5])
def test_image_adaptive_p2_matches_reference(shape: tuple[int, int, int], edge: float) -> None:
    cost = _random_cost(shape, seed=sum(shape) + 1)
    guide = np.random.default_rng(sum(shape)).uniform(0, 255, shape[:2]).astype(np.float32)
    expected = reference_sgm(cost, 30.0, 300.0, guide, edge)
    np.testing.assert_array_equal(aggregate(cost, p1=30, p2=300, guide=guide, edge=edge), expected)


def test_a_flat_guide_is_the_constant_penalty_and_an_edge_lowers_it() -> None:
    cost = _random_cost((6, 8, 5), seed=4)
    flat = np.full(cost.shape[:2], 100.0, np.float32)
    constant = aggregate(cost, p1=30, p2=300)
    np.testing.assert_array_equal(aggregate(cost, p1=30, p2=300, guide=flat), constant)
    edged = flat.copy()
    edged[:, 4:] = 200.0
    assert not np.array_equal(aggregate(cost, p1=30, p2=300, guide=edged), constant)
    with pytest.raises(ValueError, match="guide"):
        aggregate(cost, p1=30, p2=300, guide=flat[:, :3])
