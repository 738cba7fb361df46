"""Calibration from bytes (the HTTP ``calib`` field): the same answers as the path readers, one-line
CalibrationErrors for anything else; ``StereoCalibration.for_size``; the pair check's warning kinds."""

from __future__ import annotations

import gzip
from pathlib import Path

import numpy as np
import pytest

from service.calibration import CalibrationError, StereoCalibration, read_calibration
from service.calibration.pair_check import PairCheck
from service.calibration.upload import parse_calibration
from tests.helpers import require_module
from tests.service.calibration.test_calibration import KITTI, MIDDLEBURY, _rig, _storage

cv2 = require_module("cv2")


def _fields(calib: StereoCalibration) -> tuple:
    return (calib.focal_px, calib.baseline_m, calib.cx, calib.cy, calib.doffs, calib.size,
            calib.needs_rectification)


@pytest.mark.parametrize("filename", ["calib.txt", None, "../../etc/calib", "weird name.dat"])
def test_text_formats_read_as_from_a_file(tmp_path: Path, filename: str | None) -> None:
    for text, name in ((MIDDLEBURY, "calib.txt"), (KITTI, "calib_cam_to_cam.txt")):
        path = tmp_path / name
        path.write_text(text)
        assert _fields(parse_calibration(text.encode(), filename=filename)) == _fields(read_calibration(path))


def test_opencv_by_suffix_and_by_header(tmp_path: Path) -> None:
    rig = _rig()
    raw = {key: rig[key] for key in ("K1", "D1", "K2", "D2", "R", "T")}
    for suffix in (".yml", ".xml"):
        rectified = _storage(tmp_path / f"pq{suffix}", {"P1": rig["P1"], "P2": rig["P2"]})
        expected = _fields(read_calibration(rectified))
        data = rectified.read_bytes()
        assert _fields(parse_calibration(data, filename=f"rig{suffix}")) == expected
        # no telling name: OpenCV's own header (%YAML, <?xml) says it
        assert _fields(parse_calibration(data, filename="upload")) == expected
        assert parse_calibration(data).source.endswith("(OpenCV)")
    gz = tmp_path / "rig.yml.gz"
    gz.write_bytes(gzip.compress((tmp_path / "pq.yml").read_bytes()))
    assert _fields(parse_calibration(gz.read_bytes(), filename="rig.yml.gz")) == expected
    # a raw rig (K D R T) needs the image size, which the service knows from the images' headers
    data = _storage(tmp_path / "raw.yml", raw).read_bytes()
    with pytest.raises(CalibrationError, match="image size"):
        parse_calibration(data, filename="raw.yml")
    calib = parse_calibration(data, filename="raw.yml", image_size=(480, 640), units="m")
    assert calib.needs_rectification and calib.size == (480, 640)
    assert not parse_calibration(_storage(tmp_path / "full.yml", rig, size=(640, 480)).read_bytes(),
                                 filename="full.yml", rectified=True).needs_rectification


@pytest.mark.parametrize(
    ("data", "filename", "fragment"),
    [
        (b"", "calib.txt", "calib.txt: the calibration file is empty"),
        (b"\xff\xfe\x00garbage", "calib.txt", "calib.txt: not a text file"),
        (b"x" * (1 << 20 + 1), "big.txt", "too large"),
        (b"hello world", "notes.txt", "notes.txt: unknown calibration format"),
        (b"cam0=[1 2 3]\ncam1=[1]\nbaseline=1", "c.txt", "c.txt (Middlebury): cam0 must be a 3x3 matrix"),
        (b"%YAML:1.0\n---\nP1: [1, 2\n  : : ]]\n", "rig.yml", "rig.yml (OpenCV)"),
        (b"%YAML:1.0\n---\nfoo: 1\n", None, "calib.yml (OpenCV): no stereo calibration found"),
        (b"<?xml version='1.0'?><opencv_storage><P1>1", "x", "x.xml (OpenCV)"),
        (b"\x1f\x8b\x08not really gzip", "rig.yml.gz", "rig.yml.gz (OpenCV)"),
        (b"{\"Q\": [1, 2, 3]}", "q.json", "q.json (OpenCV)"),
        (MIDDLEBURY.replace("baseline=193.001", "baseline=-193").encode(), "c.txt", "swapped"),
        (MIDDLEBURY.replace("height=1988", "height=1e400").encode(), "c.txt", "non-finite"),
        # A top level that is a list or a value: OpenCV's keys() raised a cv2.error (an HTTP 500).
        (b"[1]", "rig.json", "rig.json (OpenCV): the top level must name its nodes"),
        (b"%YAML:1.0\n- 1\n", "rig.yml", "rig.yml (OpenCV): the top level must name its nodes"),
        # Deep nesting overflowed OpenCV's recursive parsers: a segfault that ended the server process.
        (b"[" * 100_000 + b"]" * 100_000, "rig.json", "rig.json (OpenCV): nested 100000 levels deep"),
        (b"%YAML:1.0\nP1: " + b"- " * 100_000 + b"1\n", "rig.yml", "levels deep"),
        (b"%YAML:1.0\n" + b"a: " * 100_000 + b"1\n", "rig.yml", "levels deep"),
        (b"<?xml version='1.0'?><opencv_storage>" + b"<a>" * 100_000 + b"</a>" * 100_000
         + b"</opencv_storage>", "rig.xml", "levels deep"),
        (gzip.compress(b"%YAML:1.0\nP1: " + b"- " * 100_000 + b"1\n"), "rig.yml.gz", "levels deep"),
        (gzip.compress(b"%YAML:1.0\nP1: [" + b"1, " * 400_000 + b"1]\n"), "rig.yml.gz", "unpacks to more"),
    ],
)
def test_bad_uploads_are_one_line(data: bytes, filename: str | None, fragment: str) -> None:
    with pytest.raises(CalibrationError) as error:
        parse_calibration(data, filename=filename)
    message = str(error.value)
    assert fragment in message and "\n" not in message and "adsm-calib-" not in message, message


def test_for_size_scales_or_refuses() -> None:
    calib = StereoCalibration(focal_px=1000.0, baseline_m=0.2, cx=499.5, cy=299.5, doffs=40.0,
                              size=(600, 1000), source="c.txt")
    assert calib.for_size(600, 1000) is calib
    assert StereoCalibration(focal_px=1.0, baseline_m=1.0, cx=0.0, cy=0.0).for_size(5, 7).size is None
    half = calib.for_size(300, 500)
    assert (half.focal_px, half.cx, half.doffs, half.size) == (500.0, 249.5, 20.0, (300, 500))
    assert calib.for_size(301, 500).size == (300, 500)  # within a pixel: Middlebury's odd sizes
    with pytest.raises(CalibrationError, match=r"c\.txt: calibrated for 1000x600 images, got 500x400"):
        calib.for_size(400, 500)
    for size in ((0, 1000), (600, 0)):
        zero = StereoCalibration(focal_px=1.0, baseline_m=1.0, cx=0.0, cy=0.0, size=size)
        with pytest.raises(CalibrationError, match="calibrated for"):
            zero.for_size(600, 1000)


def test_pair_check_kinds_and_remedies() -> None:
    bad = PairCheck(negative_share=0.9, vertical_offset_px=2.0, vertical_spread_px=0.5, tiles=9,
                    voting_pixels=100, scale=1)
    kinds = [kind for kind, _ in bad.findings(valid_share=0.2)]
    assert kinds == ["swapped", "unrectified", "few-valid"]
    assert bad.warnings(valid_share=0.2) == [sentence for _, sentence in bad.findings(valid_share=0.2)]
    assert "(--calib)" in bad.warnings()[1] and "--max-disparity" in bad.warnings(valid_share=0.2)[2]
    http = bad.findings(valid_share=0.2, calibration="the calib field", disparity_range="max_disparity")
    assert "(the calib field)" in http[1][1] and "wrong max_disparity," in http[2][1]
    good = PairCheck(negative_share=0.02, vertical_offset_px=0.0, vertical_spread_px=0.0, tiles=9,
                     voting_pixels=100, scale=1)
    assert good.findings(valid_share=0.9) == [] and np.isfinite(good.negative_share)
