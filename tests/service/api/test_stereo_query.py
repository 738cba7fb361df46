"""The stereo routes' query functions called directly: every refusal is an HTTPException 400, never a 500."""

from __future__ import annotations

import pytest
from fastapi import HTTPException

from service.api.routes.stereo_query import color_range, stereo_options
from service.match_options import MatchOptions


def test_stereo_options_build_match_options() -> None:
    # Annotated Query parameters keep plain defaults, so the dependency is callable as a function.
    options = stereo_options(max_disparity=64, min_disparity=-4, subpixel=False, weighted_median=False,
                             tower_scale=2, lr_check_threshold=1.0, border_surface_run=0, p1=30.0, p2=360.0,
                             right_sgm=False)
    assert options == MatchOptions(max_disparity=64, min_disparity=-4, subpixel=False, weighted_median=False,
                                   tower_scale=2, lr_check_threshold=1.0, border_surface_run=0, p1=30.0,
                                   p2=360.0, right_sgm=False)
    assert stereo_options().right_sgm is MatchOptions().right_sgm is True
    assert stereo_options().lr_check_threshold == MatchOptions().lr_check_threshold
    assert stereo_options().border_surface_run == MatchOptions().border_surface_run


def test_fill_defaults_to_the_check_and_needs_it() -> None:
    assert stereo_options(lr_check=False).fill is False
    with pytest.raises(HTTPException) as refused:
        stereo_options(lr_check=False, fill=True)
    assert refused.value.status_code == 400 and "needs lr_check" in refused.value.detail


@pytest.mark.parametrize("fmt", ["color", "png16"])
def test_no_colormap_range_is_none(fmt: str) -> None:
    assert color_range(None, fmt) is None


@pytest.mark.parametrize(
    ("text", "fmt", "message"),
    [("0,10", "png16", "format=color only"), ("5,5", "color", "below the high end"),
     ("0,1e9", "color", "within"), ("-inf,3", "color", "finite")],
)
def test_bad_colormap_ranges_are_refused(text: str, fmt: str, message: str) -> None:
    with pytest.raises(HTTPException) as refused:
        color_range(text, fmt)
    assert refused.value.status_code == 400 and message in refused.value.detail


def test_colormap_range_parses_two_numbers() -> None:
    assert color_range("-2.5,40", "color") == (-2.5, 40.0)
