"""Colour visualisation of disparity maps: the Turbo colour map in NumPy, invalid pixels in black.

Turbo (A. Mikhailov, Google, 2019) is a perceptually smoothed rainbow: near is red, far is blue. The
256-entry table is built once from R. Du's degree-5 polynomial fit of the original table (Apache-2.0),
so no matplotlib is needed.
"""

from __future__ import annotations

import io

import numpy as np
from PIL import Image

# Coefficients of x^0 .. x^5 for red, green, blue (Copyright 2019 Google LLC, Apache-2.0).
_TURBO_POLYNOMIAL = np.array(
    [
        [0.13572138, 4.61539260, -42.66032258, 132.13108234, -152.94239396, 59.28637943],
        [0.09140261, 2.19418839, 4.84296658, -14.18503333, 4.27729857, 2.82956604],
        [0.10667330, 12.64194608, -60.58204836, 110.36276771, -89.90310912, 27.34824973],
    ]
)


def _turbo_table(entries: int = 256) -> np.ndarray:
    x = np.linspace(0.0, 1.0, entries)
    powers = x[:, None] ** np.arange(6)[None, :]
    rgb = np.clip(powers @ _TURBO_POLYNOMIAL.T, 0.0, 1.0)
    return np.round(rgb * 255.0).astype(np.uint8)


TURBO = _turbo_table()


def colorize(
    disparity: np.ndarray, *, min_disparity: float | None = None, max_disparity: float | None = None
) -> np.ndarray:
    """uint8 RGB (H, W, 3) of a float disparity map; large disparities (near) red, NaN/inf/<=0 black.

    The range defaults to the valid pixels' minimum and maximum, so two maps are comparable only when
    the caller passes the same ``min_disparity``/``max_disparity``.
    """
    disparity = np.asarray(disparity)
    if disparity.ndim != 2 or not np.issubdtype(disparity.dtype, np.number):
        raise ValueError(f"disparity must be a 2-D numeric array, got {disparity.dtype} {disparity.shape}")
    values = disparity.astype(np.float32, copy=False)
    valid = np.isfinite(values) & (values > 0)
    rgb = np.zeros((*values.shape, 3), np.uint8)
    if not valid.any():
        return rgb
    low = float(values[valid].min()) if min_disparity is None else float(min_disparity)
    high = float(values[valid].max()) if max_disparity is None else float(max_disparity)
    span = high - low if high > low else 1.0
    index = np.clip((values[valid] - low) * ((TURBO.shape[0] - 1) / span), 0, TURBO.shape[0] - 1)
    rgb[valid] = TURBO[np.round(index).astype(np.intp)]
    return rgb


def colorize_png(disparity: np.ndarray, **range_options: float | None) -> bytes:
    """:func:`colorize` encoded as an RGB PNG."""
    buffer = io.BytesIO()
    Image.fromarray(colorize(disparity, **range_options)).save(buffer, format="PNG")
    return buffer.getvalue()
