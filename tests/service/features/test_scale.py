"""Tower scale (service/features/scale.py): the exact-grid upsampling, tiles at a scale, a match at one."""

from __future__ import annotations

import numpy as np
import pytest

from service.features import default_model_dir, load_manifest
from service.features import tiles as tiles_module
from service.features.scale import MAX_TOWER_SCALE, scaled_halo, upsample, upsampled_size
from service.features.tiles import halo_of, tiled_features, tower_plan
from service.match_options import MatchOptions
from service.matcher import Matcher
from service.memory import plan_request


@pytest.mark.parametrize("scale", [2, 3])
def test_upsampled_grid_holds_the_image_at_every_scale_th_pixel(scale):
    image = np.random.default_rng(0).integers(0, 256, (5, 7, 3), dtype=np.uint8)
    upsampled = upsample(image, scale)
    assert upsampled.shape == (upsampled_size(5, scale), upsampled_size(7, scale), 3) == (
        4 * scale + 1, 6 * scale + 1, 3)
    np.testing.assert_array_equal(upsampled[::scale, ::scale], image)
    # In between: the straight line between the two neighbours, rounded.
    a, b = image[2, 3].astype(float), image[2, 4].astype(float)
    for k in range(1, scale):
        expected = np.rint(a + (b - a) * k / scale)
        np.testing.assert_array_equal(upsampled[2 * scale, 3 * scale + k], expected)


def test_upsampling_a_single_row_or_pixel_keeps_it():
    row = np.arange(12, dtype=np.uint8).reshape(1, 4, 3)
    assert upsample(row, 2).shape == (1, 7, 3)
    assert upsample(row[:, :1], 3).shape == (1, 1, 3)
    assert upsample(row, 1) is row


def test_scaled_halo_covers_the_towers_context():
    for halo in range(0, 20):
        for scale in range(1, MAX_TOWER_SCALE + 1):
            assert scale * scaled_halo(halo, scale) >= halo > scale * (scaled_halo(halo, scale) - 1)


def test_features_at_a_scale_are_the_upsampled_pairs_at_its_own_pixels():
    matcher = Matcher.from_folder(None, threads=2)
    rng = np.random.default_rng(1)
    left, right = (rng.integers(0, 256, (21, 33, 3), dtype=np.uint8) for _ in range(2))
    by_definition = matcher.towers(upsample(left, 2), upsample(right, 2))
    scaled = tiled_features(matcher.towers, left, right, scale=2)
    for expected, got in zip(by_definition, scaled, strict=True):
        assert got.shape == (expected.shape[0], 21, 33) and got.flags.c_contiguous
        np.testing.assert_allclose(got, expected[:, ::2, ::2], atol=1e-6)


def test_tiles_at_a_scale_give_the_whole_pairs_features(monkeypatch):
    matcher = Matcher.from_folder(None, threads=2)
    scale = 2
    halo = scaled_halo(halo_of(matcher.manifest), scale)
    height, width = 3 * (2 * halo + 1) + 3, 4 * (2 * halo + 1) + 5
    rng = np.random.default_rng(3)
    left, right = (rng.integers(0, 256, (height, width, 3), dtype=np.uint8) for _ in range(2))
    whole = tiled_features(matcher.towers, left, right, scale=scale)
    per_pixel = tiles_module.work_bytes_per_pixel(matcher.manifest)
    monkeypatch.setattr(tiles_module, "TOWER_WORK_BYTES", per_pixel * scale**2 * 2 * (1 + 4 * halo) ** 2)
    tiles = tower_plan(height, width, matcher.manifest, scale=scale)
    assert len({tile.run_top for tile in tiles}) > 2 and len({tile.run_left for tile in tiles}) > 2
    budget = tiles_module.TOWER_WORK_BYTES // per_pixel
    for tile in tiles:  # each upsampled run within the budget the tiles were planned for
        assert tile.padded_pixels(halo_of(matcher.manifest), scale) <= budget
    for a, b in zip(whole, tiled_features(matcher.towers, left, right, scale=scale), strict=True):
        np.testing.assert_allclose(b, a, atol=1e-5)


def test_a_match_at_scale_two_finds_the_shift_in_image_pixels():
    # A textured pair shifted by 7 px: the disparity stays in the image's pixels, not the upsampled ones.
    rng = np.random.default_rng(2)
    texture = rng.integers(0, 256, (48, 96 + 7, 3), dtype=np.uint8)
    left, right = texture[:, :-7], texture[:, 7:]
    matcher = Matcher.from_folder(None, threads=2)
    result = matcher(left, right, MatchOptions(max_disparity=16, tower_scale=2))
    inner = result.disparity[8:-8, 16:-8]
    assert np.mean(np.abs(inner - 7) <= 0.5) > 0.95


def test_the_memory_plan_grows_with_the_tower_scale():
    manifest = load_manifest(default_model_dir())
    one, two = (plan_request(375, 1242, 192, manifest, scale=scale) for scale in (1, 2))
    assert two.volumes == one.volumes and two.images == one.images
    # 4x the pixels; at scale 2 the towers run in tiles whose halos overlap (adsm-rf17-int8: 4.008x).
    assert 3.5 * one.work_pixels < two.work_pixels <= 4.05 * one.work_pixels
    assert two.features > one.features and two.tower_work > one.tower_work
    assert Matcher.from_folder(None).plan(375, 1242, MatchOptions(tower_scale=2)).work_pixels == (
        plan_request(375, 1242, 128, manifest, scale=2).work_pixels)


@pytest.mark.parametrize("value", [0, MAX_TOWER_SCALE + 1, 1.5, True, "2"])
def test_tower_scale_out_of_range_is_refused(value):
    with pytest.raises(ValueError, match="tower_scale must be an integer"):
        MatchOptions(tower_scale=value)
