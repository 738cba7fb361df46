"""export.baseline: the NCC window and its penalties chosen by the project's one rule, and the shipped folder
holding that choice."""

from __future__ import annotations

import pytest

from export import baseline
from service.features import load_manifest
from tests.helpers import ROOT

SHIPPED = ROOT / "service" / "models" / "ncc-baseline"


@pytest.mark.torch  # the synthetic validation split needs the train extra's generator
def test_measure_tunes_every_window_and_picks_the_lowest_bad2() -> None:
    lines: list[str] = []
    table = baseline.measure(pairs=1, windows=(3, 9), p1_grid=(30.0,), p2_grid=(160.0, 540.0),
                             log=lines.append)
    assert len(lines) == 4  # every window through the whole grid
    assert set(table["windows"]) == {"3", "9"}
    for row in table["windows"].values():  # each window at its own best penalties
        assert row["p2"] in (160.0, 540.0)
    scores = {int(w): (row["bad2"], row["epe"]) for w, row in table["windows"].items()}
    winner = min(scores, key=scores.__getitem__)
    penalties = {key: table["windows"][str(winner)][key] for key in ("p1", "p2")}
    assert table["choice"] == {"window": winner, **penalties}
    assert scores[3] != scores[9]  # the two windows really were matched apart
    assert len(table["penalties"]) == 2 and "synthetic:1" in table["data"]


def test_the_shipped_baseline_is_the_recorded_choice() -> None:
    manifest = load_manifest(SHIPPED)
    selection = manifest["build"]["selection"]
    rows = selection["windows"]
    winner = min(rows, key=lambda w: (rows[w]["bad2"], rows[w]["epe"]))
    assert selection["choice"]["window"] == int(winner)
    assert manifest["config"] == f"ncc-{winner}x{winner}" and manifest["receptive_field"] == int(winner)
    assert (manifest["sgm"]["p1"], manifest["sgm"]["p2"]) == (rows[winner]["p1"], rows[winner]["p2"])
    # the builder's defaults are that choice, so `--window`/`--p1`/`--p2` left out rebuild the shipped folder
    chosen = (int(winner), rows[winner]["p1"], rows[winner]["p2"])
    assert chosen == (baseline.DEFAULT_WINDOW, baseline.SGM_P1, baseline.SGM_P2)
    assert selection["data"].startswith("synthetic:20")
    # and the synthetic figure export.measure recorded is the one the rule chose by
    measured = manifest["metrics"]["synthetic-validation"]["bad2"]
    assert measured == pytest.approx(rows[winner]["bad2"], abs=0.01)
