"""The background bias of the ray filling: an occlusion takes the farthest of the first valid pixels to
its left, a mismatch the lower tercile of its rays (hand-made maps; MC-CNN's rules and the border cases:
tests/service/disparity/test_disparity.py)."""

from __future__ import annotations

import numpy as np
import pytest

from service.filling import BACKGROUND_RUN, MC_CNN_FRACTION, MC_CNN_RUN, MISMATCH_FRACTION, fill_invalid
from service.matcher import Matcher, MatchOptions, Validity
from tests.helpers import ROOT


def _row(values: list[float], occluded: list[int]) -> tuple[np.ndarray, np.ndarray]:
    disparity = np.array([values], np.float32)
    validity = np.full(disparity.shape, Validity.VALID, np.uint8)
    validity[0, occluded] = Validity.OCCLUDED
    return disparity, validity


def test_fattened_foreground_left_of_an_occlusion_does_not_fill_it() -> None:
    # Background 2, then a pixel of foreground 6 fattened over it (it passes the check), the occluded
    # hole, the foreground itself: the hole belongs to the background.
    assert BACKGROUND_RUN >= 2
    disparity, validity = _row([2, 2, 2, 2, 2, 6, 0, 0, 0, 6, 6], occluded=[6, 7, 8])
    filled, codes = fill_invalid(disparity, validity)
    np.testing.assert_array_equal(filled[0, 6:9], 2.0)
    assert np.all(codes[0, 6:9] == Validity.FILLED_OCCLUSION)
    first, _ = fill_invalid(disparity, validity, background_run=MC_CNN_RUN)  # MC-CNN copies the foreground
    np.testing.assert_array_equal(first[0, 6:9], 6.0)


def test_only_the_first_run_of_valid_pixels_counts() -> None:
    run = BACKGROUND_RUN
    values = [1.0] * 3 + [4.0] * run + [0.0, 9.0]
    disparity, validity = _row(values, occluded=[3 + run])
    validity[0, 1] = Validity.MISMATCH  # invalid pixels are skipped, not counted
    assert fill_invalid(disparity, validity)[0][0, 3 + run] == 4.0  # the 1s lie beyond the run
    assert fill_invalid(disparity, validity, background_run=run + 1)[0][0, 3 + run] == 1.0
    with pytest.raises(ValueError, match="background_run"):
        fill_invalid(disparity, validity, background_run=0)


def test_mismatch_takes_the_lower_tercile_of_its_rays() -> None:
    # A mismatch at a depth edge, every neighbour valid, so each of the 16 rays stops one step away: 9
    # rays meet the foreground 9 (the 7 to the right and the 2 going down), 5 meet a background 3
    # (up-left, up, left) and 2 a background 5 (down-left).
    disparity = np.full((9, 9), 4.0, np.float32)
    disparity[:, 5:] = 9.0
    disparity[3, 3] = disparity[3, 4] = disparity[4, 3] = 3.0
    disparity[5, 3], disparity[5, 4] = 5.0, 9.0
    validity = np.full(disparity.shape, Validity.VALID, np.uint8)
    validity[4, 4] = Validity.MISMATCH
    rays = np.sort([3.0] * 5 + [5.0] * 2 + [9.0] * 9)
    filled, codes = fill_invalid(disparity, validity)
    assert MISMATCH_FRACTION == (1, 3) and codes[4, 4] == Validity.FILLED_MISMATCH
    assert filled[4, 4] == rays[16 // 3] == 5.0
    median, _ = fill_invalid(disparity, validity, mismatch_fraction=MC_CNN_FRACTION)  # the foreground
    assert median[4, 4] == rays[16 // 2] == 9.0
    for fraction in ((1, 1), (-1, 2), (2, 1)):
        with pytest.raises(ValueError, match="mismatch_fraction"):
            fill_invalid(disparity, validity, mismatch_fraction=fraction)


def _occluding_square() -> tuple[np.ndarray, np.ndarray]:
    """Textured background at disparity 4, a textured square at disparity 12 (columns 40..69 of the left
    view, rows 10..49); the background just left of the square (columns 36..39 and wider) is occluded."""
    rng = np.random.default_rng(3)
    height, width = 60, 112
    background = rng.integers(0, 256, (height, width + 16, 3)).astype(np.uint8)
    square = rng.integers(0, 256, (height, width + 16, 3)).astype(np.uint8)
    right = background[:, 8:8 + width].copy()
    right[10:50, 28:58] = square[10:50, 28:58]
    left = background[:, 4:4 + width].copy()               # background: left x shows right x - 4
    left[10:50, 40:70] = square[10:50, 28:58]              # square: left x shows right x - 12
    return left, right


def test_matcher_switch_changes_only_filled_pixels_and_occlusions_only_towards_the_background() -> None:
    left, right = _occluding_square()
    matcher = Matcher.from_folder(ROOT / "service" / "models" / "ncc-baseline", threads=1)
    options = {"max_disparity": 24, "weighted_median": False, "border": False}
    background, first = (matcher(left, right, MatchOptions(**options, background_fill=on))
                         for on in (True, False))
    changed = background.disparity != first.disparity
    assert changed.any()
    filled_codes = {Validity.FILLED_OCCLUSION, Validity.FILLED_MISMATCH}
    assert set(np.unique(background.validity[changed])) <= filled_codes
    # The run includes the first valid pixel, so the farthest of it is never nearer than MC-CNN's choice.
    occlusions = changed & (background.validity == Validity.FILLED_OCCLUSION)
    assert occlusions.any() and np.all(background.disparity[occlusions] < first.disparity[occlusions])
