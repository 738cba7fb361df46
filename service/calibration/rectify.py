"""Rectify a raw stereo pair with its calibration: OpenCV's ``initUndistortRectifyMap`` + ``remap``.

The maps are built once per image size and reused for every pair of a sequence (building them costs
about as much as a few remaps). Bilinear interpolation; pixels that map outside the raw image are black
(with ``alpha = 0`` rectification, which :mod:`service.calibration.opencv` uses, there are none).
"""

from __future__ import annotations

from types import ModuleType

import numpy as np

from service.calibration.errors import CalibrationError
from service.calibration.model import Rectification, StereoCalibration


class Rectifier:
    """Warps raw left/right images into the rectified frame of ``calibration``.

    >>> rectifier = Rectifier(calibration)             # a raw rig's file  # doctest: +SKIP
    >>> left, right = rectifier(raw_left, raw_right)   # images from its cameras  # doctest: +SKIP
    """

    def __init__(self, calibration: StereoCalibration) -> None:
        if calibration.rectification is None:
            raise CalibrationError(f"{calibration.source or 'calibration'}: describes a rectified rig; "
                                   "nothing to rectify")
        self.rectification: Rectification = calibration.rectification
        self._maps: tuple[tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]] | None = None

    def __call__(self, left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The rectified (left, right) images, same size and dtype as the raw ones."""
        import cv2

        size = self.rectification.size
        for name, image in (("left", left), ("right", right)):
            if image.shape[:2] != size:
                raise CalibrationError(
                    f"{name} image is {image.shape[1]}x{image.shape[0]} but the calibration is for "
                    f"{size[1]}x{size[0]}"
                )
        if self._maps is None:
            self._maps = self._build(cv2)
        (left_x, left_y), (right_x, right_y) = self._maps
        return (
            cv2.remap(left, left_x, left_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT),
            cv2.remap(right, right_x, right_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT),
        )

    def _build(self, cv2: ModuleType) -> tuple[tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]:
        r = self.rectification
        height, width = r.size
        left, right = (
            cv2.initUndistortRectifyMap(k, d, rotation, p, (width, height), cv2.CV_32FC1)
            for k, d, rotation, p in ((r.k1, r.d1, r.r1, r.p1), (r.k2, r.d2, r.r2, r.p2))
        )
        return left, right
