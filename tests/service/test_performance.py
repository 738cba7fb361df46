"""Speed- and memory-driven code paths (issues 6, 15): tower tiles, the shared ORT arena, warm-up coverage.

Each path must give the same answer as the simple one it replaces; speed itself is measured by
``python -m bench suite``, not here.
"""

from __future__ import annotations

import numpy as np
import pytest

from service.features import FeatureTowers, default_model_dir, load_manifest
from service.features import tiles as tiles_module
from service.features.tiles import (
    TOWER_WORK_BYTES,
    halo_of,
    tiled_features,
    tower_tiles,
    work_bytes_per_pixel,
)
from service.matcher import Matcher, MatchOptions
from tests.helpers import ROOT


@pytest.mark.parametrize(
    ("height", "width", "halo"),
    [(375, 1242, 18), (1, 5, 4), (50, 20000, 4), (97, 3000, 0), (8, 262144, 22), (2100, 1, 22), (3, 700, 22)],
)
def test_tower_tiles_cover_every_pixel_once_with_halo(height, width, halo):
    budget = 20_000
    tiles = tower_tiles(height, width, halo, budget_pixels=budget)
    kept = np.zeros((height, width), np.int8)
    shapes = set()
    for tile in tiles:
        kept[tile.keep_top:tile.keep_bottom, tile.keep_left:tile.keep_right] += 1
        assert 0 <= tile.run_top <= tile.keep_top < tile.keep_bottom <= tile.run_bottom <= height
        assert 0 <= tile.run_left <= tile.keep_left < tile.keep_right <= tile.run_right <= width
        # Every kept pixel is `halo` inside its run, unless the run's edge is the image's edge.
        assert tile.keep_top - tile.run_top >= halo or tile.run_top == 0
        assert tile.run_bottom - tile.keep_bottom >= halo or tile.run_bottom == height
        assert tile.keep_left - tile.run_left >= halo or tile.run_left == 0
        assert tile.run_right - tile.keep_right >= halo or tile.run_right == width
        assert tile.padded_pixels(halo) <= max(budget, (1 + 4 * halo) ** 2)
        shapes.add((tile.run_bottom - tile.run_top, tile.run_right - tile.run_left))
    assert (kept == 1).all()
    assert len(shapes) == 1  # equal runs: ONNX Runtime's arena reuses one run's chunks


def test_tile_budget_follows_the_models_work_per_pixel():
    # KITTI size: the default model's towers run whole, adsm-paper-int8's in 2 strips (1.3x the work).
    for name, count in (("adsm-fast-int8", 1), ("adsm-paper-int8", 2)):
        manifest = load_manifest(default_model_dir().parent / name)
        budget = TOWER_WORK_BYTES // work_bytes_per_pixel(manifest)
        assert len(tower_tiles(375, 1242, halo_of(manifest), budget_pixels=budget)) == count


@pytest.mark.parametrize("model", ["ncc-baseline", "default"])
def test_tiled_features_equal_whole_image_features(monkeypatch, model):
    folder = None if model == "default" else default_model_dir().parent / model
    matcher = Matcher.from_folder(folder, threads=2)
    halo = halo_of(matcher.manifest)
    height, width = 3 * (2 * halo + 1) + 3, 4 * (2 * halo + 1) + 5
    rng = np.random.default_rng(3)
    left, right = (rng.integers(0, 256, (height, width, 3), dtype=np.uint8) for _ in range(2))
    whole = matcher.towers(left, right)
    per_pixel = tiles_module.work_bytes_per_pixel(matcher.manifest)
    budget = 2 * (1 + 4 * halo) ** 2  # small tiles, with cores of a few pixels
    monkeypatch.setattr(tiles_module, "TOWER_WORK_BYTES", per_pixel * budget)
    tiles = tower_tiles(height, width, halo, budget_pixels=budget)
    assert len({tile.run_top for tile in tiles}) > 2 and len({tile.run_left for tile in tiles}) > 2
    tiled = tiled_features(matcher.towers, left, right)
    for a, b in zip(whole, tiled, strict=True):
        np.testing.assert_allclose(b, a, atol=1e-5)
    result = matcher(left, right, MatchOptions(max_disparity=16))
    monkeypatch.setattr(tiles_module, "TOWER_WORK_BYTES", 10**15)
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


# Run in a fresh process: in the test process other tests have compiled kernels already, and a warm-up
# that compiled nothing would pass unseen. Prints {kernel: specialisations} before warm-up, after it, and
# after requests with each switch of MatchOptions flipped (and a few combinations), at a size the warm-up
# never saw.
_WARMUP_PROBE = """
import dataclasses, json, sys
import numba
import numpy as np
from service.matcher import Matcher, MatchOptions

def specialisations():
    return {f"{name}.{attr}": len(value.signatures)
            for name, module in list(sys.modules.items()) if name.startswith("service.") and module
            for attr, value in vars(module).items() if isinstance(value, numba.core.registry.CPUDispatcher)}

matcher = Matcher.from_folder(threads=2)
before = specialisations()
matcher.warmup()
warm = specialisations()
rng = np.random.default_rng(5)
left, right = (rng.integers(0, 256, (37, 53, 3), dtype=np.uint8) for _ in range(2))
switches = [field.name for field in dataclasses.fields(MatchOptions) if isinstance(field.default, bool)]
every = [MatchOptions(max_disparity=12), MatchOptions(sgm=False, subpixel=False),
         MatchOptions(lr_check=False, fill=False), MatchOptions(fill=False, p1=0, p2=0),
         MatchOptions(min_disparity=-3, max_disparity=9), MatchOptions(shiftable_windows=True)]
every += [MatchOptions(**{name: not getattr(MatchOptions(), name)}) for name in switches]  # each flipped
for options in every:
    matcher(left, right, options)
print(json.dumps([before, warm, specialisations()]))
"""


def test_warmup_compiles_every_kernel_of_the_request_path():
    """Matcher.warmup() compiles (or loads) the kernels, and no switch or image size compiles another."""
    import json
    import os
    import subprocess
    import sys

    root = ROOT
    done = subprocess.run([sys.executable, "-c", _WARMUP_PROBE], capture_output=True, text=True, timeout=600,
                          cwd=root, env={**os.environ, "PYTHONPATH": str(root)})
    assert done.returncode == 0, done.stderr[-3000:]
    before, warm, served = json.loads(done.stdout.splitlines()[-1])
    assert sum(before.values()) == 0, "kernels compiled before warm-up: the probe cannot tell"
    assert sum(warm.values()) >= 10, f"warm-up compiled only {warm}"
    compiled_later = {name: (warm[name], count) for name, count in served.items() if count != warm[name]}
    assert compiled_later == {}, f"compiled on the request path after warm-up: {compiled_later}"
