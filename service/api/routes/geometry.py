"""Depth and point clouds for the HTTP routes: the shared implementation in :mod:`service.geometry`.

Coordinates are the left camera's: x right, y down, z forward, in metres. Pixels whose disparity is
NaN, infinite or not positive have no depth (NaN in the depth map, dropped from the point cloud).
"""

from __future__ import annotations

from service.geometry import (
    depth_from_disparity,
    depth_npy,
    depth_png16,
    encode_depth,
    measured,
    point_cloud_ply,
)

__all__ = ["depth_from_disparity", "depth_npy", "depth_png16", "encode_depth", "measured", "point_cloud_ply"]
