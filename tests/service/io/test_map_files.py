"""Encoders behind the HTTP maps: the confidence part (npy / 8-bit PNG), a fixed colour range for
format=color, and depth restricted to measured pixels (drop_filled)."""

from __future__ import annotations

import io

import numpy as np
import pytest
from PIL import Image

from service.geometry import depth_from_disparity, measured
from service.io import encode_disparity
from service.io.colormap import TURBO
from service.io.confidence import encode_confidence


def test_confidence_npy_is_exact_and_png_is_confidence_times_255() -> None:
    confidence = np.array([[0.0, 0.25, 0.5], [0.999, 1.0, np.nan]], np.float32)
    loaded = np.load(io.BytesIO(encode_confidence(confidence, "npy")), allow_pickle=False)
    assert loaded.dtype == np.dtype("<f4")
    np.testing.assert_array_equal(loaded, confidence)
    png = np.asarray(Image.open(io.BytesIO(encode_confidence(confidence, "png"))))
    assert png.dtype == np.uint8 and png.tolist() == [[0, 64, 128], [255, 255, 0]]
    with pytest.raises(ValueError, match="unknown confidence format 'pfm'"):
        encode_confidence(confidence, "pfm")
    with pytest.raises(ValueError, match="float H x W"):
        encode_confidence(np.zeros((2, 2), np.uint8), "npy")


def _colours(disparity: np.ndarray, **range_options) -> np.ndarray:
    return np.asarray(Image.open(io.BytesIO(encode_disparity(disparity, "color", **range_options))))


def test_a_fixed_colour_range_paints_a_value_alike_in_every_frame() -> None:
    near = np.array([[10.0, 20.0, 30.0, np.nan]], np.float32)
    far = np.array([[10.0, 12.0, 14.0, 0.0]], np.float32)
    # Each frame's own range: 20 px is the middle of one frame and beyond the top of the other
    assert not np.array_equal(_colours(near)[0, 0], _colours(far)[0, 1])
    fixed_near, fixed_far = _colours(near, color_range=(0.0, 40.0)), _colours(far, color_range=(0.0, 40.0))
    np.testing.assert_array_equal(fixed_near[0, 0], fixed_far[0, 0])  # 10 px alike in both
    index = np.round(np.array([10.0, 20.0, 30.0]) * 255 / 40).astype(int)
    np.testing.assert_array_equal(fixed_near[0, :3], TURBO[index])
    assert (fixed_near[0, 3] == 0).all() and (fixed_far[0, 3] == 0).all()  # none: black
    clipped = _colours(near, color_range=(15.0, 25.0))[0]  # beyond the range: the end colours
    np.testing.assert_array_equal(clipped[[0, 2]], TURBO[[0, 255]])


def test_depth_of_measured_pixels_only() -> None:
    disparity = np.full((1, 4), 70.0, np.float32)
    validity = np.array([[0, 1, 5, 6]], np.uint8)  # valid, occluded, filled occlusion, filled mismatch
    depth = depth_from_disparity(disparity, focal_px=700, baseline_m=0.1, keep=measured(validity))
    assert depth.tolist()[0][0] == 1.0 and np.isnan(depth[0, 1:]).all()
    with pytest.raises(ValueError, match="keep mask"):
        depth_from_disparity(disparity, focal_px=700, baseline_m=0.1, keep=np.ones((2, 2), bool))
