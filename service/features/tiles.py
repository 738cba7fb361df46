"""Tower tiles: which rectangles of an image the ONNX towers run on, so that one run's memory is bounded.

Why tiles: ONNX Runtime keeps every intermediate tensor of a run in its arena, and the graphs pad the
image inside (``halo`` pixels on every side), so one run's work area is ``(h + 2 halo) x (w + 2 halo)``
padded pixels, not ``h x w``. Row strips alone cannot bound it: an 8 x 262144 image is one strip of
52 x 262188 padded pixels (6.5x its own size; 1.5 GB per 32 Ki columns with adsm-fast-int8). Tiles
in both directions, each with ``halo`` real pixels of overlap on every side that is not an image edge,
keep every run under :data:`TOWER_WORK_BYTES` for every aspect ratio, and give exactly the features of
the whole image (the graph's edge padding applies only at the image's own edges).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from service.features.protocol import Towers
from service.features.scale import scaled_halo, upsample, upsampled_size

# Bytes of ONNX Runtime work area per padded pixel of one tower run, by precision: a bound measured on
# every shipped model (tests/service/test_memory.py::test_tower_work_model_bounds_every_shipped_model), not
# derived from the graph. int8 QDQ convs im2col their uint8 input in blocks, so their work grows with width
# and kernel size: the bound is a base plus channels x receptive field / 2. fp32 convs need less, and a
# strip of 2 rows needed 412 with adsm-fast (test_thin_image_peak_stays_within_its_plan), so their base is
# 256. Measured per padded pixel of the largest run, above the run's inputs and outputs, at 64 x 4096 /
# KITTI size / 8 x 32768 (2026-11-29, each int8 conv quantised with its ReLU; runs/s39/int8work.py then):
# adsm-paper-int8 1237 / 1433 / 1208 (bound 1824), adsm-fast-int8 365 / 283 / 409 (656), adsm-rf11-int8
# 385 / 299 / 351 (560), adsm-paper 565 / 336 / 489 (768), adsm-fast 361 / 166 / 256 (512); and
# 2026-12-01, one whole run at 64 x 4096 / KITTI size: adsm-rf17-int8 436 / 454 (792), adsm-rf17 303 / 275
# (640). Until then the int8 bound was 1024 + 8 C, set by the 64-channel graph: it split adsm-rf17-int8's
# KITTI-size run in two, 0.57 s against 0.44 for the whole run (docs/training.md, "17-8conv at four
# times the CPU steps").
_FP32_WORK_BASE = 256
_FP32_WORK_PER_CHANNEL = 8
_INT8_WORK_BASE = 384
_INT8_WORK_PER_CHANNEL_AND_FIELD_PX = 0.5
# Graphs with adaptive support (manifest onnx.adaptive_support) hold each 3x3 conv's nine weighted taps and
# their concatenation, 2 x 9 x 4 bytes per channel, beside the plain graph's work: an 11-5conv folder of
# 32 channels ran out of a plain graph's budget on Motorcycle (thirty-fourth session).
_ADAPTIVE_WORK_PER_CHANNEL = 2 * 9 * 4

# Largest work area of one tower run. 640 MiB lets every shipped folder but adsm-paper-int8 run a KITTI-size
# image (375 x 1242) whole and adsm-paper-int8 in 2 strips, as the former row-strip budget did, while a
# 1080p image goes in tiles instead of two 1 Mpx strips (~1 GB of arena).
TOWER_WORK_BYTES = 640 * 1024 * 1024


@dataclasses.dataclass(frozen=True)
class Tile:
    """One tower run: rows/columns ``run_*`` go in, rows/columns ``keep_*`` of its output are kept."""

    run_top: int
    run_bottom: int
    run_left: int
    run_right: int
    keep_top: int
    keep_bottom: int
    keep_left: int
    keep_right: int

    def padded_pixels(self, halo: int, scale: int = 1) -> int:
        """The run's work area inside the graph, which pads ``halo`` pixels on every side of the run
        upsampled by ``scale`` (service/features/scale.py)."""
        return ((upsampled_size(self.run_bottom - self.run_top, scale) + 2 * halo)
                * (upsampled_size(self.run_right - self.run_left, scale) + 2 * halo))


def work_bytes_per_pixel(manifest: dict[str, Any]) -> int:
    """Bound on ONNX Runtime's work area per padded pixel of one tower run of this model."""
    onnx = manifest.get("onnx", {})
    channels = int(manifest["channels"])
    if str(onnx.get("precision", "fp32")) == "fp32":
        work = _FP32_WORK_BASE + _FP32_WORK_PER_CHANNEL * channels
    else:  # int8, and any precision not listed
        field = int(manifest["receptive_field"])
        work = _INT8_WORK_BASE + math.ceil(_INT8_WORK_PER_CHANNEL_AND_FIELD_PX * channels * field)
    if onnx.get("adaptive_support", False):
        work += _ADAPTIVE_WORK_PER_CHANNEL * channels
    return work


def halo_of(manifest: dict[str, Any]) -> int:
    """Pixels of context each side of a feature vector: half the receptive field."""
    return int(manifest["receptive_field"]) // 2


def _spans(length: int, count: int, halo: int) -> list[tuple[int, int, int, int]]:
    """``count`` equal cores covering ``length``; every run has the same length (core + 2 halo).

    Equal runs matter for memory: ONNX Runtime's arena reuses the chunks of a run of the same shape,
    while runs of a few different shapes (an edge tile is ``halo`` shorter) fragment it to about twice
    one run's size (1080p in 5 tiles: 1067 MiB of arena instead of ~550). An edge run therefore takes
    ``halo`` more pixels from the interior: extra context, the same features.
    """
    core = -(-length // count)
    run = min(core + 2 * halo, length) if count > 1 else length
    spans = []
    for keep_start in range(0, length, core):
        keep_end = min(keep_start + core, length)
        run_start = min(max(keep_start - halo, 0), length - run)
        spans.append((run_start, run_start + run, keep_start, keep_end))
    return spans


def _run_length(core: int, length: int, halo: int) -> int:
    # An interior core carries halo context on both sides; never more than the image itself.
    return min(core + 2 * halo, length)


def tower_tiles(height: int, width: int, halo: int, *, budget_pixels: int) -> list[Tile]:
    """Tiles covering ``height x width`` whose padded work area is at most ``budget_pixels`` each.

    Whole rows are preferred (no column overlap), then the column count with the least total work.
    The budget is raised to the smallest feasible tile (1 x 1 core) when it is below that.
    """
    if height < 1 or width < 1:
        raise ValueError(f"image must be at least 1 x 1, got {height} x {width}")
    budget = max(budget_pixels, (1 + 4 * halo) ** 2)
    if (height + 2 * halo) * (width + 2 * halo) <= budget:
        return [Tile(0, height, 0, width, 0, height, 0, width)]
    best: tuple[int, int, int] | None = None  # (work, rows, columns)
    columns = 1
    while columns <= width:
        run_width = _run_length(-(-width // columns), width, halo) + 2 * halo
        max_run_rows = budget // run_width - 2 * halo  # the tallest run of this width that fits
        if max_run_rows >= height:
            rows = 1
        elif max_run_rows - 2 * halo >= 1:
            rows = -(-height // (max_run_rows - 2 * halo))
        else:
            rows = 0  # too wide for even one row of core: more columns
        if rows:
            run_height = _run_length(-(-height // rows), height, halo) + 2 * halo
            work = rows * columns * run_height * run_width
            if best is None or work < best[0]:
                best = (work, rows, columns)
            elif work > 2 * best[0]:
                break  # more columns only add overlap from here
        if columns == width:
            break
        # Every count up to 64, then 5 % steps (a 2 Mpx row needs ~100-400), ending at 1-pixel cores.
        columns = min(columns + 1 if columns < 64 else math.ceil(columns * 1.05), width)
    assert best is not None  # columns == width gives 1-pixel cores, which the raised budget always fits
    _, rows, columns = best
    return [
        Tile(rt, rb, cl, cr, kt, kb, kl, kr)
        for rt, rb, kt, kb in _spans(height, rows, halo)
        for cl, cr, kl, kr in _spans(width, columns, halo)
    ]


def tower_plan(height: int, width: int, manifest: dict[str, Any], *, scale: int = 1) -> list[Tile]:
    """The tiles the towers run on for an ``height x width`` pair at this tower scale
    (service/features/scale.py): tiles of the image whose upsampled runs each fit the work budget."""
    budget = TOWER_WORK_BYTES // work_bytes_per_pixel(manifest) // scale**2
    return tower_tiles(height, width, scaled_halo(halo_of(manifest), scale), budget_pixels=budget)


def tiled_features(towers: Towers, left: np.ndarray, right: np.ndarray, *,
                   scale: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Features [C, H, W] of both views, in tiles when one tower run would exceed :data:`TOWER_WORK_BYTES`
    (the same features as one run on the whole pair), the towers run on each tile upsampled by ``scale``."""
    manifest = towers.manifest
    height, width = left.shape[:2]
    tiles = tower_plan(height, width, manifest, scale=scale)
    if len(tiles) == 1:
        return _run(towers, left, right, scale)
    channels = int(manifest["channels"])
    features = (np.empty((channels, height, width), np.float32),
                np.empty((channels, height, width), np.float32))
    for tile in tiles:
        rows, columns = slice(tile.run_top, tile.run_bottom), slice(tile.run_left, tile.run_right)
        part = _run(towers, left[rows, columns], right[rows, columns], scale)
        keep_rows = slice(tile.keep_top - tile.run_top, tile.keep_bottom - tile.run_top)
        keep_columns = slice(tile.keep_left - tile.run_left, tile.keep_right - tile.run_left)
        for whole, piece in zip(features, part, strict=True):
            whole[:, tile.keep_top:tile.keep_bottom, tile.keep_left:tile.keep_right] = piece[:, keep_rows,
                                                                                              keep_columns]
        del part
    return features


def _run(towers: Towers, left: np.ndarray, right: np.ndarray, scale: int) -> tuple[np.ndarray, np.ndarray]:
    """One tower run on the pair upsampled by ``scale``, its features kept at the pair's own pixels."""
    if scale == 1:
        return towers(left, right)
    left_features, right_features = towers(upsample(left, scale), upsample(right, scale))
    return (np.ascontiguousarray(left_features[:, ::scale, ::scale]),
            np.ascontiguousarray(right_features[:, ::scale, ::scale]))
