"""Memory model of one stereo request: peak bytes from H, W, D, channels, the towers' padding and tiles.

Terms (bytes; ``P = H * W``, ``C`` channels, ``halo`` = receptive field // 2):

- ``images``: the two decoded uint8 images, ``2 * 3 * P``;
- ``features``: both views' float32 feature maps, ``2 * 4 * C * P``, plus one tile's outputs and its
  two float32 input batches while the towers run (at a tower scale ``s > 1``, service/features/scale.py,
  those of the tile upsampled, ``s^2`` times its pixels, and its upsampled uint8 views);
- ``tower_work``: ONNX Runtime's work area for the largest tile, ``bytes_per_padded_pixel x (h + 2 halo)
  x (w + 2 halo)`` of its run, upsampled at a tower scale > 1 (service/features/tiles.py); the arena
  keeps it after the run, but never more than :data:`~service.features.tiles.TOWER_WORK_BYTES`, whatever
  the image's shape;
- ``volumes``: the raw and the aggregated int16 cost volume, ``4 * P * D`` (kept between requests at the
  largest size served, so never more than ``4 x ADSM_MAX_COST_CELLS``);
- ``results``: winners, disparity, validity, the filling's copies and the encoded answer (a point cloud
  is the largest), bounded by :data:`RESULT_BYTES_PER_PIXEL` ``x P``.

The service computes the plan from the image headers, before anything is decoded, and refuses a request
whose peak is over ``ADSM_MAX_REQUEST_BYTES`` or whose towers would compute over
:func:`tower_work_limit` padded pixels (a 1-row image computes 45 rows).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

from service.features.scale import upsampled_size
from service.features.tiles import TOWER_WORK_BYTES, Tile, halo_of, tower_plan, work_bytes_per_pixel

# Per pixel after the volumes: int32 left/right winners (8), float32 sub-pixel and filled disparity (8),
# validity and its copy (2), and the answer: a point cloud's int64 row/column indices (16), its float32
# x, y, z (12), 15-byte vertices and their encoding (30). Measured answers stay below this.
RESULT_BYTES_PER_PIXEL = 96
_FLOAT32 = 4
_COST_CELL = 2  # int16 (service.cost.COST_DTYPE)

# ADSM_MAX_REQUEST_BYTES's default, also the CLI's: every shipped model fits at the other defaults (1080p
# at 100 M cost cells: adsm-fast-int8 1.5 GiB, ncc-baseline 2.8 GiB; docs/service.md has the table).
DEFAULT_MAX_REQUEST_BYTES = 3 * 1024**3

# Padded pixels the towers may compute, relative to a square image at the pixel limit: an ordinary image
# computes 1.1-1.3x its pixels (padding and tile overlap), an image a few rows tall up to 45x, which held
# the single inference slot for minutes at the pixel limit (2 x 1050000: 100 s).
TOWER_WORK_FACTOR = 2.0


@dataclasses.dataclass(frozen=True)
class MemoryPlan:
    """Peak bytes of one request by term, and the tower tiles they assume."""

    height: int
    width: int
    disparities: int
    images: int
    features: int
    tower_work: int
    volumes: int
    results: int
    tiles: tuple[Tile, ...]
    work_pixels: int  # padded pixels the towers compute, over all tiles
    scale: int = 1  # the tower scale the tiles and the work are planned at (service/features/scale.py)

    @property
    def peak_bytes(self) -> int:
        return self.images + self.features + self.tower_work + self.volumes + self.results

    def describe(self) -> str:
        """One clause naming the terms in MiB, for error messages and logs."""
        terms = ", ".join(
            f"{name} {_mib(getattr(self, name))}"
            for name in ("images", "features", "tower_work", "volumes", "results")
        )
        return f"{_mib(self.peak_bytes)} ({terms}; {len(self.tiles)} tower tiles)"


def plan_request(height: int, width: int, disparities: int, manifest: dict[str, Any], *,
                 scale: int = 1) -> MemoryPlan:
    """The memory plan of matching an ``height x width`` pair over ``disparities`` with this model, its
    towers run at ``scale`` (service/features/scale.py)."""
    channels = int(manifest["channels"])
    halo = halo_of(manifest)
    per_pixel = work_bytes_per_pixel(manifest)
    tiles = tuple(tower_plan(height, width, manifest, scale=scale))
    largest = max(tiles, key=lambda tile: tile.padded_pixels(halo, scale))
    run_pixels = (upsampled_size(largest.run_bottom - largest.run_top, scale)
                  * upsampled_size(largest.run_right - largest.run_left, scale))
    pixels = height * width
    whole = 2 * _FLOAT32 * channels * pixels
    # One run's two float32 input batches, and its two outputs beside the whole maps unless they are the
    # whole maps (one tile at scale 1); upsampled, its two uint8 inputs and one view's float32 working copy.
    run_outputs = 0 if len(tiles) == 1 and scale == 1 else 2 * _FLOAT32 * channels * run_pixels
    upsampling = 0 if scale == 1 else (2 * 3 + _FLOAT32 * 3) * run_pixels
    return MemoryPlan(
        height=height, width=width, disparities=disparities,
        images=2 * 3 * pixels,
        features=whole + run_outputs + 2 * _FLOAT32 * 3 * run_pixels + upsampling,
        tower_work=per_pixel * largest.padded_pixels(halo, scale),
        volumes=2 * _COST_CELL * pixels * disparities,
        results=RESULT_BYTES_PER_PIXEL * pixels,
        tiles=tiles,
        work_pixels=sum(tile.padded_pixels(halo, scale) for tile in tiles),
        scale=scale,
    )


def tower_work_limit(manifest: dict[str, Any], *, max_pixels: int) -> int:
    """Most padded pixels one request's towers may compute: ``TOWER_WORK_FACTOR`` x the work of a square
    image of ``max_pixels``, padding included (so small limits still admit compact images)."""
    return int(TOWER_WORK_FACTOR * (math.isqrt(max_pixels) + 2 * halo_of(manifest)) ** 2)


def memory_bound(manifest: dict[str, Any], *, max_pixels: int, max_cost_cells: int) -> int:
    """Bytes above the idle process that any sequence of requests within the limits can hold at once.

    Each term at its cap: the kept cost volumes (``4 x max_cost_cells``), the kept ONNX Runtime arena
    (``TOWER_WORK_BYTES``) and one request's transient arrays at ``max_pixels`` (images, features, one
    tile's buffers, results). A request's own plan never exceeds it, so the per-request limit
    (``ADSM_MAX_REQUEST_BYTES``) can only lower what is reached, not raise it.
    """
    channels = int(manifest["channels"])
    tile_pixels = TOWER_WORK_BYTES // work_bytes_per_pixel(manifest)
    transient = (6 + 2 * _FLOAT32 * channels + RESULT_BYTES_PER_PIXEL) * max_pixels
    # A run's outputs and inputs are in its padded work area's pixels, bounded whatever the tower scale.
    tile_buffers = (2 * _FLOAT32 * (channels + 3) + 2 * 3 + _FLOAT32 * 3) * tile_pixels
    return 2 * _COST_CELL * max_cost_cells + TOWER_WORK_BYTES + transient + tile_buffers


def _mib(count: int) -> str:
    return f"{count / 2**20:.0f} MiB"
