"""Depth -> points in the left camera's frame (x right, y down, z forward, metres) and binary PLY."""

from __future__ import annotations

import numpy as np

PLY_VERTEX = np.dtype(
    [("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("red", "u1"), ("green", "u1"), ("blue", "u1")]
)


def point_cloud(
    depth: np.ndarray,
    *,
    focal_px: float,
    cx: float | None = None,
    cy: float | None = None,
    focal_y_px: float | None = None,
    keep: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(points, rows, cols)``: float32 Nx3 points of the pixels with a finite depth (and ``keep``).

    ``x = (u - cx) z / f``, ``y = (v - cy) z / fy``; ``cx``/``cy`` default to the image centre
    (``(W - 1) / 2``, ``(H - 1) / 2``); ``rows``/``cols`` say which pixel each point came from (to colour
    it, or to drop filled pixels pass ``keep = service.geometry.measured(validity)``).

    >>> points, _, _ = point_cloud(np.array([[2.0, np.nan]]), focal_px=100.0, cx=0.0, cy=0.0)
    >>> points.tolist()
    [[0.0, 0.0, 2.0]]
    """
    depth = np.asarray(depth, dtype=np.float32)
    if depth.ndim != 2:
        raise ValueError(f"a depth map must be HxW, got shape {depth.shape}")
    if not (np.isfinite(focal_px) and focal_px > 0):
        raise ValueError(f"focal_px must be positive, got {focal_px}")
    height, width = depth.shape
    cx = (width - 1) / 2.0 if cx is None else cx
    cy = (height - 1) / 2.0 if cy is None else cy
    fy = focal_px if focal_y_px is None else focal_y_px
    selected = np.isfinite(depth)
    if keep is not None:
        if keep.shape != depth.shape:
            raise ValueError(f"keep mask {keep.shape} does not match the depth map {depth.shape}")
        selected &= keep.astype(bool)
    rows, cols = np.nonzero(selected)
    z = depth[rows, cols].astype(np.float64)
    points = np.empty((z.shape[0], 3), np.float32)
    points[:, 0] = (cols - cx) * z / focal_px
    points[:, 1] = (rows - cy) * z / fy
    points[:, 2] = z
    return points, rows, cols


def encode_ply(points: np.ndarray, colors: np.ndarray) -> bytes:
    """Binary little-endian PLY: float x, y, z and uchar red, green, blue per vertex (Nx3 each)."""
    if points.ndim != 2 or points.shape[1] != 3 or colors.shape != points.shape:
        raise ValueError(f"points {points.shape} and colours {colors.shape} must both be Nx3")
    vertices = np.empty(points.shape[0], dtype=PLY_VERTEX)
    vertices["x"], vertices["y"], vertices["z"] = points[:, 0], points[:, 1], points[:, 2]
    vertices["red"], vertices["green"], vertices["blue"] = colors[:, 0], colors[:, 1], colors[:, 2]
    header = (
        "ply\nformat binary_little_endian 1.0\ncomment adsm-stereo point cloud, metres, left camera frame\n"
        f"element vertex {points.shape[0]}\n"
        "property float x\nproperty float y\nproperty float z\n"
        "property uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n"
    )
    return header.encode("ascii") + vertices.tobytes()


def point_cloud_ply(
    depth: np.ndarray,
    colors: np.ndarray,
    *,
    focal_px: float,
    cx: float | None = None,
    cy: float | None = None,
    focal_y_px: float | None = None,
    keep: np.ndarray | None = None,
) -> tuple[bytes, int]:
    """Binary PLY of :func:`point_cloud` coloured by ``colors`` (uint8 HxWx3) and its vertex count."""
    depth = np.asarray(depth)
    if colors.shape != (*depth.shape, 3):
        raise ValueError(f"colours {colors.shape} do not match the depth map {depth.shape}")
    points, rows, cols = point_cloud(depth, focal_px=focal_px, cx=cx, cy=cy, focal_y_px=focal_y_px, keep=keep)
    return encode_ply(points, np.asarray(colors, dtype=np.uint8)[rows, cols]), int(points.shape[0])


def read_ply(data: bytes) -> np.ndarray:
    """The vertices of a PLY written by :func:`encode_ply` (a structured array; for tests and tools)."""
    end = data.index(b"end_header\n") + len(b"end_header\n")
    header = data[:end].decode("ascii")
    count = next(int(line.split()[2]) for line in header.splitlines() if line.startswith("element vertex"))
    return np.frombuffer(data, dtype=PLY_VERTEX, count=count, offset=end)
