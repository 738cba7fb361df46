"""export.rank: the rule's order with the split's interval, from folders or from adsm eval reports."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from export.baseline import build_folder
from export.rank import LEVEL_MARGIN, main, rank_reports, replaces

# The synthetic validation split needs the train extra's generator (scikit-image's photographs).
pytestmark = pytest.mark.torch


def _report(per_pair: list[float], *, seconds: float = 0.1) -> dict:
    pairs = [{"name": f"synthetic-{index}", "all": {"bad2": value, "bad1": value + 5, "pixels": 1000}}
             for index, value in enumerate(per_pair)]
    mean = sum(per_pair) / len(per_pair)
    return {"all": {"bad2": mean, "bad1": mean + 5, "epe": 1.0}, "seconds_per_pair": seconds,
            "per_pair": pairs}


def test_the_first_is_the_lowest_bad2_and_a_lead_counts_where_its_interval_excludes_zero():
    reports = {"noisy": _report([14.0, 7.0] * 10),        # 0.5 point behind, +-3.5 per pair: SE ~0.78
               "best": _report([10.0] * 20),
               "worse": _report([11.0] * 20)}               # 1 point behind on every pair: SE 0
    rows = rank_reports(reports)
    assert [row.name for row in rows] == ["best", "noisy", "worse"]
    assert [row.behind_first for row in rows] == [False, False, True]
    noisy, worse = rows[1].versus_first, rows[2].versus_first
    assert noisy.difference == pytest.approx(0.5) and worse.difference == pytest.approx(1.0)
    assert 0.6 < noisy.standard_error < 1.0 and not noisy.resolved
    assert worse.standard_error == 0 and worse.resolved
    assert rows[0].versus_first is None


def test_reports_in_and_json_out(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    paths = {}
    for name, values in {"a": [10.0, 12.0, 11.0], "b": [20.0, 22.0, 21.0]}.items():
        paths[name] = tmp_path / f"{name}.json"
        paths[name].write_text(json.dumps(_report(values)), encoding="utf-8")
    out = tmp_path / "rank.json"
    assert main(["--report", f"a={paths['a']}", "--report", f"b={paths['b']}", "--json", str(out)]) == 0
    table = capsys.readouterr().out
    assert table.splitlines()[1].startswith("a ") and "first" in table
    written = json.loads(out.read_text(encoding="utf-8"))
    assert [row["name"] for row in written] == ["a", "b"]
    assert written[1]["behind_first"] is True
    assert written[1]["versus_first"]["difference"] == pytest.approx(10.0)


def test_seeds_of_one_arm_are_pooled_and_bad1_gets_its_interval(tmp_path: Path,
                                                                capsys: pytest.CaptureFixture[str]) -> None:
    # Two seeds per arm; the lever is 1 point of bad-2 (and so of bad-1) lower on every pair of both.
    arms = {"control": [[12.0, 14.0, 13.0, 15.0], [13.0, 15.0, 12.0, 16.0]]}
    arms["lever"] = [[value - 1 for value in seed] for seed in arms["control"]]
    argv = []
    for arm, seeds in arms.items():
        paths = []
        for index, values in enumerate(seeds):
            paths.append(tmp_path / f"{arm}{index}.json")
            paths[-1].write_text(json.dumps(_report(values)), encoding="utf-8")
        argv += ["--report", f"{arm}=" + ",".join(str(path) for path in paths)]
    out = tmp_path / "rank.json"
    assert main([*argv, "--json", str(out)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[1].startswith("lever ") and lines[2].startswith("control ")
    control = json.loads(out.read_text(encoding="utf-8"))[1]
    assert control["bad2"] == pytest.approx(13.75) and control["behind_first"] is True  # (13.5 + 14) / 2
    for key in ("versus_first", "versus_first_bad1"):
        assert control[key]["difference"] == pytest.approx(1.0) and control[key]["pairs"] == 4
    assert lines[2].count("+1.00, 0.00 [+1.00, +1.00]") == 2   # bad-2 and bad-1


def test_folders_are_evaluated_on_the_split(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    for window in (3, 7):
        build_folder(tmp_path / f"ncc{window}", window=window, p1=30.0, p2=360.0)
    assert main([str(tmp_path / "ncc3"), str(tmp_path / "ncc7"), "--pairs", "2", "--threads", "1"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert {line.split()[0] for line in lines[1:]} == {"ncc3", "ncc7"}
    assert "1/2" in lines[2] or "0/2" in lines[2] or "2/2" in lines[2]


@pytest.mark.parametrize(("argv", "code", "message"), [
    ([], 2, "give model folders"),
    (["--report", "a=REPORT", "--pairs", "1"], 2, "--pairs must be >= 2"),
    (["--report", "nameless.json"], 1, "NAME=PATH"),
    (["--report", "a=/nonexistent/report.json"], 1, "cannot read"),
    (["--report", "a=REPORT,"], 1, "NAME=PATH[,PATH...]"),
    (["--report", "a=REPORT,REPORT", "--report", "b=REPORT"], 1, "as many pooled reports"),
    (["--report", "a=REPORT,OTHER"], 1, "a: the reports to pool are not over the same pairs"),
    (["--report", "a=REPORT", "--default", "b"], 1, "--default 'b' names no entry (a)"),
])
def test_bad_input_is_one_line_not_a_traceback(argv, code, message, tmp_path: Path,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    argv = [item.replace("REPORT", str(tmp_path / "r.json")).replace("OTHER", str(tmp_path / "o.json"))
            for item in argv]
    (tmp_path / "r.json").write_text(json.dumps(_report([1.0, 2.0])), encoding="utf-8")
    (tmp_path / "o.json").write_text(json.dumps(_report([1.0, 2.0, 3.0])), encoding="utf-8")
    try:
        returned = main(argv)
    except SystemExit as exit_:
        returned = exit_.code
    assert returned == code
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err


def test_a_missing_folder_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main([str(tmp_path / "nowhere"), "--pairs", "2"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("evaluating") and "export.rank: error:" in err and "Traceback" not in err


def _figures(bad2: list[float], bad1: list[float]) -> dict:
    """A report whose pairs have these bad-2 and bad-1 figures (1000 pixels each)."""
    pairs = [{"name": f"synthetic-{index}", "all": {"bad2": two, "bad1": one, "pixels": 1000}}
             for index, (two, one) in enumerate(zip(bad2, bad1, strict=True))]
    return {"all": {"bad2": sum(bad2) / len(bad2), "bad1": sum(bad1) / len(bad1), "epe": 1.0},
            "seconds_per_pair": 0.1, "per_pair": pairs}


CURRENT = _figures([10.0, 12.0] * 20, [15.0, 17.0] * 20)


@pytest.mark.parametrize(("bad2", "bad1", "verdict", "reason"), [
    # bad-2 0.5 lower on every pair: a resolved lead, whatever bad-1 does
    ([9.5, 11.5] * 20, [16.0, 18.0] * 20, True, "a resolved bad-2 lead (-0.50)"),
    # bad-2 alike, bad-1 0.3 lower on every pair: level and a resolved bad-1 lead
    ([10.0, 12.0] * 20, [14.7, 16.7] * 20, True, "bad-2 level (+0.00, within +-0.1) and a resolved bad-1"),
    # bad-2 0.05 higher on every pair: inside the margin, still level
    ([10.05, 12.05] * 20, [14.7, 16.7] * 20, True, "bad-2 level (+0.05"),
    # bad-2 0.2 higher on every pair: a resolved loss, not bought back by bad-1
    ([10.2, 12.2] * 20, [14.0, 16.0] * 20, False, "a resolved bad-2 loss (+0.20)"),
    # bad-2 level on average but +-1 point per pair: the interval reaches beyond the margin
    ([11.0, 11.0] * 20, [14.0, 16.0] * 20, False, "bad-2 not resolved"),
    # level on both
    ([10.0, 12.0] * 20, [15.0, 17.0] * 20, False, "bad-2 level (+0.00) without a resolved bad-1 lead"),
])
def test_a_folder_replaces_another_on_a_bad2_lead_or_on_bad1_where_bad2_is_level(
        bad2: list[float], bad1: list[float], verdict: bool, reason: str) -> None:
    result = replaces(CURRENT, _figures(bad2, bad1))
    assert result.replaces is verdict and result.reason.startswith(reason)
    assert result.bad2.pairs == 40 and LEVEL_MARGIN == 0.1


def test_the_default_flag_prints_each_entrys_verdict(tmp_path: Path,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    reports = {"current": CURRENT, "sharper": _figures([10.0, 12.0] * 20, [14.7, 16.7] * 20),
               "worse": _figures([10.2, 12.2] * 20, [14.0, 16.0] * 20)}
    argv = []
    for name, report in reports.items():
        (tmp_path / f"{name}.json").write_text(json.dumps(report), encoding="utf-8")
        argv += ["--report", f"{name}={tmp_path / name}.json"]
    out = tmp_path / "rank.json"
    assert main([*argv, "--default", "current", "--json", str(out)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert any(line.startswith("sharper replaces current: bad-2 level") for line in lines)
    assert any(line.startswith("worse does not replace current: a resolved bad-2 loss") for line in lines)
    written = {row["name"]: row for row in json.loads(out.read_text(encoding="utf-8"))}
    assert "replaces_default" not in written["current"]
    assert written["sharper"]["replaces_default"]["replaces"] is True
    assert written["worse"]["replaces_default"]["bad2"]["difference"] == pytest.approx(0.2)
