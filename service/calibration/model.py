"""`StereoCalibration`: what depth and point clouds need from a rectified stereo rig.

Conventions (the same as Middlebury's and OpenCV's): the left camera's rectified frame, x right, y
down, z forward, metres. A pixel (u, v) of the left image with disparity d = u_left - u_right lies at

    z = focal_px * baseline_m / (d + doffs),   x = (u - cx) z / focal_px,   y = (v - cy) z / focal_y_px

``doffs`` is the x-difference of the principal points, ``cx_right - cx_left`` (Middlebury's ``doffs``;
0 for KITTI and for OpenCV's ``CALIB_ZERO_DISPARITY`` rectification).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from service.calibration.errors import CalibrationError


@dataclasses.dataclass(frozen=True)
class Rectification:
    """Raw (unrectified) rig: intrinsics, distortion and the rectifying rotations and projections.

    ``k1``/``k2``: 3x3 camera matrices, ``d1``/``d2``: OpenCV distortion coefficients, ``r1``/``r2``:
    3x3 rectifying rotations, ``p1``/``p2``: 3x4 rectified projections (all float64), as
    ``cv2.stereoRectify`` returns them; ``size``: (height, width) of the images they were computed for.
    Used by :mod:`service.calibration.rectify` to warp raw images before matching.
    """

    k1: np.ndarray
    d1: np.ndarray
    k2: np.ndarray
    d2: np.ndarray
    r1: np.ndarray
    r2: np.ndarray
    p1: np.ndarray
    p2: np.ndarray
    size: tuple[int, int]


@dataclasses.dataclass(frozen=True)
class StereoCalibration:
    """Rectified stereo geometry in the left camera's frame.

    >>> calib = StereoCalibration(focal_px=700.0, baseline_m=0.1, cx=320.0, cy=240.0)
    >>> calib.depth_of(70.0)  # metres at 70 px of disparity
    1.0
    >>> calib.q_matrix[3].tolist()  # OpenCV's Q: cv2.reprojectImageTo3D(disparity, calib.q_matrix)
    [0.0, 0.0, 10.0, 0.0]
    """

    focal_px: float
    baseline_m: float
    cx: float
    cy: float
    doffs: float = 0.0
    focal_y_px: float | None = None  # None: square pixels (= focal_px)
    size: tuple[int, int] | None = None  # (height, width) the calibration is for, when the file says
    rectification: Rectification | None = None  # set when the input images still need rectifying
    source: str = ""  # where it came from, for messages ("calib.txt (Middlebury)")

    def __post_init__(self) -> None:
        for name in ("focal_px", "baseline_m", "cx", "cy", "doffs"):
            value = getattr(self, name)
            if not isinstance(value, int | float) or not math.isfinite(value):
                raise CalibrationError(f"{self._where()}{name} must be a finite number, got {value!r}")
        if self.focal_px <= 0:
            raise CalibrationError(f"{self._where()}focal length must be positive, got {self.focal_px} px")
        if self.baseline_m <= 0:
            raise CalibrationError(
                f"{self._where()}baseline must be positive (right camera to the right of the left one), "
                f"got {self.baseline_m} m: are the cameras swapped?"
            )
        if self.focal_y_px is not None and not (math.isfinite(self.focal_y_px) and self.focal_y_px > 0):
            raise CalibrationError(f"{self._where()}focal_y_px must be positive, got {self.focal_y_px}")

    @property
    def fy(self) -> float:
        """Vertical focal length in pixels (``focal_px`` unless the file gave another)."""
        return self.focal_px if self.focal_y_px is None else self.focal_y_px

    @property
    def needs_rectification(self) -> bool:
        """True when the calibration describes raw images that must be rectified before matching."""
        return self.rectification is not None

    @property
    def q_matrix(self) -> np.ndarray:
        """4x4 float64 disparity-to-depth matrix in OpenCV's convention (``stereoRectify``'s ``Q``).

        ``[X Y Z W]^T = Q [u v d 1]^T`` and the point is ``(X/W, Y/W, Z/W)`` metres, so
        ``cv2.reprojectImageTo3D(disparity, calib.q_matrix)`` gives the same points as
        :func:`service.geometry.point_cloud` (for ``focal_y_px`` = ``focal_px``).
        """
        f, b = self.focal_px, self.baseline_m
        return np.array(
            [
                [1.0, 0.0, 0.0, -self.cx],
                [0.0, 1.0, 0.0, -self.cy],
                [0.0, 0.0, 0.0, f],
                [0.0, 0.0, 1.0 / b, self.doffs / b],
            ]
        )

    def depth_of(self, disparity: float) -> float:
        """Depth in metres of one disparity (``inf`` where ``d + doffs <= 0``)."""
        shifted = disparity + self.doffs
        return math.inf if shifted <= 0 else self.focal_px * self.baseline_m / shifted

    def scaled(self, factor: float) -> StereoCalibration:
        """The calibration of images resized by ``factor`` (e.g. 0.5 for half-size Middlebury files).

        Pixel quantities scale; the baseline does not. Pixel centres follow the usual convention
        (``cx' = (cx + 0.5) * factor - 0.5``).

        >>> StereoCalibration(focal_px=1000.0, baseline_m=0.2, cx=499.5, cy=99.5).scaled(0.5).cx
        249.5
        """
        if not factor > 0:
            raise CalibrationError(f"scale factor must be positive, got {factor}")
        if self.rectification is not None and factor != 1:
            raise CalibrationError(f"{self._where()}a raw (unrectified) calibration cannot be rescaled")
        size = None if self.size is None else (round(self.size[0] * factor), round(self.size[1] * factor))
        return dataclasses.replace(
            self,
            focal_px=self.focal_px * factor,
            focal_y_px=None if self.focal_y_px is None else self.focal_y_px * factor,
            cx=(self.cx + 0.5) * factor - 0.5,
            cy=(self.cy + 0.5) * factor - 0.5,
            doffs=self.doffs * factor,
            size=size,
        )

    def for_size(self, height: int, width: int) -> StereoCalibration:
        """The calibration of ``height`` x ``width`` images: itself when it names no size or this one,
        else :meth:`scaled` to it (Middlebury's full/half/quarter sizes) when the aspect ratio agrees
        within a pixel; any other size, or a raw rig's, is a :class:`CalibrationError`.

        >>> StereoCalibration(focal_px=1000.0, baseline_m=0.2, cx=499.5, cy=99.5, size=(200, 1000)
        ...                   ).for_size(100, 500).focal_px
        500.0
        """
        if self.size is None or self.size == (height, width):
            return self
        calibrated_height, calibrated_width = self.size
        factor = width / calibrated_width if calibrated_width > 0 and calibrated_height > 0 else 0.0
        if self.rectification is not None or factor <= 0 or abs(factor * calibrated_height - height) > 1.0:
            raise CalibrationError(f"{self._where()}calibrated for {calibrated_width}x{calibrated_height} "
                                   f"images, got {width}x{height}")
        return self.scaled(factor)

    @classmethod
    def from_q(cls, q: np.ndarray, *, source: str = "", size: tuple[int, int] | None = None
               ) -> StereoCalibration:
        """Read focal length, baseline, principal point and doffs back from an OpenCV ``Q`` matrix.

        >>> q = StereoCalibration(focal_px=700.0, baseline_m=0.1, cx=320.0, cy=240.0, doffs=2.0).q_matrix
        >>> StereoCalibration.from_q(q).doffs
        2.0
        """
        q = np.asarray(q, dtype=np.float64)
        where = f"{source}: " if source else ""
        if q.shape != (4, 4) or not np.isfinite(q).all():
            raise CalibrationError(f"{where}Q must be a finite 4x4 matrix, got shape {q.shape}")
        if q[3, 2] == 0:
            raise CalibrationError(f"{where}Q[3][2] = -1/Tx is 0: no baseline")
        # OpenCV: Q[3][2] = -1/Tx with Tx = -baseline for a horizontal rig (right camera at +x).
        baseline = 1.0 / q[3, 2]
        return cls(
            focal_px=float(q[2, 3]),
            baseline_m=float(baseline),
            cx=float(-q[0, 3]),
            cy=float(-q[1, 3]),
            doffs=float(q[3, 3] * baseline),
            size=size,
            source=source,
        )

    def _where(self) -> str:
        return f"{self.source}: " if self.source else ""
