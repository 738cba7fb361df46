"""Decode stereo input images (PNG, JPEG, PPM/PGM, TIFF, BMP, WebP, GIF) to uint8 RGB arrays (H, W, 3).

The pixel count is checked from the header before any pixel is decoded, so a service can refuse a
decompression bomb cheaply. That only holds for formats whose ``Image.open`` reads a header and nothing
else: Pillow's ICO and ICNS readers decode their largest embedded image inside ``open`` (an ICO of
656 KB holding a 13000 x 13000 PNG costs 640 MiB before any check), so only :data:`ALLOWED_FORMATS` are
opened at all; every other format is refused as unknown without running its reader.

EXIF orientation is applied (a phone JPEG is matched as it is displayed),
grey is expanded to three channels, alpha is dropped (not composited: matching needs the recorded
colour), palette and CMYK are converted.

**16-bit grey** (PNG, TIFF, PGM) is scaled by its real bit depth, not by 16 bits: a Mono12 camera frame
stored in a 16-bit PNG holds 0..4095, and ``>> 8`` left it 16 grey levels. The depth is the PNG's
``sBIT`` chunk when it has one, else the bit length of the largest sample (at least 8), and the samples
are mapped to ``0..255`` by ``255 / (2^bits - 1)``. :func:`read_pair` gives both images of a pair the
larger of their two depths, so a pair keeps one photometric scale when one view happens to hold no
sample above 2047. (Pillow already scales a PGM's ``maxval`` to 16 bits.) **16-bit colour PNG** (or grey
with alpha) is refused: Pillow keeps only its high byte, which would crush a 12-bit colour frame the same
way.
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
import warnings
import zlib
from collections.abc import Iterator
from pathlib import Path
from typing import BinaryIO

import numpy as np
from PIL import Image, ImageOps, UnidentifiedImageError

# 8-bit modes Pillow converts to RGB exactly (alpha dropped, palette expanded, CMYK/YCbCr/LAB transformed).
_TO_RGB = {"RGB", "RGBA", "RGBa", "RGBX", "P", "PA", "CMYK", "YCbCr", "LAB", "HSV"}
_TO_GREY = {"L", "LA", "La", "1"}
_SIXTEEN_BIT = {"I;16", "I;16L", "I;16B", "I;16N", "I"}
# Pillow plugins whose open() parses a header only (checked for each in tests/service/io/test_io.py):
# single-image formats, and multi-frame ones whose frames are decoded lazily (TIFF pages, GIF frames; JPEG
# opens MPO).
ALLOWED_FORMATS = ("PNG", "JPEG", "PPM", "TIFF", "BMP", "WEBP", "GIF")
_ALLOWED_NAMES = "PNG, JPEG, PPM/PGM, TIFF, BMP, WebP or GIF"
_EXIF_ORIENTATION = 0x0112
# EXIF orientations that swap width and height (transposed or rotated by 90 degrees).
_SWAPS_AXES = {5, 6, 7, 8}
_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_PNG_GREY = 0  # IHDR colour type of grey without alpha: the one 16-bit PNG Pillow decodes in full


class ImageDecodeError(ValueError):
    """The bytes are not an image this runtime can use."""


class ImageTooLargeError(ImageDecodeError):
    """The image header announces more pixels than allowed (checked before decoding)."""


@contextlib.contextmanager
def _opened(source: bytes | str | Path, max_pixels: int | None, name: str) -> Iterator[Image.Image]:
    """The image with its header read and its pixel count checked; no pixel decoded yet."""
    stream = io.BytesIO(source) if isinstance(source, bytes | bytearray | memoryview) else Path(source)
    try:
        with warnings.catch_warnings():
            # The caller's max_pixels is the limit that speaks; Pillow's warning would only add a
            # multi-line stderr message before the one-line refusal (its hard error still applies).
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            image = Image.open(stream, formats=ALLOWED_FORMATS)  # reads the header only
    except Image.DecompressionBombError as error:  # Pillow's own header check, far above any stereo pair
        raise ImageTooLargeError(f"{name}: {_reason(error)}") from error
    except UnidentifiedImageError as error:  # its message names the stream object, not the field
        raise ImageDecodeError(f"{name}: not a readable image ({_unidentified(source)})") from error
    except (ValueError, SyntaxError, EOFError) as error:  # malformed headers
        raise ImageDecodeError(f"{name}: not a readable image ({_reason(error)})") from error
    except OSError as error:
        if error.errno is not None:  # the file itself (missing, a folder, unreadable): the caller's to say
            raise
        # Pillow's word on a header it cannot parse: "Truncated File Read" (a PNG cut inside IHDR),
        # "Unsupported BMP pixel depth", "could not create decoder object" (WebP), ...
        raise ImageDecodeError(f"{name}: not a readable image (malformed or truncated header: "
                               f"{_reason(error)})") from error
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


@dataclasses.dataclass(frozen=True)
class _Decoded:
    pixels: np.ndarray  # uint8 HxWx3, or the uint16 HxW samples of a 16-bit grey image
    bits: int | None  # the 16-bit samples' real depth (sBIT, else the largest sample's); None for uint8

    def rgb(self, bits: int | None = None) -> np.ndarray:
        """uint8 HxWx3; 16-bit samples scaled by ``2^bits - 1`` (default: their own depth) to 255."""
        if self.bits is None:
            return self.pixels
        full_scale = (1 << (bits or self.bits)) - 1
        grey = np.clip(np.rint(self.pixels * (255.0 / full_scale)), 0, 255).astype(np.uint8)
        return np.ascontiguousarray(np.repeat(grey[:, :, None], 3, axis=2))


def read_image(
    source: bytes | str | Path, *, max_pixels: int | None = None, name: str = "image"
) -> np.ndarray:
    """Decode ``source`` (encoded bytes or a file path) to a C-contiguous uint8 array (H, W, 3).

    ``max_pixels`` bounds width x height (None: only Pillow's decompression-bomb guard, ~179 Mpx, applies);
    ``name`` is used in error messages (e.g. "left"). A missing path raises FileNotFoundError.
    16-bit grey is scaled by its own real bit depth (module docstring); use :func:`read_pair` for a pair.
    """
    return _decode(source, max_pixels, name).rgb()


def read_pair(
    left: bytes | str | Path, right: bytes | str | Path, *, max_pixels: int | None = None,
    names: tuple[str, str] = ("left image", "right image"),
) -> tuple[np.ndarray, np.ndarray]:
    """Both images of a stereo pair as :func:`read_image` decodes them, except that 16-bit grey views
    share one bit depth (the larger of the two), so their grey levels stay comparable."""
    decoded = [_decode(source, max_pixels, name) for source, name in zip((left, right), names, strict=True)]
    depths = [item.bits for item in decoded if item.bits is not None]
    common = max(depths) if depths else None
    return decoded[0].rgb(common), decoded[1].rgb(common)


def _decode(source: bytes | str | Path, max_pixels: int | None, name: str) -> _Decoded:
    with _opened(source, max_pixels, name) as image:
        try:
            image.seek(0)  # first frame of a multi-page TIFF or an animation
            facts = _png_facts(source) if image.format == "PNG" else None
            if facts is not None and facts[0] == 16 and facts[1] != _PNG_GREY:
                raise ImageDecodeError(
                    f"{name}: 16-bit colour PNG would lose precision (Pillow reads only its high byte of "
                    "colour or alpha samples); convert it to 8-bit colour or 16-bit grey without alpha"
                )
            image = ImageOps.exif_transpose(image)
            if image.mode in _SIXTEEN_BIT:
                return _sixteen_bit(image, name, facts[2] if facts is not None else None)
            return _Decoded(_to_rgb(image, name), None)
        except ImageDecodeError:
            raise
        except (OSError, ValueError, SyntaxError, EOFError) as error:  # truncated or corrupt pixel data
            kind = image.format or "image"
            raise ImageDecodeError(f"{name}: cannot decode {kind} ({_reason(error)})") from error


def _sixteen_bit(image: Image.Image, name: str, significant: int | None) -> _Decoded:
    samples = np.asarray(image)
    if samples.min() < 0 or samples.max() > 0xFFFF:
        raise ImageDecodeError(f"{name}: {image.mode} samples outside 0..65535 are not a 16-bit image")
    samples = samples.astype(np.uint16)
    bits = significant if significant is not None else max(8, int(samples.max()).bit_length())
    return _Decoded(samples, bits)


def _to_rgb(image: Image.Image, name: str) -> np.ndarray:
    mode = image.mode
    if mode in _TO_GREY:
        grey = np.asarray(image.convert("L"))
    elif mode in _TO_RGB:
        return np.ascontiguousarray(np.asarray(image.convert("RGB")))
    else:
        raise ImageDecodeError(f"{name}: unsupported pixel format {mode} (use 8 or 16 bit grey or colour)")
    return np.ascontiguousarray(np.repeat(grey[:, :, None], 3, axis=2))


def _png_facts(source: bytes | str | Path) -> tuple[int, int, int | None] | None:
    """(bit depth, colour type, significant bits of the sBIT chunk or None) of a PNG, from the chunks
    before its pixel data; None when the header is not a PNG's."""
    with contextlib.ExitStack() as stack:
        stream: BinaryIO
        if isinstance(source, bytes | bytearray | memoryview):
            stream = io.BytesIO(source)
        else:
            stream = stack.enter_context(open(source, "rb"))
        head = stream.read(33)
        if len(head) < 33 or not head.startswith(_PNG_SIGNATURE) or head[12:16] != b"IHDR":
            return None
        depth, colour = head[24], head[25]
        for _ in range(256):  # chunks before IDAT: a handful in practice
            header = stream.read(8)
            if len(header) < 8:
                break
            length, kind = int.from_bytes(header[:4], "big"), header[4:]
            if kind in (b"IDAT", b"IEND"):
                break
            if kind == b"sBIT" and length > 4:  # at most one byte per channel: a malformed chunk
                break
            if kind != b"sBIT":
                stream.seek(length + 4, io.SEEK_CUR)
                continue
            body, crc = stream.read(length), stream.read(4)
            intact = zlib.crc32(kind + body) == int.from_bytes(crc, "big")
            if intact and len(body) >= 1 and 1 <= body[0] <= depth:
                return depth, colour, body[0]
            break
        return depth, colour, None


def _unidentified(source: bytes | str | Path) -> str:
    if isinstance(source, bytes | bytearray | memoryview) and len(source) == 0:
        return "empty file, 0 bytes"
    return f"unknown or refused format; send {_ALLOWED_NAMES}"


def _reason(error: BaseException) -> str:
    return str(error).strip() or type(error).__name__
