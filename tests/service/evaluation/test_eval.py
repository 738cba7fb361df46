"""Benchmark metrics on hand-made maps, the evaluation loop, and `adsm eval` end to end."""

from __future__ import annotations

import json

import numpy as np
import pytest
from PIL import Image

from service.cli import main
from service.datasets import StereoSample, extensions
from service.evaluation import ErrorCounts, count_errors
from service.evaluation.evaluate import evaluate
from service.io import write_disparity
from service.matcher import MatchOptions, StereoResult
from tests.helpers import ROOT
from training.data.synthetic import Photometric, SyntheticConfig, generate

BASELINE = ROOT / "service" / "models" / "ncc-baseline"


def test_count_errors_counts_every_truth_pixel_and_missing_output_as_error():
    truth = np.array([[10.0, 10.0, 10.0, 100.0, np.nan],
                      [10.0, 10.0, 10.0, 100.0, 5.0]], dtype=np.float32)
    predicted = np.array([[10.5, 11.5, 7.5, 104.5, 3.0],
                          [13.5, np.nan, 10.0, 106.0, np.nan]], dtype=np.float32)
    # 9 truth pixels; errors 0.5 1.5 2.5 4.5 | 3.5 missing 0 6 missing (4.5 of 100 is under D1's 5 %)
    figures = count_errors(predicted, truth).summary()
    assert figures["pixels"] == 9
    assert figures["density"] == pytest.approx(100 * 7 / 9, abs=1e-3)
    for threshold, bad in ((1, 7), (2, 6), (3, 5), (4, 4), (5, 3)):
        assert figures[f"bad{threshold}"] == pytest.approx(100 * bad / 9, abs=1e-3)
    assert figures["d1"] == pytest.approx(100 * 4 / 9, abs=1e-3)     # 3.5 of 10, 6 of 100, 2 missing
    assert figures["epe"] == pytest.approx((0.5 + 1.5 + 2.5 + 4.5 + 3.5 + 0 + 6) / 7, abs=1e-4)


def test_mask_selects_a_subset_and_counts_add_up_pixel_weighted():
    truth = np.full((2, 4), 20.0, dtype=np.float32)
    predicted = truth + np.array([[0, 0, 0, 9], [0, 0, 0, 0]], dtype=np.float32)
    mask = np.array([[1, 1, 1, 0], [1, 1, 1, 1]], dtype=bool)
    assert count_errors(predicted, truth, mask).summary()["bad3"] == 0
    total = ErrorCounts()
    total += count_errors(predicted, truth)                     # 1 bad of 8
    total += count_errors(truth[:1, :2], truth[:1, :2])         # 0 bad of 2
    assert total.summary()["bad3"] == pytest.approx(10.0) and total.summary()["pixels"] == 10
    assert ErrorCounts().summary()["bad2"] is None
    with pytest.raises(ValueError, match="same HxW"):
        count_errors(predicted[:1], truth)


class ShiftedTruth:
    """A stand-in matcher: answers the ground truth plus a known error, and records its options."""

    def __init__(self, samples: list[StereoSample], error: float):
        self.manifest = {"name": "shifted-truth"}
        self.truths = {id(s.left): s.disparity for s in samples}
        self.error, self.calls = error, []

    def __call__(self, left, right, options: MatchOptions) -> StereoResult:
        self.calls.append(options)
        disparity = np.nan_to_num(self.truths[id(left)], nan=0.0) + self.error
        return StereoResult(disparity, np.zeros(disparity.shape, np.uint8), {"towers": 0.5, "sgm": 0.25})


def pair(name: str, *, max_disparity: int | None, mask: bool) -> StereoSample:
    image = np.zeros((4, 6, 3), np.uint8)
    truth = np.full((4, 6), 12.0, np.float32)
    truth[0, 0] = np.nan
    visible = np.ones((4, 6), bool) if mask else None
    return StereoSample(name=name, left=image.copy(), right=image.copy(), disparity=truth,
                        nonoccluded=visible, max_disparity=max_disparity)


def test_evaluate_reports_dataset_figures_and_the_search_range_used():
    samples = [pair("a", max_disparity=64, mask=True), pair("b", max_disparity=None, mask=False)]
    matcher = ShiftedTruth(samples, error=2.5)
    report = evaluate(matcher, samples, options=MatchOptions(max_disparity=32))
    assert report["model"] == "shifted-truth" and report["pairs"] == 2
    assert report["all"]["bad2"] == 100 and report["all"]["bad3"] == 0 and report["all"]["pixels"] == 46
    assert report["all"]["epe"] == pytest.approx(2.5)
    assert report["nonoccluded"]["pixels"] == 23 and report["nonoccluded_pairs"] == 1
    assert report["per_pair"][1]["nonoccluded"] is None
    assert report["stage_seconds"] == {"towers": 0.5, "sgm": 0.25}
    # The dataset's hint fitted to the 6-px width (an explicit range beyond it is refused), else the options'.
    assert [c.max_disparity for c in matcher.calls] == [6, 32]
    evaluate(matcher, samples, max_disparity=48)
    assert [c.max_disparity for c in matcher.calls[2:]] == [48, 48]  # the caller's range wins
    json.dumps(report)


@pytest.fixture
def tiny_cones(tmp_path):
    """A synthetic pair written in the Cones layout (no real pair is needed to test the command)."""
    sample = generate(3, SyntheticConfig(height=48, width=96, max_disparity=16, photometric=Photometric(
        blur_probability=0, jpeg_probability=0)))
    folder = tmp_path / "pair"
    folder.mkdir()
    Image.fromarray(sample.left).save(folder / "left.png")
    Image.fromarray(sample.right).save(folder / "right.png")
    write_disparity(folder / "disp_left.png", sample.disparity, "png16")
    Image.fromarray(np.where(sample.nonoccluded, 255, 0).astype(np.uint8)).save(folder / "nonocc_mask.png")
    return folder


@pytest.mark.torch
def test_adsm_eval_prints_the_table_and_writes_json(tiny_cones, tmp_path, capsys):
    out = tmp_path / "report.json"
    code = main(["eval", "--model", str(BASELINE), "--data", f"cones:{tiny_cones}", "--max-disparity", "24",
                 "--json", str(out)])
    printed = capsys.readouterr()
    assert code == 0, printed.err
    assert "bad-2 %" in printed.out and "nonoccluded" in printed.out and "seconds per pair" in printed.out
    assert "[1/1] pair" in printed.err
    report = json.loads(out.read_text())
    assert report["model"] == "ncc-baseline" and report["pairs"] == 1
    assert report["options"]["max_disparity"] == 24 and report["per_pair"][0]["max_disparity"] == 24
    assert report["all"]["pixels"] == 48 * 96 and report["all"]["density"] > 90
    # A textured synthetic pair at this range: the NCC baseline gets most pixels within 3 px.
    assert report["nonoccluded"]["bad3"] < 50
    assert report["all"]["bad2"] >= report["all"]["bad3"] >= report["all"]["bad5"]


@pytest.mark.torch
def test_adsm_eval_json_to_stdout(tiny_cones, capsys):
    assert main(["eval", "--model", str(BASELINE), "--data", str(tiny_cones), "--json", "-"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["schema"] == "adsm-eval/1" and report["per_pair"][0]["max_disparity"] == 64


@pytest.mark.torch
def test_adsm_eval_errors_are_one_line(tmp_path, capsys):
    assert main(["eval", "--model", str(BASELINE), "--data", "nonsense:x"]) == 1
    assert capsys.readouterr().err.startswith("adsm: error: dataset 'nonsense:x'")
    assert main(["eval", "--model", str(tmp_path), "--data", "synthetic:1"]) == 1
    assert "bad model folder" in capsys.readouterr().err


def test_adsm_eval_synthetic_without_the_train_extra_is_one_line(monkeypatch, capsys):
    monkeypatch.setattr(extensions, "registered", lambda: {})  # as on a serve-only install
    assert main(["eval", "--model", str(BASELINE), "--data", "synthetic:1"]) == 1
    error = capsys.readouterr().err
    assert error.startswith("adsm: error: dataset 'synthetic:1' needs the train extra "
                            "(pip install -e '.[train]')")
    assert error.count("\n") == 1 and "Traceback" not in error


@pytest.mark.torch
def test_adsm_eval_switches_reach_the_matcher(tiny_cones, capsys):
    def options(*flags: str) -> dict:
        assert main(["eval", "--model", str(BASELINE), "--data", str(tiny_cones), "--json", "-", *flags]) == 0
        return json.loads(capsys.readouterr().out)["options"]

    default = options()
    assert default["adaptive_p2"] is True
    assert default["shiftable_windows"] is None and default["border"] is None  # the model's settings
    switched = options("--no-border", "--no-adaptive-p2", "--shiftable-windows")
    assert switched["border"] is False and switched["adaptive_p2"] is False
    assert switched["shiftable_windows"] is True
    assert options("--no-shiftable-windows")["shiftable_windows"] is False
    assert options("--border")["border"] is True


def test_adsm_eval_noise_degrades_the_ncc_baseline_and_is_reported(capsys, cones_dir):
    """On Cones, Gaussian noise of 10 grey levels costs the 7x7 NCC baseline nearly two points of bad-2 (9.60
    -> 11.37 %); the report names the noise."""
    ncc = BASELINE

    def bad2(*flags: str) -> tuple[float, dict]:
        assert main(["eval", "--model", str(ncc), "--data", f"cones:{cones_dir}", "--max-disparity", "64",
                     "--json", "-", *flags]) == 0
        report = json.loads(capsys.readouterr().out)
        return report["all"]["bad2"], report

    clean, report = bad2()
    noisy, noisy_report = bad2("--noise", "10")
    assert report["noise_sigma"] == 0.0 and noisy_report["noise_sigma"] == 10.0
    assert "noise sigma 10" in noisy_report["dataset"]
    assert noisy > clean + 1.0
    assert main(["eval", "--model", str(ncc), "--data", f"cones:{cones_dir}", "--noise", "-2"]) == 1
    assert capsys.readouterr().err.startswith("adsm: error: noise sigma")
