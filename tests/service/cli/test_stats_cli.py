"""`adsm stats`: the table, the JSON report and bad input (one line, exit 1, nothing computed)."""

from __future__ import annotations

import json
from pathlib import Path

from service.cli import main
from service.datasets import open_dataset
from service.evaluation.scene_statistics import SceneStatistics


def test_json_report_holds_the_figures_of_each_dataset(capsys, cones_dir: Path):
    spec = f"cones:{cones_dir}"
    assert main(["stats", "--data", spec, "--data", str(cones_dir), "--json", "-"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["schema"] == "adsm-stats/1"
    assert [entry["dataset"] for entry in report["datasets"]] == [spec, str(cones_dir)]
    sample = open_dataset(spec)[0]
    expected = SceneStatistics().add(sample.left, sample.right, sample.disparity)
    for entry in report["datasets"]:
        assert entry["pairs"] == 1 and entry["all"] == expected
        assert entry["per_pair"] == [{"name": sample.name, **expected}]
    # Cones is densely textured: far less of it is flat than of the synthetic split (docs/data.md).
    assert expected["texture_flat"] < 20 and expected["depth_edges"] > 15


def test_table_and_report_file(capsys, tmp_path, cones_dir: Path):
    target = tmp_path / "stats.json"
    assert main(["stats", "--data", f"cones:{cones_dir}", "--json", str(target)]) == 0
    captured = capsys.readouterr()
    header, row = captured.out.strip().splitlines()
    assert header.split()[:2] == ["dataset", "pairs"] and row.split()[1] == "1"
    assert "[cones:" in captured.err                                   # progress on stderr
    assert json.loads(target.read_text())["datasets"][0]["pairs"] == 1


def test_bad_input_is_one_line(capsys, tmp_path, cones_dir: Path):
    assert main(["stats", "--data", f"cones:{cones_dir}", "--data", "nonsense:x"]) == 1
    captured = capsys.readouterr()
    assert captured.out == "" and "[cones:" not in captured.err        # the bad SPEC stops it before any pair
    assert len(captured.err.strip().splitlines()) == 1 and captured.err.startswith("adsm: error:")
    assert main(["stats", "--data", f"cones:{cones_dir}", "--json", str(tmp_path)]) == 1
    assert "is a folder" in capsys.readouterr().err
