"""Disparity map codecs: KITTI uint16 PNG, Middlebury PFM, NumPy npy, and a colour PNG for people.

In memory a disparity map is float32 (H, W) with NaN where invalid. On disk each format keeps its own
convention for "invalid": png16 stores round(d * 256) with 0 = invalid (values clipped to 65535 / 256;
a positive d below 1 / 512 is stored as 1 / 256 rather than turned invalid); PFM stores +inf; npy NaN.
"""

from __future__ import annotations

import io
import re
from pathlib import Path
from typing import BinaryIO

import numpy as np
from PIL import Image

from service.io.colormap import colorize_png

FORMATS = ("png16", "npy", "pfm", "color")
MEDIA_TYPES = {
    "png16": "image/png",
    "npy": "application/x-npy",
    "pfm": "image/x-portable-floatmap",
    "color": "image/png",
}
EXTENSIONS = {".png": "png16", ".npy": "npy", ".pfm": "pfm"}
PNG16_SCALE = 256.0
_PFM_HEADER = re.compile(rb"\A(P[Ff])\s+(\d+)\s+(\d+)\s+([-+0-9.eE]+)\s")


def media_type(format: str) -> str:
    """The HTTP media type of an encoded disparity map."""
    return MEDIA_TYPES[_check_format(format)]


def encode_disparity(disparity: np.ndarray, format: str, *,
                     color_range: tuple[float, float] | None = None) -> bytes:
    """Encode a float disparity map (NaN invalid) as ``png16``, ``npy``, ``pfm`` or ``color``.

    Any non-finite value is invalid; png16 and color also treat d <= 0 as invalid (0 means "no data"
    in the KITTI convention), while npy and pfm keep a zero disparity. ``color_range`` (low, high) fixes
    the colour map's ends for ``color`` (default: the map's own minimum and maximum), so that frames
    compare.
    """
    format = _check_format(format)
    values = _as_disparity(disparity)
    if format == "color":
        low, high = (None, None) if color_range is None else color_range
        return colorize_png(values, min_disparity=low, max_disparity=high)
    buffer = io.BytesIO()
    if format == "png16":
        # zlib level 1: a 375x1242 sub-pixel map encodes in 0.036 instead of 0.087 CPU s (level 6, Pillow's
        # default) for a file 3 % larger; the lossless values are the same.
        Image.fromarray(_to_png16(values)).save(buffer, format="PNG", compress_level=1)
    elif format == "npy":
        np.save(buffer, np.where(np.isfinite(values), values, np.float32(np.nan)), allow_pickle=False)
    else:
        _write_pfm(buffer, values)
    return buffer.getvalue()


def write_disparity(target: str | Path | BinaryIO, disparity: np.ndarray, format: str) -> None:
    """Write :func:`encode_disparity`'s bytes to a path or a binary stream."""
    data = encode_disparity(disparity, format)
    if isinstance(target, str | Path):
        Path(target).write_bytes(data)
    else:
        target.write(data)


def format_for_path(path: str | Path) -> str:
    """The disparity format implied by a file extension (.png -> png16, .npy, .pfm)."""
    suffix = Path(path).suffix.lower()
    if suffix not in EXTENSIONS:
        raise ValueError(f"cannot tell the disparity format from {str(path)!r}: use .png, .npy or .pfm")
    return EXTENSIONS[suffix]


def read_disparity(path: str | Path) -> np.ndarray:
    """Read a png16, PFM or npy disparity map (told apart by content) as float32 with NaN invalid."""
    return decode_disparity(Path(path).read_bytes(), source=path)


def decode_disparity(data: bytes, *, source: str | Path = "disparity map") -> np.ndarray:
    """:func:`read_disparity` of bytes in memory (an HTTP answer); ``source`` names them in errors."""
    if data.startswith(b"\x89PNG"):
        return _from_png16(data, source)
    if data.startswith(b"\x93NUMPY"):
        values = np.load(io.BytesIO(data), allow_pickle=False)
        values = _as_disparity(values).copy()
        values[~np.isfinite(values)] = np.nan
        return values
    if data[:2] in (b"Pf", b"PF"):
        return _read_pfm(data, source)
    raise ValueError(f"{source}: not a png16, PFM or npy disparity map")


def _check_format(format: str) -> str:
    if format not in FORMATS:
        raise ValueError(f"unknown disparity format {format!r}; choose one of {', '.join(FORMATS)}")
    return format


def _as_disparity(disparity: np.ndarray) -> np.ndarray:
    values = np.asarray(disparity)
    real = np.issubdtype(values.dtype, np.floating) or np.issubdtype(values.dtype, np.integer)
    if values.ndim != 2 or not real:
        raise ValueError(f"a disparity map must be a 2-D real array, got {values.dtype} {values.shape}")
    return values.astype(np.float32, copy=False)


def _to_png16(values: np.ndarray) -> np.ndarray:
    valid = np.isfinite(values) & (values > 0)
    scaled = np.where(valid, values, 0).astype(np.float64) * PNG16_SCALE
    encoded = np.clip(np.rint(scaled), 1, 65535)
    return np.where(valid, encoded, 0).astype(np.uint16)


def _from_png16(data: bytes, path: str | Path) -> np.ndarray:
    with Image.open(io.BytesIO(data)) as image:
        if image.mode not in ("I;16", "I;16B", "I;16L", "I"):
            raise ValueError(f"{path}: a png16 disparity map must be 16-bit grey, got mode {image.mode}")
        encoded = np.asarray(image).astype(np.float32)
    return np.where(encoded > 0, encoded / np.float32(PNG16_SCALE), np.float32(np.nan))


def _write_pfm(stream: BinaryIO, values: np.ndarray) -> None:
    height, width = values.shape
    stream.write(f"Pf\n{width} {height}\n-1.0\n".encode("ascii"))  # negative scale: little endian
    stored = np.where(np.isfinite(values), values, np.float32(np.inf))
    stream.write(np.ascontiguousarray(stored[::-1], dtype="<f4").tobytes())  # rows bottom to top


def _read_pfm(data: bytes, path: str | Path) -> np.ndarray:
    header = _PFM_HEADER.match(data)
    if header is None:
        raise ValueError(f"{path}: malformed PFM header")
    width, height, scale = int(header.group(2)), int(header.group(3)), float(header.group(4))
    channels = 3 if header.group(1) == b"PF" else 1
    dtype = "<f4" if scale < 0 else ">f4"
    expected = width * height * channels * 4
    body = data[header.end() : header.end() + expected]  # some writers append a newline: ignore it
    if len(body) != expected:
        raise ValueError(f"{path}: truncated PFM ({len(body)} of {expected} data bytes)")
    values = np.frombuffer(body, dtype=dtype).reshape(height, width, channels)[::-1, :, 0]
    values = values.astype(np.float32)  # native byte order, own copy
    values[~np.isfinite(values)] = np.nan
    return values
