"""The flags shared by ``adsm predict`` and ``adsm eval`` become the MatchOptions they name."""

from __future__ import annotations

import argparse

import pytest

from service.cli.match_flags import add_match_flags, match_options
from service.match_options import MatchOptions


def parse(*flags: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    parser.add_argument("--max-disparity", type=int)
    add_match_flags(parser.add_argument)
    return parser.parse_args(list(flags))


def test_no_flags_give_the_runtimes_defaults() -> None:
    assert match_options(parse()) == MatchOptions()


def test_flags_set_their_fields() -> None:
    options = match_options(parse("--lr-check-threshold", "1", "--tower-scale", "2", "--p1", "30",
                                  "--no-weighted-median", "--shiftable-windows", "--border-surface-run", "0",
                                  "--no-right-sgm", "--no-border"))
    assert options == MatchOptions(lr_check_threshold=1.0, tower_scale=2, p1=30.0, weighted_median=False,
                                   shiftable_windows=True, border_surface_run=0, right_sgm=False,
                                   border=False)
    assert match_options(parse("--border")).border is True


def test_a_negative_threshold_is_refused_by_match_options() -> None:
    with pytest.raises(ValueError, match="lr_check_threshold"):
        match_options(parse("--lr-check-threshold", "-1"))


def test_a_negative_surface_run_is_refused_by_match_options() -> None:
    with pytest.raises(ValueError, match="border_surface_run"):
        match_options(parse("--border-surface-run", "-1"))
