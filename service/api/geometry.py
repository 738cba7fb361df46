"""Disparity -> depth and coloured point cloud for a rectified pair (paper eq. 1-2: z = B f / d).

Coordinates are the left camera's: x right, y down, z forward, in metres. Pixels whose disparity is
NaN, infinite or not positive have no depth (NaN in the depth map, dropped from the point cloud).
"""

from __future__ import annotations

import io

import numpy as np
from PIL import Image

_MM_PER_M = 1000.0
_PNG16_MAX_MM = 65535


def depth_from_disparity(disparity: np.ndarray, *, focal_px: float, baseline_m: float) -> np.ndarray:
    """float32 depth in metres, NaN where the disparity gives none."""
    if not (focal_px > 0 and baseline_m > 0):
        raise ValueError(f"focal_px and baseline_m must be positive, got {focal_px} and {baseline_m}")
    disparity = np.asarray(disparity, dtype=np.float32)
    depth = np.full(disparity.shape, np.nan, np.float32)
    valid = np.isfinite(disparity) & (disparity > 0)
    depth[valid] = np.float32(focal_px * baseline_m) / disparity[valid]
    return depth


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
    buffer = io.BytesIO()
    np.save(buffer, np.ascontiguousarray(depth, dtype="<f4"), allow_pickle=False)
    return buffer.getvalue()


def point_cloud_ply(
    depth: np.ndarray,
    colors: np.ndarray,
    *,
    focal_px: float,
    cx: float | None = None,
    cy: float | None = None,
) -> tuple[bytes, int]:
    """Binary little-endian PLY (float x, y, z; uchar red, green, blue) and its vertex count.

    ``cx``/``cy`` default to the image centre, ``(W - 1) / 2`` and ``(H - 1) / 2``.
    """
    height, width = depth.shape
    if colors.shape != (height, width, 3):
        raise ValueError(f"colours {colors.shape} do not match the depth map {depth.shape}")
    cx = (width - 1) / 2.0 if cx is None else cx
    cy = (height - 1) / 2.0 if cy is None else cy
    rows, cols = np.nonzero(np.isfinite(depth))
    z = depth[rows, cols]
    vertices = np.empty(
        z.shape[0],
        dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("red", "u1"), ("green", "u1"), ("blue", "u1")],
    )
    vertices["x"] = (cols - cx) * z / focal_px
    vertices["y"] = (rows - cy) * z / focal_px
    vertices["z"] = z
    rgb = colors[rows, cols]
    vertices["red"], vertices["green"], vertices["blue"] = rgb[:, 0], rgb[:, 1], rgb[:, 2]
    header = (
        "ply\nformat binary_little_endian 1.0\ncomment adsm-stereo point cloud, metres, left camera frame\n"
        f"element vertex {z.shape[0]}\n"
        "property float x\nproperty float y\nproperty float z\n"
        "property uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n"
    )
    return header.encode("ascii") + vertices.tobytes(), int(z.shape[0])
