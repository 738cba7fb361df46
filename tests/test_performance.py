"""Speed-driven code paths (issue 6): tower row strips, the shared ORT arena, warm-up coverage.

Each path must give the same answer as the simple one it replaces; speed itself is measured by
``python -m bench suite``, not here.
"""

from __future__ import annotations

import numpy as np
import pytest

from service import matcher as matcher_module
from service.features import FeatureTowers, default_model_dir
from service.matcher import Matcher, MatchOptions, tower_strips


@pytest.mark.parametrize(
    ("height", "width", "halo"), [(375, 1242, 18), (1, 5, 4), (50, 20000, 4), (97, 3000, 0)]
)
def test_tower_strips_cover_every_row_once_with_halo(monkeypatch, height, width, halo):
    monkeypatch.setattr(matcher_module, "TOWER_STRIP_CELLS", 20_000 * 16)
    strips = tower_strips(height, width, halo, channels=16)
    kept = np.zeros(height, int)
    for run_top, run_bottom, keep_top, keep_bottom in strips:
        kept[keep_top:keep_bottom] += 1
        assert 0 <= run_top <= keep_top < keep_bottom <= run_bottom <= height
        # Every kept row is `halo` rows inside its strip, unless the strip edge is the image edge.
        assert keep_top - run_top >= halo or run_top == 0
        assert run_bottom - keep_bottom >= halo or run_bottom == height
    assert (kept == 1).all()


def test_strip_budget_scales_with_channels():
    # KITTI size: a 16-channel tower runs whole, a 64-channel one in 2 strips (its arena is 4x larger).
    assert len(tower_strips(375, 1242, 18, channels=16)) == 1
    assert len(tower_strips(375, 1242, 18, channels=64)) == 2


@pytest.mark.parametrize("model", ["ncc-baseline", "default"])
def test_strip_features_equal_whole_image_features(monkeypatch, model):
    folder = None if model == "default" else default_model_dir().parent / model
    matcher = Matcher.from_folder(folder, threads=2)
    halo = int(matcher.manifest["receptive_field"]) // 2
    height, width = 4 * (2 * halo + 1) + 3, 40  # strips of the smallest core (2 * halo + 1 rows): 5 of them
    rng = np.random.default_rng(3)
    left, right = (rng.integers(0, 256, (height, width, 3), dtype=np.uint8) for _ in range(2))
    whole = matcher.towers(left, right)
    channels = int(matcher.manifest["channels"])
    monkeypatch.setattr(matcher_module, "TOWER_STRIP_CELLS", width * channels)  # the smallest strips
    assert len(tower_strips(height, width, halo, channels=channels)) == 5
    strips = matcher._features(left, right)
    for a, b in zip(whole, strips, strict=True):
        np.testing.assert_allclose(b, a, atol=1e-5)
    result = matcher(left, right, MatchOptions(max_disparity=16))
    monkeypatch.setattr(matcher_module, "TOWER_STRIP_CELLS", 10**12)
    reference = matcher(left, right, MatchOptions(max_disparity=16))
    np.testing.assert_array_equal(result.validity, reference.validity)
    np.testing.assert_allclose(result.disparity, reference.disparity, atol=1e-3, equal_nan=True)


def test_two_tower_pairs_share_the_arena_and_agree():
    """The process-wide arena is registered once; a second FeatureTowers reuses it and gives equal output."""
    first = FeatureTowers(default_model_dir(), threads=1)
    second = FeatureTowers(default_model_dir(), threads=2)
    image = np.random.default_rng(4).integers(0, 256, (40, 56, 3), dtype=np.uint8)
    for a, b in zip(first(image, image), second(image, image), strict=True):
        np.testing.assert_allclose(a, b, atol=1e-5)


def _compiled_specialisations() -> int:
    import sys

    import numba

    return sum(
        len(value.signatures)
        for name, module in list(sys.modules.items())
        if name.startswith("service.") and module is not None
        for value in vars(module).values()
        if isinstance(value, numba.core.registry.CPUDispatcher)
    )


def test_warmup_leaves_nothing_to_compile_on_the_request_path():
    """After Matcher.warmup(), no option combination or image size compiles a Numba kernel."""
    matcher = Matcher.from_folder(threads=2)
    matcher.warmup()
    compiled = _compiled_specialisations()
    rng = np.random.default_rng(5)
    left, right = (rng.integers(0, 256, (37, 53, 3), dtype=np.uint8) for _ in range(2))
    for options in (MatchOptions(max_disparity=12), MatchOptions(sgm=False, subpixel=False),
                    MatchOptions(lr_check=False, fill=False), MatchOptions(fill=False, p1=0, p2=0)):
        matcher(left, right, options)
    assert _compiled_specialisations() == compiled
