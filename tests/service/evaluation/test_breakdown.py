"""The error breakdown of ``adsm eval``: disjoint regions, jump distances, fattening."""

from __future__ import annotations

import numpy as np

from service.evaluation.breakdown import Breakdown, jump_distance, region_masks
from service.validation.codes import VALID, Validity


def step_scene() -> np.ndarray:
    """A 20 x 40 truth: background at 4 px, a foreground square at 12 px in the middle."""
    truth = np.full((20, 40), 4.0, np.float32)
    truth[5:15, 20:30] = 12.0
    truth[0, 39] = np.nan
    return truth


def test_jump_distance_is_zero_on_both_sides_of_a_jump_and_grows_by_one_a_pixel():
    distance = jump_distance(step_scene())
    assert distance[10, 19] == 0 and distance[10, 20] == 0          # both pixels of the jump
    assert distance[10, 17] == 2 and distance[10, 25] == 4
    assert distance[2, 2] == 11                                     # capped


def test_regions_are_disjoint_and_cover_every_ground_truth_pixel():
    truth = step_scene()
    validity = np.full(truth.shape, VALID, np.uint8)
    validity[:, 35:] = Validity.FILLED_MISMATCH
    masks = region_masks(truth, validity)
    stacked = np.stack(list(masks.values())).astype(int)
    assert (stacked.sum(axis=0) == np.isfinite(truth)).all()
    assert masks["border"][:, :4].all() and not masks["border"][:, 4:].any()    # x < 4 px background
    assert masks["rejected"][3, 36] and not masks["accepted"][3, 36]


def test_fattening_counts_the_foreground_bleeding_over_the_background():
    truth = step_scene()
    predicted = truth.copy()
    predicted[5:15, 17:20] = 12.0            # the square grows 3 px to the left: too large there
    predicted[18, 8] = 0.0                   # one error far from any jump, too small
    summary = Breakdown().add(predicted, truth, np.zeros(truth.shape, np.uint8)).summary()
    assert sum(row["share"] for row in summary["regions"].values()) == 100.0
    assert summary["regions"]["border"]["bad2"] == 0.0
    near = summary["accepted_by_jump_distance"][0]
    assert near["distance"] == "0-1" and near["bad2"] > 0 and near["fattening"] == 100.0
    far = summary["accepted_by_jump_distance"][-1]
    assert far["bad2"] > 0 and far["fattening"] == 0.0
    accepted = summary["regions"]["accepted"]["pixels"]
    assert accepted == sum(row["pixels"] for row in summary["accepted_by_jump_distance"])
