"""`adsm eval`: a --json report path that cannot be written is refused before the evaluation runs (it was
found only once every pair had been evaluated, and the report was lost)."""

from __future__ import annotations

from pathlib import Path

import pytest

from service.cli import main
from tests.helpers import ROOT

BASELINE = ROOT / "service" / "models" / "ncc-baseline"


@pytest.mark.parametrize("where", ["missing folder", "a folder"])
def test_unwritable_json_report_is_refused_before_evaluating(capsys, tmp_path, cones_dir: Path, where):
    target = tmp_path / "no" / "report.json" if where == "missing folder" else tmp_path
    code = main(["eval", "--model", str(BASELINE), "--data", f"cones:{cones_dir}", "--max-disparity", "16",
                 "--json", str(target)])
    captured = capsys.readouterr()
    assert code == 1 and captured.out == ""
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("adsm: error: --json "), captured.err  # no "[1/1] ..."
    assert ("does not exist" if where == "missing folder" else "is a folder") in lines[0]
