"""Confidence map files: ``npy`` (float32 in [0, 1]) or ``png`` (8-bit grey, confidence x 255, rounded).

The one encoder of the HTTP ``confidence`` part; ``adsm predict --confidence`` writes the same two forms.
"""

from __future__ import annotations

import io

import numpy as np
from PIL import Image

CONFIDENCE_FORMATS = ("npy", "png")
MEDIA_TYPES = {"npy": "application/x-npy", "png": "image/png"}


def encode_confidence(confidence: np.ndarray, format: str) -> bytes:
    """Encoded bytes of a float confidence map (H x W, values in [0, 1]) as ``npy`` or ``png``.

    >>> encode_confidence(np.array([[0.0, 1.0]], np.float32), "png")[:4]
    b'\\x89PNG'
    """
    values = np.asarray(confidence)
    if values.ndim != 2 or not np.issubdtype(values.dtype, np.floating):
        raise ValueError(f"a confidence map must be a float H x W array, got {values.dtype} {values.shape}")
    buffer = io.BytesIO()
    if format == "npy":
        np.save(buffer, np.ascontiguousarray(values, dtype="<f4"), allow_pickle=False)
    elif format == "png":
        levels = np.rint(np.clip(np.nan_to_num(values, nan=0.0), 0.0, 1.0) * 255.0).astype(np.uint8)
        Image.fromarray(levels).save(buffer, format="PNG")
    else:
        choices = ", ".join(CONFIDENCE_FORMATS)
        raise ValueError(f"unknown confidence format {format!r}; choose one of {choices}")
    return buffer.getvalue()
