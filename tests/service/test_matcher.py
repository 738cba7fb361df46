"""Matcher: the checks of a call, options, and end to end on a synthetic slanted plane (default model)."""

from __future__ import annotations

import dataclasses
import shutil

import numpy as np
import pytest

from service.features import ModelError
from service.features.manifest import default_model_dir, load_manifest, write_manifest
from service.filtering import weighted_median
from service.matcher import Matcher, MatchOptions, StereoResult, Validity
from tests.helpers import slanted_plane_pair


@pytest.fixture(scope="module")
def matcher() -> Matcher:
    return Matcher.from_folder(threads=2)


@pytest.mark.slow
def test_slanted_plane_bad1_below_5_percent(matcher: Matcher) -> None:
    left, right, truth, visible = slanted_plane_pair()
    options = MatchOptions(max_disparity=32)
    result = matcher(left, right, options)
    assert isinstance(result, StereoResult)
    assert result.disparity.shape == truth.shape and result.disparity.dtype == np.float32
    assert result.validity.dtype == np.uint8
    error = np.abs(result.disparity - truth)[visible]
    bad1 = np.mean(~(error <= 1.0))  # NaN counts as bad
    assert bad1 < 0.05, f"bad-1 {bad1:.2%}"
    # Sub-pixel precision: integer disparities alone would leave a mean error of ~0.25 px.
    assert np.nanmean(error) < 0.15
    # Shiftable windows run before SGM where the default model's manifest turns them on.
    shifted = ["shiftable_windows"] if matcher.uses_shiftable_windows(options) else []
    assert list(result.timings)[:4 + len(shifted)] == ["towers", "cost_volume", *shifted, "sgm", "disparity"]
    assert list(result.timings)[-1] == "total"
    assert all(seconds >= 0 for seconds in result.timings.values())


def test_switches_change_the_pipeline(matcher: Matcher) -> None:
    left, right, _, _ = slanted_plane_pair(height=40, width=64)
    options = {"max_disparity": 24, "weighted_median": False}
    bare = MatchOptions(**options, sgm=False, subpixel=False, lr_check=False, border=False)
    raw = matcher(left, right, bare)
    assert np.all(raw.validity == Validity.VALID)
    assert np.all(raw.disparity == np.round(raw.disparity))  # integers without sub-pixel
    assert "subpixel" not in raw.timings and "lr_check" not in raw.timings

    shifted = matcher(left, right, MatchOptions(**options, shiftable_windows=True))  # opt-in, before SGM
    assert list(shifted.timings)[1:4] == ["cost_volume", "shiftable_windows", "sgm"]

    unfilled = matcher(left, right, MatchOptions(**options, fill=False, border=False))
    invalid = unfilled.validity != Validity.VALID
    assert invalid.any()  # at least the columns whose match lies left of the right image
    assert set(np.unique(unfilled.validity[invalid])) <= {Validity.OCCLUDED, Validity.MISMATCH}
    assert np.all(np.isnan(unfilled.disparity[invalid])) and not np.isnan(unfilled.disparity[~invalid]).any()

    filled = matcher(left, right, MatchOptions(**options, border=False))
    assert set(np.unique(filled.validity)) <= {
        Validity.VALID, Validity.FILLED_OCCLUSION, Validity.FILLED_MISMATCH, Validity.NO_DATA
    }
    np.testing.assert_array_equal(filled.disparity[~invalid], unfilled.disparity[~invalid])
    assert "fill" in filled.timings and "border" not in filled.timings

    # The border band step, asked for (the default model's manifest turns it off: filling.border_band).
    banded = matcher(left, right, MatchOptions(**options, border=True))
    constant = matcher(left, right, MatchOptions(**options, border=True, adaptive_p2=False))
    assert constant.timings.keys() == banded.timings.keys()
    changed = banded.disparity != filled.disparity
    assert "border" in banded.timings and changed.any()
    assert np.all(banded.validity[changed] == Validity.FILLED_OCCLUSION)
    columns = np.broadcast_to(np.arange(left.shape[1]), changed.shape)
    assert np.all(columns[changed] < banded.disparity[changed])

    default = matcher(left, right, MatchOptions(max_disparity=24, border=True))  # the weighted median, last
    assert list(default.timings)[-2:] == ["weighted_median", "total"]
    assert "weighted_median" not in banded.timings
    np.testing.assert_array_equal(default.disparity, weighted_median(banded.disparity, left))
    np.testing.assert_array_equal(default.validity, banded.validity)


def test_a_stricter_left_right_check_keeps_a_subset_of_the_pixels(matcher: Matcher) -> None:
    # A slanted plane has fractional disparities: rounded, some land one step from the right view's winner.
    left, right, _, _ = slanted_plane_pair(height=40, width=64)
    options = MatchOptions(max_disparity=24, fill=False, border=False, weighted_median=False)
    strict = matcher(left, right, dataclasses.replace(options, lr_check_threshold=0.5))
    loose = matcher(left, right, dataclasses.replace(options, lr_check_threshold=1.0))  # MC-CNN's
    kept, kept_loosely = strict.validity == Validity.VALID, loose.validity == Validity.VALID
    assert not (kept & ~kept_loosely).any() and kept.sum() < kept_loosely.sum()
    np.testing.assert_array_equal(strict.disparity[kept], loose.disparity[kept])


def _near_object_pair(seed: int, width: int = 160, height: int = 48) -> tuple[np.ndarray, ...]:
    """Textured background at disparity 6, a textured near object at 20 over left x = 60..99: left x =
    46..59 is background the right camera does not see (the object hides it)."""
    rng = np.random.default_rng(seed)

    def texture() -> np.ndarray:
        noise = rng.uniform(0, 255, (height, width + 2, 3))
        return (noise[:, :-2] + noise[:, 1:-1] + noise[:, 2:]) / 3.0

    background, near = texture(), texture()
    left = np.empty_like(background)
    left[:, 6:], left[:, :6] = background[:, :-6], texture()[:, :6]
    right = background.copy()
    right[:, 40:80] = near[:, 40:80]
    left[:, 60:100] = near[:, 40:80]
    truth = np.full((height, width), 6.0, np.float32)
    truth[:, 60:100] = 20.0
    return left.round().astype(np.uint8), right.round().astype(np.uint8), truth


def test_the_right_views_own_sgm_pass_rejects_what_the_left_frame_fattened(matcher: Matcher) -> None:
    options = MatchOptions(max_disparity=32, fill=False, border=False, weighted_median=False)
    wrong = {True: 0, False: 0}
    for seed in (5, 6):
        left, right, truth = _near_object_pair(seed)
        unchecked = matcher(left, right, dataclasses.replace(options, lr_check=False))
        for right_sgm in wrong:
            result = matcher(left, right, dataclasses.replace(options, right_sgm=right_sgm))
            kept = result.validity == Validity.VALID
            # Only the check's right winners differ: the left map is the unchecked one where kept.
            np.testing.assert_array_equal(result.disparity[kept], unchecked.disparity[kept])
            wrong[right_sgm] += int(np.sum(np.abs(result.disparity - truth)[kept] > 1))
            assert ("right_sgm" in result.timings) is right_sgm
    # Measured with adsm-fast: 48 wrong pixels kept against 150 (the fattened foreground over x = 46..59,
    # the border columns): the left-aggregated volume's right winners inherit the left frame's fattening.
    assert 2 * wrong[True] < wrong[False], wrong


def test_without_sgm_the_right_views_own_pass_changes_nothing(matcher: Matcher) -> None:
    # Without aggregation both frames hold the same costs: the same right winners, the same result.
    left, right, _ = _near_object_pair(5)
    options = MatchOptions(max_disparity=32, sgm=False)
    own, read_off = (matcher(left, right, dataclasses.replace(options, right_sgm=flag))
                     for flag in (True, False))
    np.testing.assert_array_equal(own.disparity, read_off.disparity)
    np.testing.assert_array_equal(own.validity, read_off.validity)
    assert "right_sgm" not in own.timings


def test_manifest_defaults_and_width_clipping(matcher: Matcher) -> None:
    left, right, _, _ = slanted_plane_pair(height=12, width=10)
    assert matcher.manifest["disparity"]["default_max"] > 10
    result = matcher(left, right)  # D = default_max, clipped to the 10 columns
    assert np.nanmax(result.disparity) <= 9.5
    tiny = np.zeros((1, 1, 3), np.uint8)
    assert matcher(tiny, tiny).disparity.shape == (1, 1)


def test_rejects_a_bad_image_before_any_stage(matcher: Matcher) -> None:
    # The cases are in tests/service/test_match_options.py (colour_images); here only that the call checks.
    with pytest.raises(ValueError, match="differ in size"):
        matcher(np.zeros((8, 8, 3), np.uint8), np.zeros((8, 9, 3), np.uint8))


def test_rejects_options_of_another_type(matcher: Matcher) -> None:
    image = np.zeros((4, 4, 3), np.uint8)
    with pytest.raises(ValueError, match="MatchOptions"):
        matcher(image, image, {"max_disparity": 4})


def test_shiftable_windows_default_to_the_manifest(tmp_path) -> None:
    source = Matcher.from_folder(threads=2)
    folder = tmp_path / "model"
    shutil.copytree(default_model_dir(), folder)
    manifest = load_manifest(folder)
    manifest["sgm"]["shiftable_windows"] = True
    write_manifest(folder, manifest)
    shifted = Matcher.from_folder(folder, threads=2)
    left, right, _, _ = slanted_plane_pair(height=40, width=64)
    default = shifted(left, right, MatchOptions(max_disparity=24))
    assert "shiftable_windows" in default.timings
    off = shifted(left, right, MatchOptions(max_disparity=24, shiftable_windows=False))
    assert "shiftable_windows" not in off.timings
    plain = source(left, right, MatchOptions(max_disparity=24, shiftable_windows=False))
    np.testing.assert_array_equal(off.disparity, plain.disparity)


def test_the_border_band_defaults_to_the_manifest(tmp_path) -> None:
    """filling.border_band: absent -> the step runs; false -> it does not unless a call asks for it."""
    source = Matcher.from_folder(threads=2)
    folder = tmp_path / "model"
    shutil.copytree(default_model_dir(), folder)
    manifest = load_manifest(folder)
    manifest.pop("filling", None)
    write_manifest(folder, manifest)
    absent = Matcher.from_folder(folder, threads=2)
    left, right, _, _ = slanted_plane_pair(height=40, width=64)
    assert "border" in absent(left, right, MatchOptions(max_disparity=24)).timings
    manifest["filling"] = {"border_band": False}
    write_manifest(folder, manifest)
    unbanded = Matcher.from_folder(folder, threads=2)
    default = unbanded(left, right, MatchOptions(max_disparity=24))
    assert "border" not in default.timings
    asked = unbanded(left, right, MatchOptions(max_disparity=24, border=True))
    assert "border" in asked.timings
    np.testing.assert_array_equal(asked.disparity,
                                  source(left, right, MatchOptions(max_disparity=24, border=True)).disparity)
    np.testing.assert_array_equal(default.disparity,
                                  source(left, right, MatchOptions(max_disparity=24, border=False)).disparity)


def test_bad_model_folder_raises_model_error(tmp_path) -> None:
    with pytest.raises(ModelError):
        Matcher.from_folder(tmp_path)


def test_rejects_bad_threads() -> None:
    with pytest.raises(ValueError, match="threads"):
        Matcher.from_folder(threads=0)


def test_reused_volumes_give_the_same_results_as_fresh_ones(matcher: Matcher) -> None:
    kept_matcher = Matcher(matcher.towers, threads=2)
    fresh = Matcher(matcher.towers, threads=2, reuse_volumes=False)
    assert fresh.workspace is None
    # Growing, shrinking and growing again: every view of the kept buffers is written before it is read.
    for height, width, disparities in [(24, 40, 8), (40, 64, 16), (16, 32, 4), (40, 64, 16)]:
        left, right, _, _ = slanted_plane_pair(height=height, width=width, seed=height)
        options = MatchOptions(max_disparity=disparities)
        kept, new = kept_matcher(left, right, options), fresh(left, right, options)
        np.testing.assert_array_equal(kept.disparity, new.disparity)
        np.testing.assert_array_equal(kept.validity, new.validity)
    assert kept_matcher.workspace.nbytes == 2 * 2 * 40 * 64 * 16  # two int16 volumes of the largest call
    kept_matcher.workspace.release()
    assert kept_matcher.workspace.nbytes == 0
