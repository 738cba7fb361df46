"""The left border band step (service.filling.border) and its switch in the Matcher."""

from __future__ import annotations

import numpy as np
import pytest

from service.evaluation.breakdown import Breakdown
from service.filling import fill_border_band
from service.matcher import Matcher, MatchOptions
from service.validation.codes import Validity
from training.data.synthetic import SyntheticConfig, generate


def test_band_takes_the_disparity_of_the_surface_it_continues():
    disparity = np.array([[1.0, 2.0, 1.0, 6.0, 6.0, 6.0, 6.0, 2.0]], np.float32)
    validity = np.zeros(disparity.shape, np.uint8)
    validity[0, 3] = Validity.MISMATCH            # rejected pixels are never a reference
    disparity[0, 3] = 30.0
    filled, codes = fill_border_band(disparity, validity)
    # Walking left: x=7 passes the check (reference 2), x=6 (6 >= 2, reference 6), then every x < 6.
    assert filled[0].tolist() == [6.0, 6.0, 6.0, 6.0, 6.0, 6.0, 6.0, 2.0]
    assert codes[0].tolist() == [5, 5, 5, 5, 5, 5, 0, 0]
    assert disparity[0, 3] == 30.0 and validity[0, 3] == Validity.MISMATCH    # inputs untouched


def test_rows_without_a_reference_stay_and_missing_pixels_in_the_band_are_filled():
    disparity = np.array([[np.nan, 0.2, 1.0], [np.nan, np.nan, np.nan]], np.float32)
    validity = np.array([[Validity.NO_DATA, 0, 0], [3, 3, 3]], np.uint8)
    filled, codes = fill_border_band(disparity, validity)
    assert filled[0].tolist() == pytest.approx([0.2, 0.2, 1.0])          # x=0 < 0.2: in the band
    assert codes[0].tolist() == [Validity.FILLED_OCCLUSION, 0, 0]
    assert np.isnan(filled[1]).all() and (codes[1] == Validity.NO_DATA).all()


def test_shapes_are_checked():
    with pytest.raises(ValueError, match="same shape"):
        fill_border_band(np.zeros((2, 3), np.float32), np.zeros((3, 2), np.uint8))


@pytest.mark.torch
def test_the_band_step_cuts_the_border_error_of_a_synthetic_pair():
    pair = generate(11, SyntheticConfig(height=96, width=192, max_disparity=40))
    matcher = Matcher.from_folder("service/models/ncc-baseline", threads=1)
    border = {}
    for enabled in (False, True):
        result = matcher(pair.left, pair.right, MatchOptions(max_disparity=48, border=enabled))
        summary = Breakdown().add(result.disparity, pair.disparity, result.validity).summary()
        border[enabled] = summary["regions"]["border"]["bad2"]
        assert ("border" in result.timings) == enabled
    assert border[True] < border[False] - 10.0
