"""Disparity -> depth for a rectified pair: ``z = f B / (d + doffs)`` (paper eq. 1-2, Middlebury's doffs).

One implementation for the CLI, the Python API and the HTTP routes (``service.api.routes.geometry``
imports it).
"""

from __future__ import annotations

import numpy as np

from service.validation.codes import Validity


def depth_from_disparity(
    disparity: np.ndarray,
    *,
    focal_px: float,
    baseline_m: float,
    doffs: float = 0.0,
    min_disparity: float | None = None,
    max_depth: float | None = None,
    keep: np.ndarray | None = None,
) -> np.ndarray:
    """float32 depth in metres, NaN where the disparity gives none.

    A pixel has no depth when its disparity is NaN or infinite, below ``min_disparity`` (when given), or
    ``d + doffs <= 0`` (at or beyond infinity), or when its depth is over ``max_depth`` metres (when
    given: far points are where a 0.1 px disparity error moves a point by metres), or where ``keep``
    (bool HxW, when given) is False: ``keep=measured(validity)`` drops the filled pixels.

    >>> depth_from_disparity(np.array([[70.0, 0.0, np.nan]]), focal_px=700, baseline_m=0.1).tolist()
    [[1.0, nan, nan]]
    >>> depth_from_disparity(np.array([[60.0]]), focal_px=700, baseline_m=0.1, doffs=10).tolist()
    [[1.0]]
    >>> depth_from_disparity(np.array([[70.0, 70.0]]), focal_px=700, baseline_m=0.1,
    ...                      keep=measured(np.array([[0, 5]]))).tolist()
    [[1.0, nan]]
    """
    if not (np.isfinite(focal_px) and np.isfinite(baseline_m) and focal_px > 0 and baseline_m > 0):
        raise ValueError(f"focal_px and baseline_m must be positive, got {focal_px} and {baseline_m}")
    if not np.isfinite(doffs):
        raise ValueError(f"doffs must be finite, got {doffs}")
    if max_depth is not None and not max_depth > 0:
        raise ValueError(f"max_depth must be positive, got {max_depth}")
    disparity = np.asarray(disparity, dtype=np.float32)
    if disparity.ndim != 2:
        raise ValueError(f"a disparity map must be HxW, got shape {disparity.shape}")
    shifted = disparity.astype(np.float64) + doffs
    valid = np.isfinite(shifted) & (shifted > 0)
    if keep is not None:
        if np.shape(keep) != disparity.shape:
            raise ValueError(f"keep mask {np.shape(keep)} does not match the disparity map {disparity.shape}")
        valid &= np.asarray(keep, dtype=bool)
    if min_disparity is not None:
        valid &= disparity >= min_disparity
    depth = np.full(disparity.shape, np.nan, np.float32)
    depth[valid] = (focal_px * baseline_m / shifted[valid]).astype(np.float32)
    if max_depth is not None:
        depth[depth > max_depth] = np.nan
    return depth


def measured(validity: np.ndarray) -> np.ndarray:
    """bool HxW: pixels whose disparity was measured and passed the check (not filled, not missing).

    >>> measured(np.array([[0, 1, 5, 6]], np.uint8)).tolist()
    [[True, False, False, False]]
    """
    return np.asarray(validity) == Validity.VALID
