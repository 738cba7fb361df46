"""Images as the client sends them: a file path, encoded bytes, a uint8 numpy array or a Pillow image.

Paths and bytes go as they are (the service reads PNG, JPEG, PPM/PGM, TIFF, BMP, WebP and GIF and tells
them apart by content); arrays and Pillow images are encoded as PNG, losslessly.
"""

from __future__ import annotations

import io
import mimetypes
import os
from pathlib import Path
from typing import Union

import numpy as np
from PIL import Image

ImageInput = Union[str, os.PathLike, bytes, bytearray, memoryview, np.ndarray, Image.Image]  # noqa: UP007

# zlib's fastest level: every level is lossless, and an array is encoded again on every call.
_PNG_COMPRESS_LEVEL = 1


def image_part(image: ImageInput, side: str) -> tuple[str, bytes, str]:
    """The multipart file ``(filename, bytes, media type)`` of one view (``side`` is "left" or "right")."""
    if isinstance(image, str | os.PathLike):
        path = Path(image)
        media = mimetypes.guess_type(path.name)[0] or "application/octet-stream"
        return path.name, path.read_bytes(), media
    if isinstance(image, bytes | bytearray | memoryview):
        return side, bytes(image), "application/octet-stream"
    if isinstance(image, Image.Image):
        return f"{side}.png", _png(image), "image/png"
    if isinstance(image, np.ndarray):
        return f"{side}.png", _png(_array_image(image, side)), "image/png"
    raise TypeError(f"{side}: expected a file path, encoded bytes, a uint8 numpy array or a PIL image, "
                    f"got {type(image).__name__}")


def _array_image(array: np.ndarray, side: str) -> Image.Image:
    channels = 1 if array.ndim == 2 else array.shape[-1] if array.ndim == 3 else 0
    if array.dtype != np.uint8 or channels not in (1, 3, 4):
        raise ValueError(f"{side}: a numpy image must be uint8 H x W, H x W x 1, 3 (RGB) or 4 (RGBA), got "
                         f"{array.dtype} {array.shape}; encode other images yourself and pass the bytes")
    if array.ndim == 3 and channels == 1:
        array = array[:, :, 0]
    return Image.fromarray(np.ascontiguousarray(array))


def _png(image: Image.Image) -> bytes:
    buffer = io.BytesIO()
    image.save(buffer, format="PNG", compress_level=_PNG_COMPRESS_LEVEL)
    return buffer.getvalue()


CalibrationInput = Union[str, os.PathLike, bytes, bytearray, memoryview]  # noqa: UP007


def calibration_part(calib: CalibrationInput) -> tuple[str, bytes, str]:
    """The multipart file of a calibration: a path (its name tells the service the format) or bytes."""
    if isinstance(calib, str | os.PathLike):
        path = Path(calib)
        return path.name, path.read_bytes(), "application/octet-stream"
    if isinstance(calib, bytes | bytearray | memoryview):
        return "calib", bytes(calib), "application/octet-stream"
    raise TypeError(f"calib: expected a file path or the file's bytes, got {type(calib).__name__}")
