"""The README's performance table is a committed `python -m bench suite` run, not figures typed by hand.

The README names the JSON under bench/results/; every row of its table must be that run's figures
(rounded as printed), every shipped model must have its rows, and a row whose weights are no longer the
shipped ones (the run's ``files`` sha256 against today's manifest) must say so in its model cell.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from service.features import load_manifest
from tests.helpers import ROOT

MODELS = ROOT / "service" / "models"
SHIPPED = sorted(folder.name for folder in MODELS.iterdir() if (folder / "manifest.json").is_file())
OLDER_WEIGHTS = "(older weights)"
# README column -> (figure of a suite row, decimals printed).
COLUMNS = {
    "towers s": (lambda row: row["median"]["towers"], 3),
    "cost volume s": (lambda row: row["median"]["cost_volume"], 3),
    "SGM s": (lambda row: row["median"]["sgm"], 3),
    "post s": (lambda row: row["median"]["post"], 3),
    "predict s": (lambda row: row["median"]["predict"], 3),
    "cpu s": (lambda row: row["median"]["cpu"], 3),
    "peak RSS MiB": (lambda row: row["peak_rss_mib"], 0),
    "first call s": (lambda row: row["first_call_total"], 3),
}


def performance_section() -> str:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    start = text.index("\n## Performance\n")
    end = text.find("\n## ", start + 1)
    return text[start:end if end >= 0 else None]


def readme_run() -> tuple[Path, dict]:
    named = re.findall(r"bench/results/[\w.+-]+\.json", performance_section())
    assert named, "the README's performance section names no bench/results/*.json"
    assert len(set(named)) == 1, f"one run per table, the README names {sorted(set(named))}"
    path = ROOT / named[0]
    return path, json.loads(path.read_text(encoding="utf-8"))


def readme_rows() -> dict[tuple[str, str], dict[str, str]]:
    lines = performance_section().splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("| model | size |"))
    header = [cell.strip() for cell in lines[start].strip("|").split("|")]
    rows = {}
    for line in lines[start + 2:]:
        if not line.startswith("|"):
            break
        cells = dict(zip(header, (cell.strip() for cell in line.strip("|").split("|")), strict=True))
        name = re.sub(r"\*|\(.*?\)", "", cells["model"]).strip()  # "**NAME** (default)" -> NAME
        rows[(name, cells["size"])] = cells
    return rows


def test_the_run_is_committed_and_says_where_it_ran():
    path, run = readme_run()
    assert path.is_file()
    assert run["command"].startswith("python -m bench suite") and run["machine"] and run["commit"]
    assert run["command"] in performance_section(), "the README must give the command of the run"
    assert not run["commit"].endswith("+dirty"), "a run of uncommitted code cannot be reproduced"


def test_every_row_is_the_runs_figure():
    _, run = readme_run()
    measured = {(row["model"], row["size"]): row for row in run["models"]}
    rows = readme_rows()
    assert sorted(rows) == sorted(measured), "the table must show every row of the run, and only those"
    for key, cells in rows.items():
        for column, (figure, decimals) in COLUMNS.items():
            assert cells[column].replace("*", "") == f"{figure(measured[key]):.{decimals}f}", (key, column)


@pytest.mark.parametrize("name", SHIPPED)
def test_every_shipped_model_has_rows_and_their_weights_are_named(name):
    _, run = readme_run()
    rows = readme_rows()
    measured = [row for row in run["models"] if row["model"] == name]
    assert measured, f"{name} is shipped but not in the README's performance run"
    shipped = {file: entry["sha256"] for file, entry in load_manifest(MODELS / name)["files"].items()}
    for row in measured:
        same = {file: entry["sha256"] for file, entry in row["files"].items()} == shipped
        marked = OLDER_WEIGHTS in rows[(name, row["size"])]["model"]
        assert marked == (not same), (f"{name} at {row['size']}: the run measured "
                                      f"{'the shipped' if same else 'older'} weights, the README row "
                                      f"{'says older' if marked else 'does not say so'}")
