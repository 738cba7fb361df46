"""Decode stereo input images (PNG, JPEG, PPM/PGM, TIFF, ...) to uint8 RGB arrays (H, W, 3).

The pixel count is checked from the header before any pixel is decoded, so a service can refuse a
decompression bomb cheaply. EXIF orientation is applied (a phone JPEG is matched as it is displayed),
grey is expanded to three channels, 16-bit samples keep their high byte (>> 8: scaling, not clipping),
alpha is dropped (not composited: matching needs the recorded colour), palette and CMYK are converted.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
from PIL import Image, ImageOps, UnidentifiedImageError

# 8-bit modes Pillow converts to RGB exactly (alpha dropped, palette expanded, CMYK/YCbCr/LAB transformed).
_TO_RGB = {"RGB", "RGBA", "RGBa", "RGBX", "P", "PA", "CMYK", "YCbCr", "LAB", "HSV"}
_TO_GREY = {"L", "LA", "La", "1"}
_SIXTEEN_BIT = {"I;16", "I;16L", "I;16B", "I;16N", "I"}


class ImageDecodeError(ValueError):
    """The bytes are not an image this runtime can use."""


class ImageTooLargeError(ImageDecodeError):
    """The image header announces more pixels than allowed (checked before decoding)."""


def read_image(
    source: bytes | str | Path, *, max_pixels: int | None = None, name: str = "image"
) -> np.ndarray:
    """Decode ``source`` (encoded bytes or a file path) to a C-contiguous uint8 array (H, W, 3).

    ``max_pixels`` bounds width x height (None: only Pillow's decompression-bomb guard, ~179 Mpx, applies);
    ``name`` is used in error messages (e.g. "left"). A missing path raises FileNotFoundError.
    """
    stream = io.BytesIO(source) if isinstance(source, bytes | bytearray | memoryview) else Path(source)
    try:
        image = Image.open(stream)  # reads the header only
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
    return "unknown format; send PNG, JPEG, PPM/PGM or TIFF"


def _reason(error: BaseException) -> str:
    return str(error).strip() or type(error).__name__
