"""`adsm predict --data SPEC` with `adsm eval`'s dataset SPECs (issue 12, item 5): kitti2015:PATH on a tiny
KITTI 2015 layout written here, cones:PATH on the shared Cones pair, a dataset kind an extra registers
(made on access, as synthetic:N), and the one-line error for a kind nobody registered."""

from __future__ import annotations

import importlib.metadata
import shutil
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from service.cli import main
from service.datasets import StereoSample, extensions
from service.io import read_disparity
from tests.helpers import ROOT, cones_folder

SHIPPED = ROOT / "service" / "models" / "ncc-baseline"
HEIGHT, WIDTH = 40, 80
SHIFTS = (3, 5, 7)  # pair i's disparity: outputs swapped between pairs would show another


def textured_pair(shift: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """The right view is the left shifted by ``shift`` px (2x2 blocks: NCC-friendly texture)."""
    blocks = np.random.default_rng(seed).integers(0, 256, (HEIGHT // 2, WIDTH // 2 + 8, 3), dtype=np.uint8)
    wide = np.repeat(np.repeat(blocks, 2, axis=0), 2, axis=1)
    # left(x) = wide(x), right(x) = wide(x + shift): the left pixel x is seen at x - shift on the right.
    return np.ascontiguousarray(wide[:, :WIDTH]), np.ascontiguousarray(wide[:, shift:shift + WIDTH])


def write_kitti2015(root: Path) -> None:
    """root/training in KITTI 2015's layout: scenes 000000..000002 (frame 10 with png16 truth), a frame 11
    and a scene without truth, which kitti2015:PATH (adsm eval's pairs) leaves out."""
    folders = {name: root / "training" / name for name in ("image_2", "image_3", "disp_occ_0")}
    for folder in folders.values():
        folder.mkdir(parents=True)
    for index, shift in enumerate(SHIFTS):
        left, right = textured_pair(shift, index)
        name = f"{index:06d}_10.png"
        Image.fromarray(left).save(folders["image_2"] / name)
        Image.fromarray(right).save(folders["image_3"] / name)
        Image.fromarray(np.full((HEIGHT, WIDTH), shift * 256, np.uint16)).save(folders["disp_occ_0"] / name)
        shutil.copy(folders["image_2"] / name, folders["image_2"] / f"{index:06d}_11.png")
    left, right = textured_pair(4, 9)
    Image.fromarray(left).save(folders["image_2"] / "000009_10.png")  # no truth: not one of eval's pairs
    Image.fromarray(right).save(folders["image_3"] / "000009_10.png")


@pytest.fixture
def kitti(tmp_path) -> Path:
    write_kitti2015(tmp_path / "kitti")
    return tmp_path / "kitti"


def _run(capsys, *argv: str) -> tuple[int, str, str]:
    code = main(["predict", *argv])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def _progress(err: str) -> list[str]:
    return [line.split()[1] for line in err.splitlines() if line.startswith("[")]


def test_kitti2015_spec_writes_evals_pairs_named_after_them(capsys, kitti, tmp_path):
    out = tmp_path / "out"
    code, stdout, err = _run(capsys, "--data", f"kitti2015:{kitti}", "--out-dir", str(out), "--format",
                             "npy", "--model", str(SHIPPED), "--no-check")
    assert (code, stdout) == (0, ""), err
    names = [f"{index:06d}_10" for index in range(len(SHIFTS))]
    assert sorted(path.stem for path in out.iterdir()) == names  # no frame 11, no pair without truth
    assert _progress(err) == names and "[3/3]" in err and "pairs/s" in err
    assert err.strip().splitlines()[-1].startswith("adsm: 3 pairs written, 0 skipped, 0 failed")
    for name, shift in zip(names, SHIFTS, strict=True):
        disparity = np.load(out / f"{name}.npy")
        assert disparity.shape == (HEIGHT, WIDTH)
        assert np.nanmedian(np.abs(disparity[8:-8, 16:-8] - shift)) < 0.25, name



def test_dataset_shards_skip_existing_failed_pair_and_calib(capsys, kitti, tmp_path):
    out = tmp_path / "out"
    seen = []
    for shard in ("0/2", "1/2"):
        code, _, err = _run(capsys, "--data", f"kitti2015:{kitti}", "--out-dir", str(out), "--shard", shard,
                            "--max-disparity", "16", "--model", str(SHIPPED), "--no-check")
        assert code == 0, err
        seen += _progress(err)
    assert sorted(seen) == ["000000_10", "000001_10", "000002_10"]  # each pair once
    code, _, err = _run(capsys, "--data", f"kitti2015:{kitti}", "--out-dir", str(out), "--skip-existing",
                        "--max-disparity", "16", "--model", str(SHIPPED))
    assert code == 0 and "0 pairs written, 3 skipped, 0 failed" in err

    # A pair that cannot be decoded fails alone; the others are written; --calib gives each its depth.
    (kitti / "training" / "image_3" / "000001_10.png").write_bytes(b"not an image")
    calib = tmp_path / "calib.txt"  # f = 400 px, B = 0.1 m, doffs = 0: d = 5 -> z = 8 m
    calib.write_text("cam0=[400 0 39.5; 0 400 19.5; 0 0 1]\ncam1=[400 0 39.5; 0 400 19.5; 0 0 1]\n"
                     "baseline=100\n")
    template = str(tmp_path / "m" / "{name}")
    code, _, err = _run(capsys, "--data", f"kitti2015:{kitti}", "-o", template + ".png", "--depth",
                        template + "-z.npy", "--calib", str(calib), "--max-disparity", "16", "--model",
                        str(SHIPPED), "--no-check")
    assert code == 1
    assert "adsm: error: 000001_10: right image" in err and "not a readable image" in err
    assert "2 pairs written, 0 skipped, 1 failed" in err.strip().splitlines()[-1]
    assert sorted(path.name for path in (tmp_path / "m").glob("*.png")) == ["000000_10.png", "000002_10.png"]
    depth = np.load(tmp_path / "m" / "000000_10-z.npy")
    assert np.nanmedian(depth[8:-8, 16:-8]) == pytest.approx(400 * 0.1 / SHIFTS[0], rel=0.03)


def test_cones_spec_names_the_output_after_the_pair(capsys, tmp_path):
    cones = cones_folder()
    code, _, err = _run(capsys, "--data", f"cones:{cones}", "--out-dir", str(tmp_path), "--model",
                        str(SHIPPED))
    assert code == 0, err
    written = tmp_path / f"{cones.name}.png"
    assert [path.name for path in tmp_path.iterdir()] == [written.name]
    disparity = read_disparity(written)
    truth = read_disparity(cones / "disp_left.png")
    known = np.isfinite(truth) & np.isfinite(disparity)
    # The NCC baseline gets most of Cones within 2 px (README: bad-2 about 8 %); a map of another pair
    # or of a wrong search range would not.
    assert known.mean() > 0.8 and (np.abs(disparity - truth)[known] > 2).mean() < 0.2


class Generated(Sequence[StereoSample]):
    """A dataset made on access, as synthetic:N is: pair 1 cannot be drawn, pair 3 repeats pair 0's name."""

    def __init__(self, argument: str) -> None:
        self.count = int(argument)

    def __len__(self) -> int:
        return self.count

    def __getitem__(self, index):  # type: ignore[override]
        if index == 1:
            raise ValueError("the generator failed")
        left, right = textured_pair(SHIFTS[index % 3], index)
        name = "made-0" if index == 3 else f"made-{index}"
        return StereoSample(name, left, right, np.full((HEIGHT, WIDTH), np.nan, np.float32), max_disparity=16)


def open_generated(argument: str) -> Generated:
    return Generated(argument)


def test_a_kind_an_extra_registers_is_drawn_pair_by_pair(capsys, monkeypatch, tmp_path):
    entry = importlib.metadata.EntryPoint(name="made", value=f"{__name__}:open_generated",
                                          group=extensions.ENTRY_POINT_GROUP)
    monkeypatch.setattr(extensions, "registered", lambda: {"made": entry})
    out = tmp_path / "out"
    argv = ("--data", "made:4", "--out-dir", str(out), "--format", "npy", "--model", str(SHIPPED),
            "--no-check")
    code, _, err = _run(capsys, *argv)
    assert code == 1
    assert "adsm: error: pair 1: the generator failed" in err
    assert "adsm: error: made-0: another pair of the dataset has this name" in err
    assert sorted(path.name for path in out.iterdir()) == ["made-0.npy", "made-2.npy"]
    written = np.load(out / "made-2.npy")
    assert np.nanmedian(np.abs(written[8:-8, 16:-8] - SHIFTS[2])) < 0.25

    # Without --max-disparity a pair is searched over the range its dataset recommends (16 here), as adsm
    # eval searches it, not over the model's default (clipped to the 80 px width).
    from service.matcher import Matcher, MatchOptions

    matcher = Matcher.from_folder(SHIPPED)
    left, right = textured_pair(SHIFTS[2], 2)
    recommended = matcher(left, right, MatchOptions(max_disparity=16)).disparity
    np.testing.assert_array_equal(written, recommended)
    assert not np.array_equal(recommended, matcher(left, right, MatchOptions()).disparity, equal_nan=True)
    code, _, err = _run(capsys, *argv, "--skip-existing", "--shard", "0/2")  # pairs 0 and 2
    assert code == 0 and "0 pairs written, 2 skipped, 0 failed" in err


@pytest.mark.parametrize("spec", ["kiti2015:/data/kitti", "middleburry:x"])
def test_unknown_dataset_kind_is_one_line_naming_the_kinds(capsys, tmp_path, spec):
    code, _, err = _run(capsys, "--data", spec, "--out-dir", str(tmp_path))
    assert code == 1
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"adsm: error: --data {spec!r}: unknown dataset kind")
    for kind in ("kitti2012:PATH", "kitti2015:PATH", "middlebury:PATH", "cones:PATH", "synthetic[:N]"):
        assert kind in lines[0]


def test_a_folder_in_a_dataset_layout_reads_as_that_dataset(capsys, tmp_path):
    cones = cones_folder()
    scene = tmp_path / "scenes" / "cones"
    scene.mkdir(parents=True)
    for name in ("left.png", "right.png", "disp_left.png"):
        shutil.copy(cones / name, scene / name)
    code, _, err = _run(capsys, "--data", str(tmp_path / "scenes"), "--out-dir", str(tmp_path / "out"),
                        "--max-disparity", "64", "--model", str(SHIPPED), "--no-check")
    assert code == 0, err
    assert [path.name for path in (tmp_path / "out").iterdir()] == ["cones.png"]
    code, _, err = _run(capsys, "--data", str(tmp_path / "out"), "--out-dir", str(tmp_path / "o2"))
    assert code == 1 and "no pair of folders" in err and "no dataset layout" in err


def test_calibration_of_another_size_scales_or_is_refused_as_over_http(capsys, tmp_path):
    # One rule for CLI and HTTP (StereoCalibration.for_size): Middlebury's full-size calib.txt serves its
    # half-size images, scaled; an aspect ratio that differs is one line naming both sizes.
    left, right = textured_pair(SHIFTS[1], 1)
    Image.fromarray(left).save(tmp_path / "l.png")
    Image.fromarray(right).save(tmp_path / "r.png")
    calib = tmp_path / "calib.txt"  # full size 160x80: f = 800 px there, 400 px at 80x40; B = 0.1 m
    calib.write_text("cam0=[800 0 79.5; 0 800 39.5; 0 0 1]\ncam1=[800 0 79.5; 0 800 39.5; 0 0 1]\n"
                     "baseline=100\nwidth=160\nheight=80\n")
    argv = (str(tmp_path / "l.png"), str(tmp_path / "r.png"), "-o", str(tmp_path / "d.png"), "--depth",
            str(tmp_path / "z.npy"), "--calib", str(calib), "--max-disparity", "16", "--model", str(SHIPPED))
    code, _, err = _run(capsys, *argv)
    assert (code, err) == (0, "")
    depth = np.load(tmp_path / "z.npy")
    assert np.nanmedian(depth[8:-8, 16:-8]) == pytest.approx(400 * 0.1 / SHIFTS[1], rel=0.03)
    calib.write_text(calib.read_text().replace("width=160", "width=200"))
    code, _, err = _run(capsys, *argv)
    assert code == 1 and len(err.strip().splitlines()) == 1
    assert err.startswith("adsm: error: ") and "calibrated for 200x80 images, got 80x40" in err
