"""`adsm predict`: outputs in every format, timings on stderr, one-line errors for bad input."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from service.cli import main
from service.io import read_disparity

SHIPPED = Path(__file__).resolve().parent.parent / "service" / "models" / "ncc-baseline"


@pytest.fixture(scope="module")
def pair(tmp_path_factory) -> tuple[Path, Path]:
    """A small textured pair: the right view is the left shifted by 4 px (disparity 4 everywhere)."""
    folder = tmp_path_factory.mktemp("pair")
    rng = np.random.default_rng(11)
    wide = rng.integers(0, 256, (24, 44, 3), dtype=np.uint8)
    wide = np.repeat(np.repeat(wide, 2, axis=0), 2, axis=1)[:40, :84]  # 2x2 blocks: NCC-friendly texture
    # left(x) = wide(x) and right(x) = wide(x + 4): the left pixel x is seen at x - 4 in the right view.
    Image.fromarray(np.ascontiguousarray(wide[:, :-4])).save(folder / "left.png")
    Image.fromarray(np.ascontiguousarray(wide[:, 4:])).save(folder / "right.png")
    return folder / "left.png", folder / "right.png"


def _run(capsys, *argv: str) -> tuple[int, str, str]:
    code = main(["predict", *argv])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def _assert_one_line_error(code: int, err: str, *fragments: str) -> None:
    assert code == 1
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("adsm: error: "), err
    for fragment in fragments:
        assert fragment in lines[0], (fragment, lines[0])


def test_missing_file(capsys, pair, tmp_path):
    code, _, err = _run(capsys, str(tmp_path / "nope.png"), str(pair[1]), "-o", str(tmp_path / "d.png"))
    _assert_one_line_error(code, err, "left image", "nope.png", "does not exist")


def test_undecodable_image(capsys, pair, tmp_path):
    (tmp_path / "junk.png").write_bytes(b"this is not a png")
    code, _, err = _run(capsys, str(pair[0]), str(tmp_path / "junk.png"), "-o", str(tmp_path / "d.png"))
    _assert_one_line_error(code, err, "right image", "junk.png", "not a readable image")


def test_mismatched_sizes(capsys, pair, tmp_path):
    Image.new("RGB", (30, 20)).save(tmp_path / "small.png")
    code, _, err = _run(capsys, str(pair[0]), str(tmp_path / "small.png"), "-o", str(tmp_path / "d.png"))
    _assert_one_line_error(code, err, "differ in size", "80x40 vs 30x20")


def test_unknown_output_extension(capsys, pair, tmp_path):
    code, _, err = _run(capsys, *map(str, pair), "-o", str(tmp_path / "d.jpg"))
    _assert_one_line_error(code, err, "cannot tell the disparity format", ".pfm")


def test_bad_validity_extension(capsys, pair, tmp_path):
    out, validity = str(tmp_path / "d.png"), str(tmp_path / "v.txt")
    code, _, err = _run(capsys, *map(str, pair), "-o", out, "--validity", validity)
    _assert_one_line_error(code, err, "--validity")


def test_no_traceback_from_the_console_entry(pair, tmp_path):
    out = str(tmp_path / "d.png")
    command = [sys.executable, "-m", "service", "predict", "missing.png", str(pair[1]), "-o", out]
    completed = subprocess.run(command, capture_output=True, text=True, timeout=120, check=False)
    assert completed.returncode == 1
    assert "Traceback" not in completed.stderr
    assert completed.stderr.startswith("adsm: error: left image 'missing.png' does not exist")


def test_bad_model_folder(capsys, pair, tmp_path):
    tampered = tmp_path / "model"
    shutil.copytree(SHIPPED, tampered)
    with open(tampered / "right.onnx", "ab") as stream:
        stream.write(b"\0")
    out = str(tmp_path / "d.png")
    code, _, err = _run(capsys, *map(str, pair), "-o", out, "--model", str(tampered))
    _assert_one_line_error(code, err, "bad model folder", "right.onnx", "sha256")
    code, _, err = _run(capsys, *map(str, pair), "-o", out, "--model", str(tmp_path / "no"))
    _assert_one_line_error(code, err, "bad model folder", "does not exist")


@pytest.mark.parametrize(
    ("name", "extra"), [("d.png", []), ("d.npy", []), ("d.pfm", []), ("c.png", ["--format", "color"])]
)
def test_formats_written(capsys, pair, tmp_path, name, extra):
    out = tmp_path / name
    code, stdout, err = _run(capsys, *map(str, pair), "-o", str(out), "--max-disparity", "16", *extra)
    assert (code, stdout, err) == (0, "", "")
    if "color" in extra:
        with Image.open(out) as image:
            assert image.mode == "RGB" and image.size == (80, 40)
        return
    disparity = read_disparity(out)
    assert disparity.shape == (40, 80)
    inner = disparity[8:-8, 16:-8]
    assert np.nanmedian(np.abs(inner - 4.0)) < 0.25


def test_timings_and_validity_and_switches(capsys, pair, tmp_path):
    out, validity = tmp_path / "d.npy", tmp_path / "v.png"
    code, stdout, err = _run(
        capsys, *map(str, pair), "-o", str(out), "--max-disparity", "16", "--timings", "--validity",
        str(validity), "--no-fill", "--no-border", "--no-subpixel", "--p1", "10", "--p2", "100",
        "--threads", "1",
    )
    assert code == 0 and stdout == ""
    lines = err.strip().splitlines()
    assert len(lines) == 1
    timings = json.loads(lines[0])
    for stage in ("decode", "load_model", "towers", "cost_volume", "sgm", "disparity", "encode", "total"):
        assert timings[stage] >= 0, stage
    assert "fill" not in timings and "border" not in timings
    assert timings["total"] >= timings["towers"] + timings["sgm"]
    disparity = np.load(out)
    finite = disparity[np.isfinite(disparity)]
    np.testing.assert_array_equal(finite, np.round(finite))  # --no-subpixel: integers
    with Image.open(validity) as image:
        codes = np.asarray(image)
    assert codes.shape == (40, 80)
    assert np.isnan(disparity[codes != 0]).all()  # --no-fill --no-border: invalid pixels stay NaN
    assert (codes == 0).mean() > 0.5


def test_bad_option_values(capsys, pair, tmp_path):
    code, _, err = _run(capsys, *map(str, pair), "-o", str(tmp_path / "d.png"), "--max-disparity", "0")
    _assert_one_line_error(code, err)
