"""Decode stereo input images (PNG, JPEG, PPM/PGM, TIFF, BMP, WebP, GIF) to uint8 RGB arrays (H, W, 3).

The pixel count is checked from the header before any pixel is decoded, so a service can refuse a
decompression bomb cheaply. That only holds for formats whose ``Image.open`` reads a header and nothing
else: Pillow's ICO and ICNS readers decode their largest embedded image inside ``open`` (an ICO of
656 KB holding a 13000 x 13000 PNG costs 640 MiB before any check), so only :data:`ALLOWED_FORMATS` are
opened at all; every other format is refused as unknown without running its reader.

EXIF orientation is applied (a phone JPEG is matched as it is displayed),
grey is expanded to three channels, 16-bit samples keep their high byte (>> 8: scaling, not clipping),
alpha is dropped (not composited: matching needs the recorded colour), palette and CMYK are converted.
"""

from __future__ import annotations

import contextlib
import io
from collections.abc import Iterator
from pathlib import Path

import numpy as np
from PIL import Image, ImageOps, UnidentifiedImageError

# 8-bit modes Pillow converts to RGB exactly (alpha dropped, palette expanded, CMYK/YCbCr/LAB transformed).
_TO_RGB = {"RGB", "RGBA", "RGBa", "RGBX", "P", "PA", "CMYK", "YCbCr", "LAB", "HSV"}
_TO_GREY = {"L", "LA", "La", "1"}
_SIXTEEN_BIT = {"I;16", "I;16L", "I;16B", "I;16N", "I"}
# Pillow plugins whose open() parses a header only (checked for each in tests/test_io.py): single-image
# formats, and multi-frame ones whose frames are decoded lazily (TIFF pages, GIF frames; JPEG opens MPO).
ALLOWED_FORMATS = ("PNG", "JPEG", "PPM", "TIFF", "BMP", "WEBP", "GIF")
_ALLOWED_NAMES = "PNG, JPEG, PPM/PGM, TIFF, BMP, WebP or GIF"
_EXIF_ORIENTATION = 0x0112
# EXIF orientations that swap width and height (transposed or rotated by 90 degrees).
_SWAPS_AXES = {5, 6, 7, 8}


class ImageDecodeError(ValueError):
    """The bytes are not an image this runtime can use."""


class ImageTooLargeError(ImageDecodeError):
    """The image header announces more pixels than allowed (checked before decoding)."""


@contextlib.contextmanager
def _opened(source: bytes | str | Path, max_pixels: int | None, name: str) -> Iterator[Image.Image]:
    """The image with its header read and its pixel count checked; no pixel decoded yet."""
    stream = io.BytesIO(source) if isinstance(source, bytes | bytearray | memoryview) else Path(source)
    try:
        image = Image.open(stream, formats=ALLOWED_FORMATS)  # reads the header only
    except Image.DecompressionBombError as error:  # Pillow's own header check, far above any stereo pair
        raise ImageTooLargeError(f"{name}: {_reason(error)}") from error
    except UnidentifiedImageError as error:  # its message names the stream object, not the field
        raise ImageDecodeError(f"{name}: not a readable image ({_unidentified(source)})") from error
    except (ValueError, SyntaxError, EOFError) as error:  # malformed headers
        raise ImageDecodeError(f"{name}: not a readable image ({_reason(error)})") from error
    with image:
        width, height = image.size
        if max_pixels is not None and width * height > max_pixels:
            raise ImageTooLargeError(
                f"{name}: {width} x {height} = {width * height} pixels exceeds the limit of {max_pixels}"
            )
        if width == 0 or height == 0:
            raise ImageDecodeError(f"{name}: empty image ({width} x {height})")
        yield image


def image_size(
    source: bytes | str | Path, *, max_pixels: int | None = None, name: str = "image"
) -> tuple[int, int]:
    """``(height, width)`` of the array :func:`read_image` would return, from the header alone.

    Raises as :func:`read_image` does for an unknown format or too many pixels; decodes nothing, so a
    caller can plan memory (service/memory.py) before the pixels exist.
    """
    with _opened(source, max_pixels, name) as image:
        width, height = image.size
        try:
            orientation = image.getexif().get(_EXIF_ORIENTATION)
        except (OSError, ValueError, SyntaxError, EOFError):
            orientation = None  # exif_transpose ignores an unreadable EXIF block too
        return (width, height) if orientation in _SWAPS_AXES else (height, width)


def read_image(
    source: bytes | str | Path, *, max_pixels: int | None = None, name: str = "image"
) -> np.ndarray:
    """Decode ``source`` (encoded bytes or a file path) to a C-contiguous uint8 array (H, W, 3).

    ``max_pixels`` bounds width x height (None: only Pillow's decompression-bomb guard, ~179 Mpx, applies);
    ``name`` is used in error messages (e.g. "left"). A missing path raises FileNotFoundError.
    """
    with _opened(source, max_pixels, name) as image:
        try:
            image.seek(0)  # first frame of a multi-page TIFF or an animation
            image = ImageOps.exif_transpose(image)
            return _to_rgb(image, name)
        except ImageDecodeError:
            raise
        except (OSError, ValueError, SyntaxError, EOFError) as error:  # truncated or corrupt pixel data
            kind = image.format or "image"
            raise ImageDecodeError(f"{name}: cannot decode {kind} ({_reason(error)})") from error


def _to_rgb(image: Image.Image, name: str) -> np.ndarray:
    mode = image.mode
    if mode in _SIXTEEN_BIT:
        samples = np.asarray(image)
        if samples.min() < 0 or samples.max() > 0xFFFF:
            raise ImageDecodeError(f"{name}: {mode} samples outside 0..65535 are not a 16-bit image")
        grey = (samples.astype(np.uint32) >> 8).astype(np.uint8)
    elif mode in _TO_GREY:
        grey = np.asarray(image.convert("L"))
    elif mode in _TO_RGB:
        return np.ascontiguousarray(np.asarray(image.convert("RGB")))
    else:
        raise ImageDecodeError(f"{name}: unsupported pixel format {mode} (use 8 or 16 bit grey or colour)")
    return np.ascontiguousarray(np.repeat(grey[:, :, None], 3, axis=2))


def _unidentified(source: bytes | str | Path) -> str:
    if isinstance(source, bytes | bytearray | memoryview) and len(source) == 0:
        return "empty file, 0 bytes"
    return f"unknown or refused format; send {_ALLOWED_NAMES}"


def _reason(error: BaseException) -> str:
    return str(error).strip() or type(error).__name__
