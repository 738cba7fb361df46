"""What a stereo dataset's scenes and cameras are like: the figures that decide which matching window wins.

On the synthetic validation split a larger window wins; on real photographs such as Cones a smaller one
does (docs/training.md, issue 11). Three figures per dataset tell how a dataset differs from the split,
each over its ground-truth pixels (``adsm stats``):

- ``depth_edges``: % within ``EDGE_REACH`` px of a disparity jump (:func:`breakdown.jump_distance`),
  where a large window fattens the nearer surface; a jump counts only between two known neighbours, so
  on sparse ground truth (KITTI's LiDAR points) the figure is a lower bound;
- ``texture``: the 3x3 standard deviation of the left view's grey level (0-255): median and % below
  ``FLAT`` and ``WEAK`` grey levels, where a small window has too little signal to match;
- ``residual``: ``1 - ZNCC`` of 3x3 windows at the *true* match (the right view sampled at ``x - d``,
  linear in x), median over the textured pixels whose match lies inside the right image: what noise,
  blur, compression and the views' photometric differences leave of a perfect match (0: identical).

    >>> import numpy as np
    >>> rng = np.random.default_rng(0)
    >>> right = rng.integers(0, 256, (40, 60, 3), dtype=np.uint8)
    >>> left = np.roll(right, 4, axis=1)                     # every pixel at disparity 4
    >>> truth = np.full((40, 60), 4.0, np.float32)
    >>> figures = SceneStatistics().add(left, right, truth)
    >>> figures["depth_edges"], figures["residual_median"]
    (0.0, 0.0)

NumPy only, like the metrics, so that training can use it without the runtime.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from service.filtering.box import box_sum, local_std

from .breakdown import jump_distance

EDGE_REACH = 3          # px from a disparity jump that count as "at a depth edge"
FLAT, WEAK = 2.0, 4.0   # grey levels of 3x3 standard deviation: flat, weak texture
TEXTURE_BINS = np.linspace(0.0, 128.0, 2561)     # 0.05 grey level: medians exact to the printed digits
RESIDUAL_BINS = np.linspace(0.0, 2.0, 4001)      # 1 - ZNCC lies in [0, 2]


def grey(image: np.ndarray) -> np.ndarray:
    """Grey level (0-255, float64) of an HxWx3 or HxW image: the channels' mean, as the runtime's guide."""
    image = np.asarray(image, dtype=np.float64)
    return image.mean(axis=2) if image.ndim == 3 else image


def match_residual(left: np.ndarray, right: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """``1 - ZNCC`` of each left pixel's 3x3 window and the right view's at ``x - truth`` (NaN where unknown).

    NaN where a window pixel's truth is unknown or its match falls outside the right image, or where either
    window is flatter than ``FLAT`` grey levels (there the correlation measures noise, not the match).
    """
    grey_left, grey_right = grey(left), grey(right)
    height, width = grey_left.shape
    known = np.isfinite(truth)
    position = np.arange(width)[None, :] - np.where(known, truth, 0.0)
    inside = known & (position >= 0) & (position <= width - 1)
    column = np.clip(position, 0, width - 1)
    low = np.clip(np.floor(column), 0, max(width - 2, 0)).astype(np.int64)
    high = np.minimum(low + 1, width - 1)
    weight = column - low
    rows = np.arange(height)[:, None]
    warped = (1 - weight) * grey_right[rows, low] + weight * grey_right[rows, high]
    mean_left, mean_warped = box_sum(grey_left, 1) / 9, box_sum(warped, 1) / 9
    covariance = box_sum(grey_left * warped, 1) / 9 - mean_left * mean_warped
    spread_left, spread_warped = local_std(grey_left, 1), local_std(warped, 1)
    textured = (spread_left >= FLAT) & (spread_warped >= FLAT)
    residual = np.full((height, width), np.nan)
    # The whole window's matches inside the right image, not only the centre's (clipping would mismatch).
    counted = (box_sum(inside.astype(np.float64), 1) > 8.5) & textured
    # Clipped: rounding can put a perfect match a hair below 0.
    residual[counted] = np.clip(1.0 - covariance[counted] / (spread_left[counted] * spread_warped[counted]),
                                0.0, 2.0)
    return residual


class SceneStatistics:
    """Accumulates the three figures over a dataset's pairs; :meth:`add` returns one pair's figures."""

    def __init__(self) -> None:
        self.pixels = 0
        self.at_edges = 0
        self.texture = np.zeros(len(TEXTURE_BINS) - 1, np.int64)
        self.residual = np.zeros(len(RESIDUAL_BINS) - 1, np.int64)

    def add(self, left: np.ndarray, right: np.ndarray, truth: np.ndarray) -> dict[str, float | int | None]:
        known = np.isfinite(truth)
        at_edges = int((known & (jump_distance(truth) <= EDGE_REACH)).sum())
        texture = np.histogram(np.clip(local_std(grey(left), 1)[known], 0, TEXTURE_BINS[-1]), TEXTURE_BINS)[0]
        residual = match_residual(left, right, truth)
        residual = np.histogram(residual[np.isfinite(residual)], RESIDUAL_BINS)[0]
        self.pixels += int(known.sum())
        self.at_edges += at_edges
        self.texture += texture
        self.residual += residual
        return _figures(int(known.sum()), at_edges, texture, residual)

    def summary(self) -> dict[str, float | int | None]:
        """The dataset's figures (None where no pixel was counted)."""
        return _figures(self.pixels, self.at_edges, self.texture, self.residual)


def _figures(pixels: int, at_edges: int, texture: np.ndarray, residual: np.ndarray) -> dict[str, Any]:
    def percent(count: float) -> float | None:
        return round(100.0 * count / pixels, 2) if pixels else None

    flat = texture[: np.searchsorted(TEXTURE_BINS, FLAT)].sum()
    weak = texture[: np.searchsorted(TEXTURE_BINS, WEAK)].sum()
    return {
        "pixels": pixels,
        "depth_edges": percent(at_edges),
        "texture_median": _median(texture, TEXTURE_BINS, 2),
        "texture_flat": percent(flat),
        "texture_weak": percent(weak),
        "residual_median": _median(residual, RESIDUAL_BINS, 3),
        "residual_pixels": int(residual.sum()),
    }


def _median(counts: np.ndarray, bins: np.ndarray, digits: int) -> float | None:
    """The lower edge of the bin holding the middle value (bins are finer than the printed digits)."""
    total = int(counts.sum())
    if not total:
        return None
    index = int(np.searchsorted(np.cumsum(counts), (total + 1) // 2))
    return round(float(bins[index]), digits)
