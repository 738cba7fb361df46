"""What one match call takes and gives: :class:`MatchOptions` (per-call settings), :class:`StereoResult`
(its output) and :func:`colour_images` (the input check). Kept apart from service/matcher.py so that the
HTTP layer, the CLI and the evaluation can build and check options without the pipeline.

    >>> MatchOptions(max_disparity=64, p1=30, p2=360).sgm
    True
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from service.features.scale import MAX_TOWER_SCALE
from service.filling.border import SURFACE_RUN
from service.optimization import MAX_PENALTY
from service.validation import LR_CHECK_THRESHOLD

__all__ = ["MatchOptions", "StereoResult", "colour_images"]


@dataclasses.dataclass(frozen=True, kw_only=True)
class MatchOptions:
    """Per-call settings; ``None`` takes the model manifest's value. Raises ValueError when out of range."""

    max_disparity: int | None = None  # range size D; None -> manifest disparity.default_max, clipped to fit
    p1: float | None = None  # None -> manifest sgm.p1 (whole cost units, see cost.scale; <= MAX_PENALTY)
    p2: float | None = None  # None -> manifest sgm.p2
    # Each cost the lowest of its row neighbours' (x +- 1) at the same disparity before SGM: windows that
    # may shift off a depth edge (service.aggregation.shiftable_windows). None -> manifest
    # sgm.shiftable_windows (absent: off), set where it measurably helps that model (docs/training.md).
    shiftable_windows: bool | None = None
    # The towers run on the pair upsampled by this integer factor, so each feature sees 1/scale of its
    # receptive field in image pixels (service/features/scale.py): sharper depth edges on clean, densely
    # textured images, worse on noisy or compressed ones; costs ~scale^2 the towers' time and memory.
    tower_scale: int = 1
    sgm: bool = True
    adaptive_p2: bool = True  # lower SGM's jump penalty across image edges (service.optimization.aggregate)
    subpixel: bool = True
    lr_check: bool = True
    # Largest |DL - DR| (pixels) of a pixel the left-right check keeps: 0.75 keeps a right winner one step
    # off only where the sub-pixel disparity lies within 0.25 px of the half-way point, stricter than
    # MC-CNN's 1 (service/validation/inner_check.py).
    lr_check_threshold: float = LR_CHECK_THRESHOLD
    # The check's right winners from the right view's own SGM pass over its re-indexed costs (MC-CNN's
    # D^R), not read off the left view's aggregated volume, which carries the left frame's fattening
    # (service/cost/right_view.py); one more SGM pass. Needs sgm and lr_check.
    right_sgm: bool = True
    fill: bool = True  # fill the pixels the left-right check rejected (needs lr_check)
    # Rejected pixels filled leaning to the background (occlusions: the farthest of the first valid pixels
    # to the left; mismatches: the lower tercile of the rays), not by MC-CNN's rules, which copy the
    # fattened foreground into the holes: service/filling/rays.py.
    background_fill: bool = True
    # Give the left border band (match left of the right image) its surface's disparity. None -> manifest
    # filling.border_band (absent: on); off where the folder's own P1/P2 measure better without it, as
    # for towers whose right-view check already rejects the band's wrong matches (docs/training.md).
    border: bool | None = None
    # The band ends at a run of this many accepted pixels at one disparity matched inside the right image (a
    # farther surface the right camera saw); 0 carries every band to the border (service/filling/border.py).
    border_surface_run: int = SURFACE_RUN
    weighted_median: bool = True  # image-guided weighted median at depth edges (service.filtering)

    # --- Issue 12 (range offset, confidence): kept apart from the pipeline switches above. ---
    # The search range is [min_disparity, min_disparity + max_disparity), as OpenCV's minDisparity and
    # numDisparities; negative values search matches right of the left pixel (service/limits.py).
    min_disparity: int = 0
    # Also return StereoResult.confidence (service/validation/confidence.py): one more pass over the volume.
    confidence: bool = False

    def __post_init__(self) -> None:
        if isinstance(self.min_disparity, bool) or not isinstance(self.min_disparity, int | np.integer):
            raise ValueError(f"min_disparity must be an integer, got {self.min_disparity!r}")
        if self.max_disparity is not None:
            if isinstance(self.max_disparity, bool) or not isinstance(self.max_disparity, int | np.integer):
                raise ValueError(f"max_disparity must be an integer, got {self.max_disparity!r}")
            if self.max_disparity < 1:
                raise ValueError(f"max_disparity must be >= 1, got {self.max_disparity}")
        if (isinstance(self.tower_scale, bool) or not isinstance(self.tower_scale, int | np.integer)
                or not 1 <= self.tower_scale <= MAX_TOWER_SCALE):
            raise ValueError(f"tower_scale must be an integer in 1..{MAX_TOWER_SCALE}, "
                             f"got {self.tower_scale!r}")
        for name in ("p1", "p2"):
            value = getattr(self, name)
            if value is not None and (
                isinstance(value, bool) or not isinstance(value, int | float | np.number)
                or not math.isfinite(value) or not 0 <= value <= MAX_PENALTY
            ):
                raise ValueError(f"{name} must be a number in [0, {MAX_PENALTY:g}], got {value!r}")
        if (isinstance(self.lr_check_threshold, bool)
                or not isinstance(self.lr_check_threshold, int | float | np.number)
                or not math.isfinite(self.lr_check_threshold) or self.lr_check_threshold < 0):
            raise ValueError(f"lr_check_threshold must be a finite number of pixels >= 0, "
                             f"got {self.lr_check_threshold!r}")
        if (isinstance(self.border_surface_run, bool)
                or not isinstance(self.border_surface_run, int | np.integer) or self.border_surface_run < 0):
            raise ValueError(f"border_surface_run must be an integer number of pixels >= 0, "
                             f"got {self.border_surface_run!r}")
        for name in ("shiftable_windows", "border"):  # None: the model's setting
            value = getattr(self, name)
            if value is not None and not isinstance(value, bool | np.bool_):
                raise ValueError(f"{name} must be true, false or None, got {value!r}")
        for name in ("sgm", "adaptive_p2", "subpixel", "lr_check", "right_sgm", "fill", "background_fill",
                     "weighted_median", "confidence"):
            if not isinstance(getattr(self, name), bool | np.bool_):
                raise ValueError(f"{name} must be true or false, got {getattr(self, name)!r}")


@dataclasses.dataclass(frozen=True)
class StereoResult:
    disparity: np.ndarray  # float32 HxW, NaN where invalid and not filled
    validity: np.ndarray  # uint8 HxW, Validity codes
    timings: dict[str, float]  # seconds per stage, in pipeline order, then "total"
    confidence: np.ndarray | None = None  # float32 HxW in [0, 1] with MatchOptions(confidence=True)


def colour_images(left: Any, right: Any) -> tuple[np.ndarray, np.ndarray]:
    """Both images as uint8 (H, W, 3); grey (H, W) or (H, W, 1) arrays are expanded to three channels."""
    images = []
    for side, image in (("left", left), ("right", right)):
        expected = f"{side} image must be a uint8 array of shape (H, W, 3), or (H, W) for grey"
        if not isinstance(image, np.ndarray):
            raise ValueError(f"{expected}, got {type(image).__name__}")
        grey = image.ndim == 2 or (image.ndim == 3 and image.shape[2] == 1)
        if image.dtype != np.uint8 or not (grey or (image.ndim == 3 and image.shape[2] == 3)):
            hint = " (scale 16-bit samples to 0..255 first: service.io.read_image does)" if (
                image.dtype == np.uint16) else ""
            raise ValueError(f"{expected}, got {image.dtype} {image.shape}{hint}")
        if image.shape[0] < 1 or image.shape[1] < 1:
            raise ValueError(f"{side} image is empty: shape {image.shape}")
        if grey:
            image = np.repeat(image.reshape(*image.shape[:2], 1), 3, axis=2)
        images.append(image)
    left, right = images
    if left.shape != right.shape:
        raise ValueError(f"left and right images differ in size: {left.shape[:2]} vs {right.shape[:2]}")
    return left, right
