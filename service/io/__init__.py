"""Input images and output disparity maps: decoding, encoding, colour visualisation."""

from service.io.colormap import colorize, colorize_png
from service.io.disparity import (
    FORMATS,
    MEDIA_TYPES,
    encode_disparity,
    format_for_path,
    media_type,
    read_disparity,
    write_disparity,
)
from service.io.images import (
    ALLOWED_FORMATS,
    ImageDecodeError,
    ImageTooLargeError,
    image_size,
    read_image,
    read_pair,
)

__all__ = [
    "ALLOWED_FORMATS",
    "FORMATS",
    "MEDIA_TYPES",
    "ImageDecodeError",
    "ImageTooLargeError",
    "colorize",
    "colorize_png",
    "encode_disparity",
    "format_for_path",
    "image_size",
    "media_type",
    "read_disparity",
    "read_image",
    "read_pair",
    "write_disparity",
]
