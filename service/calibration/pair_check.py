"""Is this a rectified left-right pair? A cheap, independent look before (or beside) the matcher.

A swapped pair (right image given as left) or an unrectified one still gives a clean-looking disparity
map, so the pair is checked on its own: both images are reduced to about ``TARGET_WIDTH`` pixels wide,
census-transformed (5x5, robust to exposure differences), and every pixel is matched over horizontal
shifts of both signs, ``dx`` in [-D, D], and vertical shifts ``dy`` in [-3, 3] (reduced pixels). From that:

- ``negative_share``: among textured pixels with a clear winner, the share whose best ``dx`` is
  negative. A left-right pair has disparities >= 0 (negative only where matching fails); a swapped
  pair's disparities are all negative.
- ``vertical_offset_px``: the ``dy`` (full-resolution pixels, sub-pixel parabola fit) that minimises
  the mean best cost, in the whole image and in each of 3x3 tiles; ``vertical_spread_px`` is the largest
  tile offset minus the smallest (a rotation or a scale difference between the views shows there).

Thresholds (``SWAPPED_SHARE``, ``VERTICAL_PX``) were set from measurements on Cones and on the project's
synthetic pairs, in docs/service.md ("Pair diagnostics"). It costs 0.05-0.15 s on these 2 cores.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from service.filtering.box import box_sum, local_std

TARGET_WIDTH = 200
MAX_DY_PX = 8  # full-resolution pixels of vertical offset searched up and down
SWAPPED_SHARE = 0.5
VERTICAL_PX = 1.25
MIN_TILES = 3  # tiles with a clear row-profile peak needed before a vertical offset is believed
LOW_VALID_SHARE = 0.5
_MIN_TEXTURE = 2.0  # grey levels of local standard deviation (reduced image) for a pixel to vote
_MIN_SIDE = 8  # reduced rows and columns below which a pair is not judged (census 5x5 + box 5x5)


@dataclasses.dataclass(frozen=True)
class PairCheck:
    """What :func:`check_pair` measured, and the warnings it implies."""

    negative_share: float  # share of voting pixels whose best horizontal shift is negative
    vertical_offset_px: float  # best vertical shift of the right view, full-resolution pixels
    vertical_spread_px: float  # largest minus smallest best vertical shift over 3x3 tiles
    tiles: int  # tiles whose row profiles gave a clear vertical offset
    voting_pixels: int
    scale: int  # reduction factor used

    def warnings(self, *, valid_share: float | None = None) -> list[str]:
        """One-line warnings (empty when the pair looks fine); ``valid_share`` from the matcher's check.
        The remedies are named as ``adsm predict``'s flags."""
        return [sentence for _, sentence in self.findings(valid_share=valid_share)]

    def findings(self, *, valid_share: float | None = None, calibration: str = "--calib",
                 disparity_range: str = "--max-disparity") -> list[tuple[str, str]]:
        """``(kind, sentence)`` of each warning, kind ``swapped``, ``unrectified`` or ``few-valid``;
        ``calibration`` and ``disparity_range`` name the remedies in the caller's words (the HTTP
        service says ``the calib file field`` and ``max_disparity``)."""
        found = []
        if self.voting_pixels > 0 and self.negative_share >= SWAPPED_SHARE:
            found.append(("swapped",
                f"the pair looks swapped: {self.negative_share:.0%} of textured pixels match best at a "
                "negative disparity (is LEFT the right camera's image?)"
            ))
        if abs(self.vertical_offset_px) >= VERTICAL_PX:
            found.append(("unrectified",
                "the pair does not look rectified: estimated vertical offset "
                f"{self.vertical_offset_px:+.1f} px (spread {self.vertical_spread_px:.1f} px); "
                f"rectify it first ({calibration})"
            ))
        if valid_share is not None and valid_share < LOW_VALID_SHARE:
            found.append(("few-valid",
                f"only {valid_share:.0%} of pixels passed the left-right check: the disparity map is mostly "
                f"filled in (wrong {disparity_range}, textureless scene, or not a rectified pair?)"
            ))
        return found

    def as_dict(self) -> dict[str, float | int]:
        return dataclasses.asdict(self)


def check_pair(left: np.ndarray, right: np.ndarray, *, max_disparity: int | None = None) -> PairCheck:
    """Measure a pair (uint8 HxWx3 or HxW each, same shape) for the signs of a swap or missing rectification.

    ``max_disparity`` (full-resolution pixels) bounds the horizontal search; default a quarter of the width.
    """
    if left.shape != right.shape:
        raise ValueError(f"left {left.shape} and right {right.shape} differ in shape")
    grey_left, grey_right = _grey(left), _grey(right)
    width = grey_left.shape[1]
    scale = max(1, int(np.ceil(width / TARGET_WIDTH)))
    small_left, small_right = _reduce(grey_left, scale), _reduce(grey_right, scale)
    rows, cols = small_left.shape
    if rows < _MIN_SIDE or cols < _MIN_SIDE:
        # Too few pixels left after the reduction (a strip such as 64 x 32768 becomes 0 rows): nothing to
        # judge, so nothing to warn about.
        return PairCheck(negative_share=0.0, vertical_offset_px=0.0, vertical_spread_px=0.0, tiles=0,
                         voting_pixels=0, scale=scale)
    limit = width // 4 if max_disparity is None else max_disparity
    reach = int(max(2, min(np.ceil(limit / scale), cols // 2 - 3)))
    census_left, census_right = _census(small_left), _census(small_right)
    texture = local_std(small_left, 2) >= _MIN_TEXTURE

    best_cost = np.full((rows, cols), np.inf, np.float32)
    best_dx = np.zeros((rows, cols), np.int16)
    for dx in range(-reach, reach + 1):
        moved = np.roll(census_right, dx, axis=1)  # right(x - dx)
        cost = box_sum(_popcount(census_left ^ moved).astype(np.float32), 2)
        better = cost < best_cost
        best_cost[better] = cost[better]
        best_dx[better] = dx
    inside = np.zeros((rows, cols), bool)  # only pixels whose every shift stayed inside (np.roll wraps)
    inside[2 : rows - 2, reach + 2 : cols - reach - 2] = True
    votes = inside & texture & (best_dx != 0)  # dx = 0 is both signs' boundary: no vote
    share = float((best_dx[votes] < 0).mean()) if votes.any() else 0.0
    positive = best_dx[votes & (best_dx > 0)]
    typical = int(np.median(positive)) * scale if positive.size else 0
    offsets = _tile_offsets(grey_left, grey_right, typical)
    offset = float(np.median(offsets)) if len(offsets) >= MIN_TILES else 0.0
    spread = float(max(offsets) - min(offsets)) if len(offsets) >= 2 else 0.0
    return PairCheck(
        negative_share=share,
        vertical_offset_px=offset,
        vertical_spread_px=spread,
        tiles=len(offsets),
        voting_pixels=int(votes.sum()),
        scale=scale,
    )


def _grey(image: np.ndarray) -> np.ndarray:
    image = np.asarray(image, dtype=np.float32)
    if image.ndim == 3:
        image = image[..., :3] @ np.array([0.299, 0.587, 0.114], np.float32)
    if image.ndim != 2:
        raise ValueError(f"an image must be HxW or HxWx3, got shape {image.shape}")
    return image


def _reduce(image: np.ndarray, scale: int) -> np.ndarray:
    if scale == 1:
        return image
    height, width = (image.shape[0] // scale) * scale, (image.shape[1] // scale) * scale
    blocks = image[:height, :width].reshape(height // scale, scale, width // scale, scale)
    return blocks.mean(axis=(1, 3))


def _census(image: np.ndarray) -> np.ndarray:
    padded = np.pad(image, 2, mode="edge")
    code = np.zeros(image.shape, np.uint32)
    height, width = image.shape
    for dy in range(5):
        for dx in range(5):
            if dy == 2 and dx == 2:
                continue
            code = (code << np.uint32(1)) | (padded[dy : dy + height, dx : dx + width] < image)
    return code


def _popcount(values: np.ndarray) -> np.ndarray:
    return np.bitwise_count(values)


def _parabola_argmin(values: np.ndarray) -> float:
    index = int(np.argmin(values))
    if 0 < index < len(values) - 1 and np.isfinite(values[index - 1 : index + 2]).all():
        below, here, above = values[index - 1], values[index], values[index + 1]
        curvature = below - 2 * here + above
        if curvature > 0:
            return index + 0.5 * (below - above) / curvature
    return float(index)


def _tile_offsets(left: np.ndarray, right: np.ndarray, disparity: int) -> list[float]:
    """Vertical shift of the right view in each of 3x3 tiles, from the tiles' row profiles.

    Averaging a tile along x keeps its horizontal edges and forgets horizontal shifts (disparity), so
    the row profiles of a left tile and of the right tile ``disparity`` pixels to its left differ by the
    vertical offset alone; it is the argmax of their correlation (sub-pixel parabola fit).
    """
    height, width = left.shape
    offsets = []
    for i in range(3):
        top, bottom = i * height // 3, (i + 1) * height // 3
        if bottom - top < 4 * MAX_DY_PX:
            continue
        for j in range(3):
            start, stop = j * width // 3, (j + 1) * width // 3
            shift = min(disparity, start)
            profile_left = np.diff(left[top:bottom, start:stop].mean(axis=1))
            profile_right = np.diff(right[:, start - shift : stop - shift].mean(axis=1))
            if profile_left.std() < 0.05:
                continue  # no horizontal structure in this tile
            scores = np.full(2 * MAX_DY_PX + 1, -np.inf)
            for index, dy in enumerate(range(-MAX_DY_PX, MAX_DY_PX + 1)):
                lo, hi = top + dy, bottom - 1 + dy
                if lo < 0 or hi > height - 1:
                    continue
                centred_left = profile_left - profile_left.mean()
                window = profile_right[lo:hi] - profile_right[lo:hi].mean()
                norms = np.linalg.norm(centred_left) * np.linalg.norm(window) + 1e-9
                scores[index] = np.dot(centred_left, window) / norms
            if np.isfinite(scores).sum() >= 3 and scores.max() > 0.3:
                offsets.append(_parabola_argmin(-scores) - MAX_DY_PX)
    return offsets
