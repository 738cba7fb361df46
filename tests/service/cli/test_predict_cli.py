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
from tests.helpers import ROOT

SHIPPED = ROOT / "service" / "models" / "ncc-baseline"


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


@pytest.mark.parametrize("flags", [("--max-disparity", "0"), ("--tower-scale", "9")])
def test_bad_option_values(capsys, pair, tmp_path, flags):
    code, _, err = _run(capsys, *map(str, pair), "-o", str(tmp_path / "d.png"), *flags)
    _assert_one_line_error(code, err)
    assert flags[0][2:].replace("-", "_") in err


def test_tower_scale_runs_the_towers_on_the_upsampled_pair(capsys, pair, tmp_path):
    outputs = [tmp_path / "d1.npy", tmp_path / "d2.npy"]
    for scale, out in zip(("1", "2"), outputs, strict=True):
        code, _, err = _run(capsys, *map(str, pair), "-o", str(out), "--max-disparity", "16",
                            "--tower-scale", scale)
        assert code == 0, err
    one, two = (np.load(out) for out in outputs)
    assert one.shape == two.shape == (40, 80) and not np.array_equal(one, two)


# --- calibration, metric outputs, many pairs, 16-bit input, diagnostics (issue 12) ---

CALIB = "cam0=[400 0 39.5; 0 400 19.5; 0 0 1]\ncam1=[400 0 41.5; 0 400 19.5; 0 0 1]\nbaseline=100\n"


def test_depth_and_pointcloud_from_calib(capsys, pair, tmp_path):
    from service.geometry import read_ply

    calib = tmp_path / "calib.txt"
    calib.write_text(CALIB)  # f = 400 px, B = 0.1 m, doffs = 2: d = 4 -> z = 40 / 6 m
    out, depth, cloud = tmp_path / "d.npy", tmp_path / "z.npy", tmp_path / "c.ply"
    code, stdout, err = _run(capsys, *map(str, pair), "-o", str(out), "--max-disparity", "16", "--model",
                             str(SHIPPED), "--calib", str(calib), "--depth", str(depth), "--pointcloud",
                             str(cloud))
    assert (code, stdout, err) == (0, "", "")
    z = np.load(depth)
    assert np.nanmedian(z[8:-8, 16:-8]) == pytest.approx(40 / 6, rel=0.03)
    vertices = read_ply(cloud.read_bytes())
    assert len(vertices) == np.isfinite(z).sum()
    np.testing.assert_allclose(np.sort(vertices["z"]), np.sort(z[np.isfinite(z)]), rtol=1e-6)
    # --drop-filled and --max-depth shrink the cloud; png16 depth is in millimetres
    code, _, err = _run(capsys, *map(str, pair), "-o", str(out), "--max-disparity", "16", "--model",
                        str(SHIPPED), "--calib", str(calib), "--pointcloud", str(cloud), "--drop-filled",
                        "--max-depth", "6.8", "--depth", str(tmp_path / "z.png"))
    assert code == 0, err
    assert 0 < len(read_ply(cloud.read_bytes())) < len(vertices)
    with Image.open(tmp_path / "z.png") as image:
        millimetres = np.asarray(image)
    assert np.median(millimetres[millimetres > 0]) == pytest.approx(6667, rel=0.03)


def test_metric_output_errors(capsys, pair, tmp_path):
    out = str(tmp_path / "d.png")
    code, _, err = _run(capsys, *map(str, pair), "-o", out, "--depth", str(tmp_path / "z.npy"))
    _assert_one_line_error(code, err, "--calib")
    (tmp_path / "calib.txt").write_text("cam0=[1 2 3]\n")
    code, _, err = _run(capsys, *map(str, pair), "-o", out, "--calib", str(tmp_path / "calib.txt"),
                        "--depth", str(tmp_path / "z.npy"))
    _assert_one_line_error(code, err, "calib.txt")
    code, _, err = _run(capsys, *map(str, pair), "-o", out, "--depth", str(tmp_path / "z.jpg"))
    _assert_one_line_error(code, err, "depth format")


def test_unreadable_first_pair_fails_alone_with_a_calibration(capsys, pair, tmp_path):
    # With --calib the first left image's header was read for the calibration's image size, outside the
    # per-pair handling: an unreadable first pair ended the whole batch and no pair was written.
    rig = tmp_path / "rig"
    (rig / "left").mkdir(parents=True)
    (rig / "right").mkdir()
    (rig / "left" / "a.png").write_bytes(b"not an image")
    (rig / "right" / "a.png").write_bytes(b"not an image")
    shutil.copy(pair[0], rig / "left" / "b.png")
    shutil.copy(pair[1], rig / "right" / "b.png")
    (tmp_path / "calib.txt").write_text(CALIB)
    out = tmp_path / "out"
    code, _, err = _run(capsys, "--data", str(rig), "--out-dir", str(out), "--calib",
                        str(tmp_path / "calib.txt"), "--depth", str(out / "{name}-z.npy"),
                        "--max-disparity", "16", "--model", str(SHIPPED))
    assert code == 1 and "adsm: error: a: left image" in err, err
    assert "1 pairs written, 0 skipped, 1 failed" in err.strip().splitlines()[-1]
    assert sorted(path.name for path in out.iterdir()) == ["b-z.npy", "b.png"]


def test_output_over_an_input_image_is_refused(capsys, pair, tmp_path):
    # -o naming the left image (directly, through '..' or a link) used to overwrite it with the map.
    left, right = shutil.copy(pair[0], tmp_path / "l.png"), shutil.copy(pair[1], tmp_path / "r.png")
    (tmp_path / "link.png").symlink_to(left)
    kept = Path(left).read_bytes(), Path(right).read_bytes()
    targets = ((left, left), (tmp_path / "sub" / ".." / "r.png", right), (tmp_path / "link.png", left))
    for target, image in targets:
        code, _, err = _run(capsys, str(left), str(right), "-o", str(target), "--model", str(SHIPPED))
        _assert_one_line_error(code, err, "-o", "input image", str(image), "destroy the input")
    code, _, err = _run(capsys, str(left), str(right), "-o", str(tmp_path / "d.png"), "--validity",
                        str(right), "--model", str(SHIPPED))
    _assert_one_line_error(code, err, "--validity", "input image")
    assert (Path(left).read_bytes(), Path(right).read_bytes()) == kept
    # in a batch the pair fails alone, and its images stay as they were
    rig = tmp_path / "rig"
    (rig / "left").mkdir(parents=True)
    (rig / "right").mkdir()
    shutil.copy(left, rig / "left" / "a.png")
    shutil.copy(right, rig / "right" / "a.png")
    code, _, err = _run(capsys, "--data", str(rig), "-o", str(rig / "left" / "{name}.png"), "--model",
                        str(SHIPPED), "--max-disparity", "16")
    assert code == 1 and "adsm: error: a: -o" in err and "input image" in err, err
    assert (rig / "left" / "a.png").read_bytes() == kept[0]


@pytest.mark.parametrize("flag", ["--validity", "--confidence"])
def test_two_outputs_in_one_file_are_refused(capsys, pair, tmp_path, flag):
    # The map written second used to replace the disparity map silently.
    out = tmp_path / "d.npy"
    code, _, err = _run(capsys, *map(str, pair), "-o", str(out), flag, str(tmp_path / "." / "d.npy"),
                        "--model", str(SHIPPED))
    _assert_one_line_error(code, err, "-o and " + flag, "same file")
    assert not out.exists()


def test_unusable_out_dir_and_pair_list(capsys, pair, tmp_path):
    code, _, err = _run(capsys, "--pairs", str(pair[0]), "--out-dir", str(tmp_path / "o"))
    _assert_one_line_error(code, err, "--pairs", "left.png", "not a UTF-8 text file")
    listing = tmp_path / "pairs.txt"
    listing.write_text(f"{pair[0]} {pair[1]}\n")
    code, _, err = _run(capsys, "--pairs", str(listing), "--out-dir", str(pair[0]))
    _assert_one_line_error(code, err, "--out-dir", "is a file, not a folder")


def test_many_pairs_one_process(capsys, pair, tmp_path):
    rig = tmp_path / "rig"
    (rig / "left").mkdir(parents=True)
    (rig / "right").mkdir()
    for name in ("a", "b", "c"):
        shutil.copy(pair[0], rig / "left" / f"{name}.png")
        shutil.copy(pair[1], rig / "right" / f"{name}.png")
    (rig / "left" / "d.png").write_bytes(b"not an image")  # fails
    (rig / "right" / "d.png").write_bytes(b"not an image")
    shutil.copy(pair[0], rig / "left" / "e.png")  # no right image: fails
    template = str(tmp_path / "out" / "{name}.npy")
    code, stdout, err = _run(capsys, "--data", str(rig), "-o", template, "--max-disparity", "16",
                             "--model", str(SHIPPED), "--validity", str(tmp_path / "out" / "{name}-v.png"))
    assert code == 1 and stdout == ""
    assert sorted(path.name for path in (tmp_path / "out").glob("?.npy")) == ["a.npy", "b.npy", "c.npy"]
    assert (tmp_path / "out" / "a-v.png").is_file()
    assert "adsm: error: d:" in err and "adsm: error: e: no right image" in err
    assert "[3/5] c" in err and "pairs/s" in err
    assert "3 pairs written, 0 skipped, 2 failed" in err.strip().splitlines()[-1]
    # shards partition the pairs; --skip-existing skips written ones; --out-dir names outputs
    listing = tmp_path / "pairs.txt"
    listing.write_text("".join(f"rig/left/{n}.png rig/right/{n}.png\n" for n in ("a", "b", "c")))
    seen = []
    for shard in ("0/2", "1/2"):
        code, _, err = _run(capsys, "--pairs", str(listing), "--out-dir", str(tmp_path / "s"), "--shard",
                            shard, "--max-disparity", "16", "--model", str(SHIPPED))
        assert code == 0, err
        seen.append(sum(line.startswith("[") for line in err.splitlines()))
    assert seen == [2, 1] and len(list((tmp_path / "s").glob("*.png"))) == 3
    code, _, err = _run(capsys, "--pairs", str(listing), "--out-dir", str(tmp_path / "s"), "--skip-existing",
                        "--model", str(SHIPPED))
    assert code == 0 and "0 pairs written, 3 skipped" in err
    code, _, err = _run(capsys, "--data", str(rig), "-o", str(tmp_path / "one.png"))
    _assert_one_line_error(code, err, "{name}")
    code, _, err = _run(capsys, "--pairs", str(listing), "--out-dir", str(tmp_path), "--shard", "2/2")
    _assert_one_line_error(code, err, "--shard")


def test_twelve_bit_grey_png_keeps_its_levels(capsys, tmp_path):
    # The CLI reads through the shared reader (service.io.read_pair, tested in tests/service/io/test_io.py);
    # here the matched pair must be the one read_pair decodes, and a 16-bit colour PNG one line.
    from service.io import read_pair
    from service.matcher import Matcher, MatchOptions

    rng = np.random.default_rng(3)
    texture = rng.integers(0, 4096, (40, 88), dtype=np.uint16)  # 12-bit samples in 16-bit PNGs
    Image.fromarray(np.ascontiguousarray(texture[:, 4:])).save(tmp_path / "l12.png")
    Image.fromarray(np.ascontiguousarray(texture[:, :-4])).save(tmp_path / "r12.png")
    left, right = read_pair(tmp_path / "l12.png", tmp_path / "r12.png")
    assert left.max() > 240 and len(np.unique(left)) > 200  # >> 8 left 16 levels
    code, _, err = _run(capsys, str(tmp_path / "l12.png"), str(tmp_path / "r12.png"), "-o",
                        str(tmp_path / "d.npy"), "--max-disparity", "16", "--model", str(SHIPPED),
                        "--no-check")
    assert code == 0, err
    expected = Matcher.from_folder(SHIPPED)(left, right, MatchOptions(max_disparity=16)).disparity
    np.testing.assert_array_equal(np.load(tmp_path / "d.npy"), expected)

    import zlib as _zlib

    raw = b"".join(b"\0" + np.full((8, 3), 1000, ">u2").tobytes() for _ in range(8))

    def chunk(kind: bytes, body: bytes) -> bytes:
        return (len(body).to_bytes(4, "big") + kind + body
                + _zlib.crc32(kind + body).to_bytes(4, "big"))

    ihdr = (8).to_bytes(4, "big") * 2 + bytes([16, 2, 0, 0, 0])
    rgb16 = tmp_path / "rgb16.png"
    rgb16.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", _zlib.compress(raw))
                      + chunk(b"IEND", b""))
    code, _, err = _run(capsys, str(rgb16), str(rgb16), "-o", str(tmp_path / "d.png"), "--model",
                        str(SHIPPED))
    _assert_one_line_error(code, err, "16-bit colour PNG would lose precision")


def test_swapped_pair_warns_and_exits_zero(capsys, tmp_path, cones_dir):
    cones = cones_dir
    out = str(tmp_path / "d.png")
    code, _, err = _run(capsys, str(cones / "right.png"), str(cones / "left.png"), "-o", out,
                        "--max-disparity", "64")
    assert code == 0
    assert "adsm: warning: right: the pair looks swapped" in err
    code, _, err = _run(capsys, str(cones / "left.png"), str(cones / "right.png"), "-o", out,
                        "--max-disparity", "64")
    assert (code, err) == (0, "")
