"""bench time_budget: fresh processes alternating per round, and the verdict against the +10 % budget."""

from __future__ import annotations

import json
import subprocess

import pytest

from bench import time_budget
from bench.__main__ import main as bench_main
from tests.helpers import ROOT

MODELS = ROOT / "service" / "models"


def test_the_verdict_reads_the_ratio_of_the_medians_against_the_budget():
    fits = time_budget.verdict([1.0, 1.2, 1.0], [1.09, 1.0, 1.1])
    assert fits["ratio"] == pytest.approx(1.09) and fits["fits"]
    assert fits["round_ratios"] == pytest.approx([1.09, 0.8333, 1.1], abs=1e-4)
    assert fits["round_median"] == pytest.approx(1.09)
    outside = time_budget.verdict([1.0, 1.0], [1.11, 1.12])
    assert outside["ratio"] > time_budget.TIME_BUDGET and not outside["fits"]
    with pytest.raises(ValueError, match="one time per round"):
        time_budget.verdict([1.0], [1.0, 1.1])
    with pytest.raises(ValueError, match="one time per round"):
        time_budget.verdict([], [])


def test_each_round_starts_a_fresh_process_per_folder_alternating_which_goes_first(
    tmp_path, monkeypatch, capsys
):
    default, candidate = MODELS / "adsm-rf17-int8", MODELS / "adsm-rf17-ncc3-int8"
    seconds = {str(default): 1.0, str(candidate): 1.06}
    started: list[str] = []

    def run(argv, **_):  # type: ignore[no-untyped-def]
        if argv[0] == "git":  # the checkout's commit, for the report
            return subprocess.CompletedProcess(argv, 0, stdout="", stderr="")
        folder = next(arg.split("=", 1)[1] for arg in argv if arg.startswith("--child="))
        started.append(folder)
        return subprocess.CompletedProcess(argv, 0, stdout=f"{json.dumps(seconds[folder])}\n", stderr="")

    monkeypatch.setattr(time_budget.subprocess, "run", run)
    out = tmp_path / "budget.json"
    assert time_budget.main(["--candidate", "adsm-rf17-ncc3-int8", "--default", str(default),
                             "--rounds", "3", "--json", str(out)]) == 0
    assert started == [str(default), str(candidate), str(candidate), str(default), str(default),
                       str(candidate)]
    report = json.loads(out.read_text())
    assert report["ratio"] == pytest.approx(1.06) and report["fits"] and report["rounds"] == 3
    assert report["seconds"] == {"default": [1.0] * 3, "candidate": [1.06] * 3}
    assert "ratio of the medians 1.060x" in capsys.readouterr().out


def test_a_failed_child_or_a_bad_folder_is_one_line(monkeypatch, capsys):
    assert bench_main(["time_budget", "--candidate", "/nonexistent-model-folder"]) == 1
    err = capsys.readouterr().err
    assert "not a model folder" in err and "Traceback" not in err
    monkeypatch.setattr(time_budget.subprocess, "run", lambda argv, **_: subprocess.CompletedProcess(
        argv, argv[0] != "git", stdout="", stderr="Traceback ...\nMemoryError: out of memory\n"))
    assert bench_main(["time_budget", "--candidate", "adsm-rf17-ncc3-int8", "--rounds", "1"]) == 1
    err = capsys.readouterr().err
    assert "MemoryError: out of memory" in err and err.count("\n") == 1
    with pytest.raises(SystemExit) as exit_code:
        bench_main(["time_budget", "--candidate", "adsm-rf17-ncc3-int8", "--rounds", "0"])
    assert exit_code.value.code == 2
