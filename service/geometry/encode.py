"""Depth map files: ``npy`` (float32 metres, NaN none), ``png16`` (uint16 millimetres, 0 none), ``pfm``."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
from PIL import Image

from service.io import encode_disparity

DEPTH_FORMATS = ("npy", "png16", "pfm")
_EXTENSIONS = {".npy": "npy", ".png": "png16", ".pfm": "pfm"}
_MM_PER_M = 1000.0
_PNG16_MAX_MM = 65535


def depth_png16(depth: np.ndarray) -> bytes:
    """uint16 PNG in millimetres; 0 where there is no depth or it exceeds 65.535 m (not representable)."""
    millimetres = np.zeros(depth.shape, np.uint16)
    scaled = np.round(np.nan_to_num(depth, nan=0.0, posinf=0.0) * _MM_PER_M)
    representable = (scaled >= 1) & (scaled <= _PNG16_MAX_MM)
    millimetres[representable] = scaled[representable].astype(np.uint16)
    buffer = io.BytesIO()
    Image.fromarray(millimetres).save(buffer, format="PNG")
    return buffer.getvalue()


def depth_npy(depth: np.ndarray) -> bytes:
    """float32 little-endian npy in metres, NaN where there is no depth."""
    buffer = io.BytesIO()
    np.save(buffer, np.ascontiguousarray(depth, dtype="<f4"), allow_pickle=False)
    return buffer.getvalue()


def depth_pfm(depth: np.ndarray) -> bytes:
    """Little-endian PFM in metres, inf where there is no depth (Middlebury's convention)."""
    return encode_disparity(depth, "pfm")


def depth_format_for_path(path: str | Path) -> str:
    """``npy``, ``png16`` or ``pfm`` from a file extension (.npy, .png, .pfm)."""
    suffix = Path(path).suffix.lower()
    if suffix not in _EXTENSIONS:
        raise ValueError(f"cannot tell the depth format from {str(path)!r}: use .npy (metres), "
                         ".png (16-bit millimetres) or .pfm (metres)")
    return _EXTENSIONS[suffix]


def encode_depth(depth: np.ndarray, format: str) -> bytes:
    """Encoded bytes of a depth map in ``npy``, ``png16`` or ``pfm``."""
    encoders = {"npy": depth_npy, "png16": depth_png16, "pfm": depth_pfm}
    if format not in encoders:
        raise ValueError(f"unknown depth format {format!r}; choose one of {', '.join(DEPTH_FORMATS)}")
    return encoders[format](depth)
