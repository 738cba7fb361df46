"""Metric geometry of a rectified pair: depth, point clouds and their file formats.

The one implementation used by ``adsm predict``, the Python API and the HTTP routes
(``service.api.routes.geometry`` re-exports it).

>>> import numpy as np
>>> from service.geometry import depth_from_disparity, point_cloud
>>> depth = depth_from_disparity(np.full((2, 2), 35.0), focal_px=700.0, baseline_m=0.1)
>>> float(depth[0, 0])
2.0
>>> point_cloud(depth, focal_px=700.0)[0].shape
(4, 3)
"""

from service.geometry.depth import depth_from_disparity, measured
from service.geometry.encode import (
    DEPTH_FORMATS,
    depth_format_for_path,
    depth_npy,
    depth_pfm,
    depth_png16,
    encode_depth,
)
from service.geometry.pointcloud import encode_ply, point_cloud, point_cloud_ply, read_ply

__all__ = [
    "DEPTH_FORMATS",
    "depth_format_for_path",
    "depth_from_disparity",
    "depth_npy",
    "depth_pfm",
    "depth_png16",
    "encode_depth",
    "encode_ply",
    "measured",
    "point_cloud",
    "point_cloud_ply",
    "read_ply",
]
