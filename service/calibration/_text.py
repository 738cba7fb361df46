"""Helpers shared by the text readers: numbers out of ``key: values`` and ``key=[...]`` lines."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from service.calibration.errors import CalibrationError

MAX_CALIBRATION_BYTES = 1 << 20  # a calibration file is a few hundred bytes; refuse anything absurd


def read_text(path: str | Path) -> str:
    """The file's text, or a one-line CalibrationError (missing, too large, not text)."""
    path = Path(path)
    if not path.is_file():
        raise CalibrationError(f"calibration file {str(path)!r} does not exist or is not a file")
    size = path.stat().st_size
    if size > MAX_CALIBRATION_BYTES:
        raise CalibrationError(f"{path.name}: {size} bytes is too large for a calibration file")
    try:
        return path.read_text(encoding="utf-8")
    except UnicodeDecodeError as error:
        raise CalibrationError(f"{path.name}: not a text file ({error.reason})") from error


def numbers(text: str, *, where: str, key: str) -> list[float]:
    """Finite floats from a whitespace, comma or semicolon separated list (brackets ignored)."""
    cleaned = text.replace("[", " ").replace("]", " ").replace(";", " ").replace(",", " ")
    try:
        values = [float(token) for token in cleaned.split()]
    except ValueError as error:
        raise CalibrationError(f"{where}: {key} holds a value that is not a number ({error})") from error
    if not all(math.isfinite(value) for value in values):
        raise CalibrationError(f"{where}: {key} holds a non-finite value")
    return values


def matrix(values: list[float], rows: int, cols: int, *, where: str, key: str, layout: str) -> np.ndarray:
    """``values`` as a rows x cols float64 array, or a CalibrationError naming the expected layout."""
    if len(values) != rows * cols:
        raise CalibrationError(
            f"{where}: {key} must be a {rows}x{cols} matrix {layout}, got {len(values)} numbers"
        )
    return np.array(values, dtype=np.float64).reshape(rows, cols)
