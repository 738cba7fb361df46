"""Depth and point clouds (service.geometry): doffs, limits, filled pixels, PLY, and OpenCV's Q."""

from __future__ import annotations

import io

import numpy as np
import pytest

from service.api.routes import geometry as api_geometry
from service.calibration import StereoCalibration
from service.geometry import (
    depth_format_for_path,
    depth_from_disparity,
    encode_depth,
    measured,
    point_cloud,
    point_cloud_ply,
    read_ply,
)
from service.io import read_disparity
from service.validation.codes import Validity
from tests.helpers import require_module


def test_depth_formula_with_doffs_and_limits():
    disparity = np.array([[70.0, 35.0, 0.0, -5.0, np.nan, np.inf, 1.0]], np.float32)
    depth = depth_from_disparity(disparity, focal_px=700, baseline_m=0.1)
    np.testing.assert_allclose(depth[0, :2], [1.0, 2.0])
    assert np.isnan(depth[0, 2:6]).all() and depth[0, 6] == pytest.approx(70.0)
    # Middlebury: Z = f B / (d + doffs); d = 0 has a finite depth when doffs > 0
    shifted = depth_from_disparity(disparity, focal_px=700, baseline_m=0.1, doffs=10)
    np.testing.assert_allclose(shifted[0, [0, 2, 3]], [70 / 80, 7.0, 70 / 5])
    limited = depth_from_disparity(disparity, focal_px=700, baseline_m=0.1, max_depth=10, min_disparity=2)
    np.testing.assert_allclose(limited[0, :2], [1.0, 2.0])
    assert np.isnan(limited[0, 6])  # 70 m > max_depth (and d = 1 < min_disparity)
    for bad in ({"focal_px": 0, "baseline_m": 0.1}, {"focal_px": 700, "baseline_m": -1},
                {"focal_px": 700, "baseline_m": 0.1, "max_depth": 0}):
        with pytest.raises(ValueError):
            depth_from_disparity(disparity, **bad)


def test_api_geometry_is_the_shared_module():
    assert api_geometry.depth_from_disparity is depth_from_disparity
    assert api_geometry.point_cloud_ply is point_cloud_ply


def test_point_cloud_matches_opencv_reproject():
    cv2 = require_module("cv2")
    rng = np.random.default_rng(5)
    calib = StereoCalibration(focal_px=640.0, baseline_m=0.12, cx=150.3, cy=99.7, doffs=3.5)
    disparity = rng.uniform(5, 60, (200, 300)).astype(np.float32)
    depth = depth_from_disparity(disparity, focal_px=calib.focal_px, baseline_m=calib.baseline_m,
                                 doffs=calib.doffs)
    points, rows, cols = point_cloud(depth, focal_px=calib.focal_px, cx=calib.cx, cy=calib.cy)
    assert points.shape == (200 * 300, 3)
    reference = cv2.reprojectImageTo3D(disparity, calib.q_matrix)[rows, cols]
    np.testing.assert_allclose(points, reference, rtol=1e-4, atol=1e-5)
    back = StereoCalibration.from_q(calib.q_matrix)
    assert (back.focal_px, back.baseline_m, back.cx, back.cy, back.doffs) == pytest.approx(
        (640.0, 0.12, 150.3, 99.7, 3.5))


def test_ply_drop_filled_and_colours():
    depth = np.array([[1.0, 2.0], [np.nan, 4.0]], np.float32)
    colors = np.arange(12, dtype=np.uint8).reshape(2, 2, 3)
    validity = np.array([[Validity.VALID, Validity.FILLED_OCCLUSION], [Validity.OCCLUDED, Validity.VALID]],
                        np.uint8)
    body, count = point_cloud_ply(depth, colors, focal_px=2.0, cx=0.0, cy=0.0)
    vertices = read_ply(body)
    assert count == 3 and len(vertices) == 3
    assert body.startswith(b"ply\nformat binary_little_endian 1.0\n")
    np.testing.assert_allclose(vertices["z"], [1.0, 2.0, 4.0])
    np.testing.assert_allclose(vertices["x"], [0.0, 1.0, 2.0])  # (u - cx) z / f
    np.testing.assert_allclose(vertices["y"], [0.0, 0.0, 2.0])
    assert vertices["red"].tolist() == [0, 3, 9]
    body, count = point_cloud_ply(depth, colors, focal_px=2.0, keep=measured(validity))
    assert count == 2 and read_ply(body)["z"].tolist() == [1.0, 4.0]
    with pytest.raises(ValueError, match="do not match"):
        point_cloud_ply(depth, colors[:1], focal_px=2.0)


def test_depth_files(tmp_path):
    depth = np.array([[1.5, np.nan], [70.0, 0.25]], np.float32)
    assert [depth_format_for_path(name) for name in ("d.npy", "d.PNG", "d.pfm")] == ["npy", "png16", "pfm"]
    with pytest.raises(ValueError, match="depth format"):
        depth_format_for_path("d.jpg")
    stored = np.load(io.BytesIO(encode_depth(depth, "npy")))
    np.testing.assert_array_equal(stored, depth)
    from PIL import Image

    with Image.open(io.BytesIO(encode_depth(depth, "png16"))) as image:
        millimetres = np.asarray(image)
    assert millimetres.tolist() == [[1500, 0], [0, 250]]  # 70 m is beyond uint16 millimetres: 0
    pfm = encode_depth(depth, "pfm")
    target = tmp_path / "d.pfm"
    target.write_bytes(pfm)
    back = read_disparity(target)
    np.testing.assert_array_equal(back[np.isfinite(back)], depth[np.isfinite(depth)])
