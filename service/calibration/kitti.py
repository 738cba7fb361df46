"""KITTI calibration: ``calib_cam_to_cam.txt`` (``P_rect_02``/``P_rect_03``) or a per-frame ``P2:``/``P3:``.

Both hold 3x4 rectified projection matrices ``P = K [I | t]`` of the colour cameras 2 (left) and 3
(right) in row-major order. With ``fx = P[0][0]``, ``P[0][3] = fx * t_x``, so the baseline is
``(P2[0][3] - P3[0][3]) / fx`` (0.54 m for the KITTI car) and ``doffs = P3[0][2] - P2[0][2]`` (0).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from service.calibration._text import matrix, numbers, read_text
from service.calibration.errors import CalibrationError
from service.calibration.model import StereoCalibration

_LAYOUT = "(12 numbers, row-major P = K [I | t])"


def looks_like_kitti(text: str) -> bool:
    """True when the text has a ``P_rect_0N:`` or ``PN:`` line."""
    heads = {line.split(":", 1)[0].strip() for line in text.splitlines() if ":" in line}
    return bool(heads & {"P_rect_02", "P_rect_00", "P2", "P0"})


def parse_kitti(text: str, *, source: str = "calib_cam_to_cam.txt", cameras: tuple[int, int] = (2, 3)
                ) -> StereoCalibration:
    """Parse a KITTI calibration text for the camera pair ``cameras`` (left, right; default colour 2, 3).

    >>> p2 = "P_rect_02: 721.5 0 609.6 44.86 0 721.5 172.9 0.2163 0 0 1 0.002746"
    >>> p3 = "P_rect_03: 721.5 0 609.6 -339.5 0 721.5 172.9 2.200 0 0 1 0.002730"
    >>> calib = parse_kitti(p2 + "\\n" + p3)
    >>> round(calib.baseline_m, 4), calib.cx
    (0.5327, 609.6)
    """
    fields: dict[str, str] = {}
    for line in text.splitlines():
        key, sep, value = line.partition(":")
        if sep:
            fields[key.strip()] = value
    left, right = (_projection(fields, camera, source) for camera in cameras)
    focal = float(left[0, 0])
    if focal <= 0:
        raise CalibrationError(f"{source}: P of camera {cameras[0]} has a non-positive fx = {focal}")
    if not np.isclose(right[0, 0], focal, rtol=1e-4):
        raise CalibrationError(
            f"{source}: cameras {cameras[0]} and {cameras[1]} have different fx ({focal} vs {right[0, 0]}): "
            "not a rectified pair"
        )
    if not np.isclose(left[1, 2], right[1, 2], atol=1e-3):
        raise CalibrationError(
            f"{source}: the cameras' cy differ ({left[1, 2]} vs {right[1, 2]}): not rectified"
        )
    size = None
    size_key = f"S_rect_{cameras[0]:02d}"
    if size_key in fields:
        width_height = numbers(fields[size_key], where=source, key=size_key)
        if len(width_height) == 2:
            size = (round(width_height[1]), round(width_height[0]))
    return StereoCalibration(
        focal_px=focal,
        focal_y_px=float(left[1, 1]) if left[1, 1] != focal else None,
        baseline_m=float((left[0, 3] - right[0, 3]) / focal),
        cx=float(left[0, 2]),
        cy=float(left[1, 2]),
        doffs=float(right[0, 2] - left[0, 2]),
        size=size,
        source=source,
    )


def read_kitti(path: str | Path, *, cameras: tuple[int, int] = (2, 3)) -> StereoCalibration:
    """Read a KITTI ``calib_cam_to_cam.txt`` or per-frame ``calib/NNNNNN.txt`` (see :func:`parse_kitti`)."""
    return parse_kitti(read_text(path), source=f"{Path(path).name} (KITTI)", cameras=cameras)


def _projection(fields: dict[str, str], camera: int, source: str) -> np.ndarray:
    for key in (f"P_rect_{camera:02d}", f"P{camera}"):
        if key in fields:
            return matrix(numbers(fields[key], where=source, key=key), 3, 4, where=source, key=key,
                          layout=_LAYOUT)
    raise CalibrationError(
        f"{source}: no 'P_rect_{camera:02d}:' or 'P{camera}:' line (not a KITTI calibration?)"
    )
