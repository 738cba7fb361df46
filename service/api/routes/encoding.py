"""Response bodies and headers: format negotiation, the validity map, multipart/mixed, Server-Timing.

Format choice: the ``format`` query wins; otherwise the ``Accept`` header picks by media type
(``image/png`` -> the endpoint's PNG format, ``application/x-npy`` -> npy, ``image/x-portable-floatmap``
-> pfm, highest ``q`` first); anything else, or no header, gets the endpoint's default. ``color`` shares
``image/png`` with png16, so it is chosen by the query only.
"""

from __future__ import annotations

import io
import secrets
from collections.abc import Iterable, Mapping, Sequence

import numpy as np
from PIL import Image

_ACCEPT_TO_FORMAT = {
    "image/png": "png16",
    "application/x-npy": "npy",
    "image/x-portable-floatmap": "pfm",
}


def negotiate_format(query_format: str | None, accept: str | None, *, offered: Sequence[str]) -> str:
    """The response format: ``query_format`` if given, else the best ``Accept`` match, else ``offered[0]``."""
    if query_format is not None:
        return query_format
    for media in _accepted_media_types(accept or ""):
        format = _ACCEPT_TO_FORMAT.get(media)
        if format is not None and format in offered:
            return format
    return offered[0]


def _accepted_media_types(accept: str) -> list[str]:
    ranked: list[tuple[float, int, str]] = []
    for position, item in enumerate(accept.split(",")):
        media, *params = (piece.strip() for piece in item.split(";"))
        quality = 1.0
        for param in params:
            key, _, value = param.partition("=")
            if key.strip().lower() == "q":
                try:
                    quality = float(value)
                except ValueError:
                    quality = 0.0
        if media and quality > 0:
            ranked.append((-quality, position, media.lower()))
    return [media for _, _, media in sorted(ranked)]


def validity_png(validity: np.ndarray) -> bytes:
    """The validity map as an 8-bit grey PNG whose values are the Validity codes (0 = valid)."""
    buffer = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(validity, dtype=np.uint8), mode="L").save(buffer, format="PNG")
    return buffer.getvalue()


def multipart_mixed(parts: Iterable[tuple[str, str, str, bytes]]) -> tuple[bytes, str]:
    """Encode ``(name, filename, media_type, body)`` parts; returns the body and its Content-Type.

    Each part names itself in ``Content-Disposition`` so clients can pick parts by name.
    """
    boundary = f"adsm-{secrets.token_hex(16)}"
    chunks: list[bytes] = []
    for name, filename, media_type, body in parts:
        head = (
            f"--{boundary}\r\nContent-Type: {media_type}\r\n"
            f'Content-Disposition: attachment; name="{name}"; filename="{filename}"\r\n'
            f"Content-Length: {len(body)}\r\n\r\n"
        )
        chunks += [head.encode("ascii"), body, b"\r\n"]
    chunks.append(f"--{boundary}--\r\n".encode("ascii"))
    return b"".join(chunks), f'multipart/mixed; boundary="{boundary}"'


def server_timing(timings: Mapping[str, float]) -> str:
    """``Server-Timing`` header value: one ``name;dur=<milliseconds>`` metric per stage, in order."""
    return ", ".join(f"{name};dur={seconds * 1000.0:.2f}" for name, seconds in timings.items())


FILE_EXTENSIONS = {"png16": "png", "color": "png", "npy": "npy", "pfm": "pfm"}
