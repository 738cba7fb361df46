"""Middlebury ``calib.txt`` (2005-2021 stereo sets): ``cam0``, ``cam1``, ``doffs``, ``baseline`` in mm.

A file looks like::

    cam0=[3979.911 0 1244.772; 0 3979.911 1019.507; 0 0 1]
    cam1=[3979.911 0 1369.115; 0 3979.911 1019.507; 0 0 1]
    doffs=124.343
    baseline=193.001
    width=2964
    height=1988
    ndisp=270

and gives ``Z = baseline * f / (d + doffs)`` (Middlebury's own formula, in mm; here in metres).
"""

from __future__ import annotations

from pathlib import Path

from service.calibration._text import matrix, numbers, read_text
from service.calibration.errors import CalibrationError
from service.calibration.model import StereoCalibration

_LAYOUT = "[fx 0 cx; 0 fy cy; 0 0 1]"
_MM_PER_M = 1000.0


def looks_like_middlebury(text: str) -> bool:
    """True when the text has Middlebury's ``cam0=`` line."""
    return any(line.strip().startswith("cam0=") for line in text.splitlines())


def parse_middlebury(text: str, *, source: str = "calib.txt") -> StereoCalibration:
    """Parse the text of a Middlebury ``calib.txt``.

    >>> text = "cam0=[700 0 300; 0 700 200; 0 0 1]\\ncam1=[700 0 310; 0 700 200; 0 0 1]\\nbaseline=100"
    >>> calib = parse_middlebury(text)
    >>> (calib.focal_px, calib.baseline_m, calib.doffs)
    (700.0, 0.1, 10.0)
    """
    fields: dict[str, str] = {}
    for number, line in enumerate(text.splitlines(), start=1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        key, sep, value = line.partition("=")
        if not sep:
            raise CalibrationError(f"{source}: line {number} is not 'key=value': {line[:60]!r}")
        fields[key.strip()] = value.strip()
    for required in ("cam0", "cam1", "baseline"):
        if required not in fields:
            raise CalibrationError(f"{source}: no '{required}=' line (not a Middlebury calib.txt?)")
    cam0 = matrix(numbers(fields["cam0"], where=source, key="cam0"), 3, 3, where=source, key="cam0",
                  layout=_LAYOUT)
    cam1 = matrix(numbers(fields["cam1"], where=source, key="cam1"), 3, 3, where=source, key="cam1",
                  layout=_LAYOUT)
    baseline_mm = _scalar(fields, "baseline", source)
    # doffs is cx(cam1) - cx(cam0); the file states it, older files may leave it out
    doffs = _scalar(fields, "doffs", source) if "doffs" in fields else float(cam1[0, 2] - cam0[0, 2])
    size = None
    if "width" in fields and "height" in fields:
        size = (int(_scalar(fields, "height", source)), int(_scalar(fields, "width", source)))
    return StereoCalibration(
        focal_px=float(cam0[0, 0]),
        focal_y_px=float(cam0[1, 1]) if cam0[1, 1] != cam0[0, 0] else None,
        baseline_m=baseline_mm / _MM_PER_M,
        cx=float(cam0[0, 2]),
        cy=float(cam0[1, 2]),
        doffs=doffs,
        size=size,
        source=source,
    )


def read_middlebury(path: str | Path) -> StereoCalibration:
    """Read a Middlebury ``calib.txt`` file (see :func:`parse_middlebury`)."""
    return parse_middlebury(read_text(path), source=f"{Path(path).name} (Middlebury)")


def _scalar(fields: dict[str, str], key: str, source: str) -> float:
    values = numbers(fields[key], where=source, key=key)
    if len(values) != 1:
        raise CalibrationError(f"{source}: {key} must be one number, got {len(values)}")
    return values[0]
