"""One stereo pair with ground truth, the unit every dataset reader and the generator produce."""

from __future__ import annotations

import dataclasses

import numpy as np


@dataclasses.dataclass(frozen=True, eq=False)
class StereoSample:
    """A rectified pair and the disparity of its left view.

    ``disparity`` is float32 (H, W) with NaN where the ground truth is unknown; ``nonoccluded`` is a bool
    mask of the pixels visible in both views when the dataset tells (None otherwise);
    ``max_disparity`` is the search range the dataset recommends (None: the caller's choice).
    """

    name: str
    left: np.ndarray
    right: np.ndarray
    disparity: np.ndarray
    nonoccluded: np.ndarray | None = None
    max_disparity: int | None = None

    def __post_init__(self) -> None:
        shape = self.left.shape
        if self.left.dtype != np.uint8 or len(shape) != 3 or shape[2] != 3:
            raise ValueError(f"{self.name}: left must be uint8 (H, W, 3), got {self.left.dtype} {shape}")
        if self.right.shape != shape or self.right.dtype != np.uint8:
            raise ValueError(f"{self.name}: right {self.right.shape} does not match left {shape}")
        if self.disparity.shape != shape[:2] or self.disparity.dtype != np.float32:
            raise ValueError(f"{self.name}: disparity must be float32 {shape[:2]}, "
                             f"got {self.disparity.dtype} {self.disparity.shape}")
        if self.nonoccluded is not None and (self.nonoccluded.shape != shape[:2]
                                             or self.nonoccluded.dtype != np.bool_):
            raise ValueError(f"{self.name}: nonoccluded must be a bool {shape[:2]} mask")

    @property
    def valid(self) -> np.ndarray:
        """Pixels with known ground truth."""
        return np.isfinite(self.disparity)
