"""MatchOptions' checks and colour_images, the input check every match call starts with."""

from __future__ import annotations

import numpy as np
import pytest

from service.match_options import MatchOptions, colour_images


@pytest.mark.parametrize(
    ("left", "right", "message"),
    [
        (np.zeros((8, 8, 3), np.float32), np.zeros((8, 8, 3), np.uint8), "left image must be a uint8"),
        (np.zeros((8, 8), np.uint16), np.zeros((8, 8), np.uint16), "scale 16-bit samples"),
        (np.zeros((8, 8, 2), np.uint8), np.zeros((8, 8, 2), np.uint8), "shape"),
        (np.zeros((8, 8, 4), np.uint8), np.zeros((8, 8, 4), np.uint8), "shape"),
        (np.zeros((8, 8, 3), np.uint8), [[0]], "right image"),
        (np.zeros((8, 8, 3), np.uint8), np.zeros((8, 9, 3), np.uint8), "differ in size"),
        (np.zeros((0, 8, 3), np.uint8), np.zeros((0, 8, 3), np.uint8), "empty"),
    ],
)
def test_rejects_bad_images(left, right, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        colour_images(left, right)


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"max_disparity": 0}, "max_disparity"),
        ({"max_disparity": 2.5}, "max_disparity"),
        ({"max_disparity": True}, "max_disparity"),
        ({"p1": -1.0}, "p1"),
        ({"p2": float("inf")}, "p2"),
        ({"p2": "160"}, "p2"),
        ({"p2": 4097.0}, "p2"),
        ({"fill": "yes"}, "fill"),
        ({"right_sgm": 1}, "right_sgm"),
        ({"shiftable_windows": "yes"}, "shiftable_windows"),
        ({"lr_check_threshold": -0.5}, "lr_check_threshold"),
        ({"lr_check_threshold": float("nan")}, "lr_check_threshold"),
        ({"lr_check_threshold": True}, "lr_check_threshold"),
        ({"lr_check_threshold": "1"}, "lr_check_threshold"),
        ({"border": "yes"}, "border"),
        ({"border_surface_run": -1}, "border_surface_run"),
        ({"border_surface_run": 2.5}, "border_surface_run"),
        ({"border_surface_run": False}, "border_surface_run"),
    ],
)
def test_rejects_bad_options(options: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        MatchOptions(**options)


@pytest.mark.parametrize("shape", [(5, 7), (5, 7, 1)])
def test_grey_images_become_three_equal_channels(shape: tuple[int, ...]) -> None:
    grey = np.arange(35, dtype=np.uint8).reshape(shape)
    left, right = colour_images(grey, grey)
    assert left.shape == right.shape == (5, 7, 3)
    np.testing.assert_array_equal(left, np.repeat(grey.reshape(5, 7, 1), 3, axis=2))


def test_colour_images_pass_through_unchanged() -> None:
    image = np.random.default_rng(0).integers(0, 256, (4, 6, 3), dtype=np.uint8)
    left, right = colour_images(image, image)
    assert left is image and right is image
