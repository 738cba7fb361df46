"""The Motorcycle pair (scikit-image's copy of Middlebury 2014's): the reader, its derived occlusion mask,
and that nothing fits to it (trainer, int8 calibration, synthetic textures)."""

from __future__ import annotations

import numpy as np
import pytest

from export.quantize import calibration_images
from service.datasets import open_dataset
from training.data.evaluation_only import EVALUATION_ONLY, MOTORCYCLE_FILES, MOTORCYCLE_NAME
from training.data.motorcycle import MOTORCYCLE_MAX_DISPARITY, motorcycle_files, visible_in_right
from training.data.synthetic import validation_split
from training.data.synthetic.textures import PHOTOS

# Needs scikit-image's data folder (the train extra) when it runs.
pytestmark = pytest.mark.torch


def test_the_spec_reads_the_pair_with_its_truth_and_range():
    dataset = open_dataset("motorcycle")
    assert len(dataset) == 1 and dataset[:5][0].name == dataset[-1].name == "motorcycle"
    pair = dataset[0]
    assert pair.left.shape == pair.right.shape == (500, 741, 3)
    assert pair.max_disparity == MOTORCYCLE_MAX_DISPARITY
    with np.load(motorcycle_files()[2], allow_pickle=False) as archive:
        raw = archive["arr_0"]
    # Unknown truth (inf in the archive) is NaN; every known value kept exactly, all inside the range.
    np.testing.assert_array_equal(np.isnan(pair.disparity), ~np.isfinite(raw))
    known = pair.disparity[pair.valid]
    np.testing.assert_array_equal(known, raw[np.isfinite(raw)])
    assert 0.9 < pair.valid.mean() < 0.95 and known.min() > 5 and known.max() < MOTORCYCLE_MAX_DISPARITY
    # The derived mask: a tenth of the known pixels occluded, as in Cones (12 %); never an unknown pixel.
    assert not (pair.nonoccluded & ~pair.valid).any()
    assert 0.85 < pair.nonoccluded[pair.valid].mean() < 0.95
    with pytest.raises(IndexError):
        dataset[1]


def test_visible_in_right_matches_the_generators_exact_occlusions():
    """The synthetic scenes' masks are exact (ray-cast): the z-buffer of the left truth alone agrees on
    nearly every pixel and almost never calls a visible pixel occluded (it cannot see occluders that
    only the right view shows, beyond the left image's right edge)."""
    for pair in validation_split(4, camera_effects=False):
        derived, exact = visible_in_right(pair.disparity)[pair.valid], pair.nonoccluded[pair.valid]
        assert (derived == exact).mean() > 0.97, pair.name
        assert (exact & ~derived).mean() < 0.005, pair.name


def test_visible_in_right_marks_the_band_a_step_hides():
    disparity = np.full((3, 40), 4.0, dtype=np.float32)
    disparity[:, 20:30] = 10.0  # a foreground 6 px nearer: the 6 background pixels left of it are hidden
    disparity[1, 5] = np.nan
    visible = visible_in_right(disparity)
    expected = np.ones((3, 40), dtype=bool)
    expected[:, :4] = False      # their match lies left of the right image
    expected[:, 14:20] = False
    expected[1, 5] = False       # unknown truth is never counted
    np.testing.assert_array_equal(visible, expected)


def test_nothing_is_fitted_to_it(tmp_path):
    from training.trainer.batches import BatchSpec, TrainingData

    assert MOTORCYCLE_NAME in EVALUATION_ONLY
    with pytest.raises(ValueError, match="evaluation pair"):
        TrainingData("motorcycle", seed=0, spec=BatchSpec())
    with pytest.raises(ValueError, match="evaluation-only"):
        calibration_images("skimage:motorcycle_left")
    assert not set(MOTORCYCLE_FILES) & set(PHOTOS)
