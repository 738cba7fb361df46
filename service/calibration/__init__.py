"""Stereo calibration: Middlebury, KITTI and OpenCV files -> one :class:`StereoCalibration`.

>>> import pathlib, tempfile
>>> from service.calibration import read_calibration
>>> path = pathlib.Path(tempfile.mkdtemp(), "calib.txt")   # a Middlebury calib.txt
>>> _ = path.write_text("cam0=[700 0 300; 0 700 200; 0 0 1]\\ncam1=[700 0 310; 0 700 200; 0 0 1]\\n"
...                     "baseline=100")
>>> calib = read_calibration(path)
>>> calib.focal_px, calib.baseline_m, calib.doffs
(700.0, 0.1, 10.0)

The format is told from the file: OpenCV by extension (.yml, .yaml, .xml, .json, .gz), otherwise
Middlebury (``cam0=`` line) or KITTI (``P_rect_02:`` / ``P2:`` lines). Every reader raises
:class:`CalibrationError` (a ``ValueError``) with one line naming the file and the problem.
"""

from __future__ import annotations

from pathlib import Path

from service.calibration._text import read_text
from service.calibration.errors import CalibrationError
from service.calibration.kitti import looks_like_kitti, parse_kitti, read_kitti
from service.calibration.middlebury import looks_like_middlebury, parse_middlebury, read_middlebury
from service.calibration.model import Rectification, StereoCalibration
from service.calibration.opencv import SUFFIXES as OPENCV_SUFFIXES
from service.calibration.opencv import UNITS, read_opencv

__all__ = [
    "UNITS",
    "CalibrationError",
    "Rectification",
    "StereoCalibration",
    "parse_kitti",
    "parse_middlebury",
    "read_calibration",
    "read_kitti",
    "read_middlebury",
    "read_opencv",
]


def read_calibration(path: str | Path, *, image_size: tuple[int, int] | None = None, units: str = "m",
                     rectified: bool = False) -> StereoCalibration:
    """Read any supported calibration file.

    ``image_size`` (height, width), ``units`` and ``rectified`` apply to OpenCV files only (see
    :func:`service.calibration.opencv.read_opencv`); Middlebury files are in millimetres and KITTI files
    in metres by definition.
    """
    path = Path(path)
    if path.suffix.lower() in OPENCV_SUFFIXES:
        return read_opencv(path, image_size=image_size, units=units, rectified=rectified)
    text = read_text(path)
    if looks_like_middlebury(text):
        return parse_middlebury(text, source=f"{path.name} (Middlebury)")
    if looks_like_kitti(text):
        return parse_kitti(text, source=f"{path.name} (KITTI)")
    raise CalibrationError(
        f"{path.name}: unknown calibration format; expected a Middlebury calib.txt (cam0=...), a KITTI "
        "calibration (P_rect_02: ...) or an OpenCV .yml/.yaml/.xml/.json file"
    )
