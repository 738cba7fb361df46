"""CachedTowers: the towers run once per distinct pair, and a P1/P2 grid through them tunes as without."""

from __future__ import annotations

import numpy as np
import pytest

from service.datasets import StereoSample
from service.evaluation.tuning import tune_penalties
from service.features import CachedTowers, FeatureTowers, default_model_dir
from service.matcher import Matcher


class _CountingTowers:
    """Features that depend on the pair, and a count of the calls."""

    def __init__(self, towers=None) -> None:
        self.towers = towers
        self.manifest = towers.manifest if towers is not None else {"channels": 1}
        self.calls = 0

    def __call__(self, left, right):
        self.calls += 1
        if self.towers is not None:
            self.returned = self.towers(left, right)
        else:
            self.returned = (left[None, ..., 0].astype(np.float32), right[None, ..., 0].astype(np.float32))
        return self.returned

    def warmup(self) -> None:
        pass


def _image(seed: int, shape=(8, 12, 3)) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, shape, dtype=np.uint8)


def test_a_pair_seen_before_does_not_run_the_towers_again() -> None:
    counting = _CountingTowers()
    towers = CachedTowers(counting, pairs=2)
    first = towers(_image(0), _image(1))
    assert towers(_image(0), _image(1)) is first
    np.testing.assert_array_equal(first[0], _image(0)[None, ..., 0])
    assert counting.calls == 1
    towers(_image(1), _image(0))  # the views swapped: another pair
    assert counting.calls == 2


def test_the_cache_holds_copies_not_the_towers_buffers() -> None:
    # ONNX Runtime's outputs stay in its capped arena while they live: 20 cached pairs of a 64-channel
    # model's features ran it out of memory before the cache copied them.
    counting = _CountingTowers(FeatureTowers(default_model_dir(), threads=1))
    cached = CachedTowers(counting, pairs=1)(_image(0, (24, 40, 3)), _image(1, (24, 40, 3)))
    for kept, returned in zip(cached, counting.returned, strict=True):
        np.testing.assert_array_equal(kept, returned)
        assert not np.shares_memory(kept, returned)


def test_the_least_recently_used_pair_is_dropped() -> None:
    counting = _CountingTowers()
    towers = CachedTowers(counting, pairs=2)
    a, b, c = ((_image(seed), _image(seed + 10)) for seed in range(3))
    towers(*a), towers(*b), towers(*a), towers(*c)  # b is the oldest when c arrives
    assert counting.calls == 3
    towers(*a)
    assert counting.calls == 3
    towers(*b)
    assert counting.calls == 4


def test_the_same_bytes_in_another_shape_are_another_pair() -> None:
    counting = _CountingTowers()
    towers = CachedTowers(counting, pairs=4)
    left, right = _image(0), _image(1)
    towers(left, right)
    towers(left.reshape(12, 8, 3), right.reshape(12, 8, 3))
    assert counting.calls == 2


def test_it_keeps_at_least_one_pair() -> None:
    with pytest.raises(ValueError, match="pairs must be >= 1"):
        CachedTowers(_CountingTowers(), pairs=0)


def test_a_grid_through_cached_towers_chooses_and_measures_as_without() -> None:
    # The Matcher must not write into the features it is given: the cached arrays serve every grid point.
    rng = np.random.default_rng(5)
    samples = []
    for index in range(2):
        right = rng.integers(0, 256, (40, 72, 3), dtype=np.uint8)
        shift = 3 + 2 * index
        left = np.empty_like(right)
        left[:, shift:], left[:, :shift] = right[:, :-shift], right[:, :1]
        truth = np.full((40, 72), float(shift), np.float32)
        samples.append(StereoSample(name=f"shift-{shift}", left=left, right=right, disparity=truth,
                                    max_disparity=16))
    grid = {"p1_grid": (10.0, 45.0), "p2_grid": (80.0, 540.0)}
    folder = default_model_dir()
    plain = tune_penalties(Matcher.from_folder(folder, threads=1), samples, **grid)
    counting = _CountingTowers(FeatureTowers(folder, threads=1))
    cached = tune_penalties(Matcher(CachedTowers(counting, pairs=len(samples)), threads=1), samples, **grid)
    assert cached == plain
    assert counting.calls == len(samples)
