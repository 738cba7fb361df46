"""A calibration file that arrives as bytes (an HTTP upload) rather than as a path.

The format is told as :func:`service.calibration.read_calibration` tells it, from the file name the client
gave and then from the content: OpenCV by extension (.yml, .yaml, .xml, .json, .gz) or by its own header
(``%YAML``, ``<?xml``, ``{``), otherwise Middlebury (``cam0=``) or KITTI (``P_rect_02:`` / ``P2:``).
OpenCV files go through ``cv2.FileStorage``, which reads files only: they are written to a private
temporary folder under the client's base name (sanitised), so that messages name the client's file.
"""

from __future__ import annotations

import os
import re
import tempfile
from pathlib import Path

from service.calibration._text import MAX_CALIBRATION_BYTES
from service.calibration.errors import CalibrationError
from service.calibration.kitti import looks_like_kitti, parse_kitti
from service.calibration.middlebury import looks_like_middlebury, parse_middlebury
from service.calibration.model import StereoCalibration
from service.calibration.opencv import SUFFIXES as OPENCV_SUFFIXES
from service.calibration.opencv import read_opencv

_OPENCV_HEADS = {"%YAML": ".yml", "<?xml": ".xml", "{": ".json"}
_UNSAFE = re.compile(r"[^A-Za-z0-9._-]+")


def parse_calibration(data: bytes, *, filename: str | None = None, image_size: tuple[int, int] | None = None,
                      units: str = "m", rectified: bool = False) -> StereoCalibration:
    """The calibration in ``data``; every problem is one :class:`CalibrationError` line naming the file.

    ``filename`` is the client's name for it (only its base name is used, to tell the format and in
    messages); ``image_size``, ``units`` and ``rectified`` are :func:`read_calibration`'s.

    >>> parse_calibration(b"cam0=[700 0 300; 0 700 200; 0 0 1]\\ncam1=[700 0 310; 0 700 200; 0 0 1]\\n"
    ...                   b"baseline=100", filename="calib.txt").doffs
    10.0
    """
    name = _UNSAFE.sub("_", Path(filename or "").name).strip("._")[:64] or "calib"
    if not data:
        raise CalibrationError(f"{name}: the calibration file is empty")
    if len(data) > MAX_CALIBRATION_BYTES:
        raise CalibrationError(f"{name}: {len(data)} bytes is too large for a calibration file "
                               f"(at most {MAX_CALIBRATION_BYTES})")
    if Path(name).suffix.lower() not in OPENCV_SUFFIXES:
        try:
            text = data.decode("utf-8-sig")
        except UnicodeDecodeError as error:
            raise CalibrationError(f"{name}: not a text file ({error.reason})") from None
        opencv = [ending for head, ending in _OPENCV_HEADS.items() if text.lstrip().startswith(head)]
        if not opencv:
            return _parse_text(text, name)
        name = f"{Path(name).stem or 'calib'}{opencv[0]}"
    with tempfile.TemporaryDirectory(prefix="adsm-calib-") as folder:
        path = Path(folder) / name
        path.write_bytes(data)
        try:
            return read_opencv(path, image_size=image_size, units=units, rectified=rectified)
        except CalibrationError as error:  # OpenCV's parse errors name the file by its path: not ours to show
            raise CalibrationError(str(error).replace(f"{folder}{os.sep}", "")) from None
        except (ValueError, TypeError, ArithmeticError, IndexError, KeyError) as error:  # hostile content
            reason = type(error).__name__
            raise CalibrationError(f"{name} (OpenCV): unusable calibration ({reason})") from None


def _parse_text(text: str, name: str) -> StereoCalibration:
    try:
        if looks_like_middlebury(text):
            return parse_middlebury(text, source=f"{name} (Middlebury)")
        if looks_like_kitti(text):
            return parse_kitti(text, source=f"{name} (KITTI)")
    except CalibrationError:
        raise
    except (ValueError, TypeError, ArithmeticError, IndexError, KeyError) as error:  # hostile content
        raise CalibrationError(f"{name}: unusable calibration ({type(error).__name__})") from None
    raise CalibrationError(
        f"{name}: unknown calibration format; expected a Middlebury calib.txt (cam0=...), a KITTI "
        "calibration (P_rect_02: ...) or an OpenCV .yml/.yaml/.xml/.json file"
    )
