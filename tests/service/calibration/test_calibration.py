"""Calibration readers (Middlebury, KITTI, OpenCV), rectification and the pair diagnostics."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from service.calibration import CalibrationError, StereoCalibration, read_calibration
from service.calibration.pair_check import SWAPPED_SHARE, VERTICAL_PX, check_pair
from service.calibration.rectify import Rectifier
from tests.helpers import cones_folder, require_module

cv2 = require_module("cv2")

MIDDLEBURY = """cam0=[3979.911 0 1244.772; 0 3979.911 1019.507; 0 0 1]
cam1=[3979.911 0 1369.115; 0 3979.911 1019.507; 0 0 1]
doffs=124.343
baseline=193.001
width=2964
height=1988
ndisp=270
isint=0
vmin=23
vmax=245
"""
KITTI = """calib_time: 09-Jan-2012 13:57:47
S_rect_02: 1.242000e+03 3.750000e+02
P_rect_02: 7.215377e+02 0.000000e+00 6.095593e+02 4.485728e+01 0.000000e+00 7.215377e+02 1.728540e+02 \
2.163791e-01 0.000000e+00 0.000000e+00 1.000000e+00 2.745884e-03
P_rect_03: 7.215377e+02 0.000000e+00 6.095593e+02 -3.395242e+02 0.000000e+00 7.215377e+02 1.728540e+02 \
2.199936e+00 0.000000e+00 0.000000e+00 1.000000e+00 2.729905e-03
"""


def _write(folder: Path, name: str, text: str) -> Path:
    path = folder / name
    path.write_text(text)
    return path


def test_middlebury(tmp_path):
    calib = read_calibration(_write(tmp_path, "calib.txt", MIDDLEBURY))
    assert calib.focal_px == pytest.approx(3979.911)
    assert calib.baseline_m == pytest.approx(0.193001)
    assert (calib.cx, calib.cy, calib.doffs) == pytest.approx((1244.772, 1019.507, 124.343))
    assert calib.size == (1988, 2964)
    assert not calib.needs_rectification
    # Middlebury's own formula: Z[mm] = baseline * f / (d + doffs)
    assert calib.depth_of(100.0) == pytest.approx(193.001 * 3979.911 / (100 + 124.343) / 1000)
    half = calib.scaled(0.5)
    assert half.focal_px == pytest.approx(3979.911 / 2) and half.doffs == pytest.approx(124.343 / 2)
    assert half.baseline_m == calib.baseline_m and half.size == (994, 1482)


@pytest.mark.parametrize(
    ("text", "fragment"),
    [
        (MIDDLEBURY.replace("cam0=[3979.911 0 1244.772; ", "cam0=["), "cam0 must be a 3x3 matrix"),
        (MIDDLEBURY.replace("baseline=193.001\n", ""), "no 'baseline=' line"),
        (MIDDLEBURY.replace("doffs=124.343", "doffs=abc"), "not a number"),
        (MIDDLEBURY.replace("baseline=193.001", "baseline=-193"), "baseline must be positive"),
        (MIDDLEBURY + "garbage line\n", "not 'key=value'"),
        ("hello world\n", "unknown calibration format"),
    ],
)
def test_malformed_text_files(tmp_path, text, fragment):
    with pytest.raises(CalibrationError) as caught:
        read_calibration(_write(tmp_path, "calib.txt", text))
    message = str(caught.value)
    assert fragment in message and "calib.txt" in message and "\n" not in message


def test_missing_file(tmp_path):
    with pytest.raises(CalibrationError, match="does not exist"):
        read_calibration(tmp_path / "nope.txt")
    with pytest.raises(CalibrationError, match="does not exist"):
        read_calibration(tmp_path / "nope.yml")


def test_kitti_cam_to_cam_and_per_frame(tmp_path):
    calib = read_calibration(_write(tmp_path, "calib_cam_to_cam.txt", KITTI))
    assert calib.focal_px == pytest.approx(721.5377)
    assert calib.baseline_m == pytest.approx((44.85728 + 339.5242) / 721.5377)  # 0.5327 m
    assert (calib.cx, calib.cy, calib.doffs) == pytest.approx((609.5593, 172.854, 0.0))
    assert calib.size == (375, 1242)
    per_frame = KITTI.replace("P_rect_02:", "P2:").replace("P_rect_03:", "P3:")
    again = read_calibration(_write(tmp_path, "000000.txt", per_frame))
    assert again.baseline_m == pytest.approx(calib.baseline_m)
    with pytest.raises(CalibrationError, match="P_rect_03"):
        read_calibration(_write(tmp_path, "bad.txt", KITTI.split("P_rect_03")[0]))
    with pytest.raises(CalibrationError, match="3x4 matrix"):
        read_calibration(_write(tmp_path, "short.txt", KITTI.replace("2.729905e-03", "")))


def _rig(image_size=(640, 480)):
    """A realistic raw rig and OpenCV's own rectification of it (alpha 0, zero disparity)."""
    k1 = np.array([[700.0, 0, 318.0], [0, 702.0, 243.0], [0, 0, 1]])
    k2 = np.array([[705.0, 0, 325.0], [0, 706.0, 238.0], [0, 0, 1]])
    d1 = np.array([[-0.28, 0.09, 0.001, -0.0005, 0.0]])
    d2 = np.array([[-0.27, 0.08, -0.0008, 0.0003, 0.0]])
    r, _ = cv2.Rodrigues(np.array([0.01, -0.02, 0.005]))
    t = np.array([[-0.12], [0.002], [0.001]])  # metres: right camera 12 cm to the right
    r1, r2, p1, p2, q, _, _ = cv2.stereoRectify(k1, d1, k2, d2, image_size, r, t,
                                                 flags=cv2.CALIB_ZERO_DISPARITY, alpha=0)
    return {"K1": k1, "D1": d1, "K2": k2, "D2": d2, "R": r, "T": t, "R1": r1, "R2": r2, "P1": p1,
            "P2": p2, "Q": q}


def _storage(path: Path, nodes: dict, size=None) -> Path:
    storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    for key, value in nodes.items():
        storage.write(key, value)
    if size is not None:
        storage.write("image_width", size[0])
        storage.write("image_height", size[1])
    storage.release()
    return path


@pytest.mark.parametrize("suffix", [".yml", ".xml"])
def test_opencv_rectified_and_raw(tmp_path, suffix):
    rig = _rig()
    p1, p2 = rig["P1"], rig["P2"]
    expected = (p1[0, 0], -p2[0, 3] / p2[0, 0], p1[0, 2], p1[1, 2], p2[0, 2] - p1[0, 2])

    rectified = read_calibration(_storage(tmp_path / f"pq{suffix}", {"P1": p1, "P2": p2, "Q": rig["Q"]}))
    got = (rectified.focal_px, rectified.baseline_m, rectified.cx, rectified.cy, rectified.doffs)
    assert got == pytest.approx(expected)
    assert not rectified.needs_rectification
    assert rectified.baseline_m == pytest.approx(np.linalg.norm(rig["T"]), rel=1e-6)
    # Q alone reads back the same geometry; our Q reprojects like OpenCV's
    only_q = read_calibration(_storage(tmp_path / f"q{suffix}", {"Q": rig["Q"]}))
    assert (only_q.focal_px, only_q.baseline_m, only_q.cx, only_q.cy) == pytest.approx(expected[:4])
    np.testing.assert_allclose(only_q.q_matrix, rig["Q"], rtol=1e-9, atol=1e-9)

    # stereoCalibrate's output (K D R T, OpenCV sample names M1/M2): rectified here by stereoRectify
    raw_nodes = {"M1": rig["K1"], "D1": rig["D1"], "M2": rig["K2"], "D2": rig["D2"], "R": rig["R"],
                 "T": rig["T"] * 1000}  # millimetres
    raw = read_calibration(_storage(tmp_path / f"raw{suffix}", raw_nodes, size=(640, 480)), units="mm")
    assert raw.needs_rectification and raw.size == (480, 640)
    assert (raw.focal_px, raw.baseline_m, raw.cx, raw.cy, raw.doffs) == pytest.approx(expected)
    np.testing.assert_allclose(raw.rectification.r1, rig["R1"])
    # the same file, images said to be rectified already: no size needed, nothing to rectify
    full = read_calibration(_storage(tmp_path / f"full{suffix}", {**rig}, size=(640, 480)), rectified=True)
    assert not full.needs_rectification


def test_opencv_errors(tmp_path):
    rig = _rig()
    raw = {key: rig[key] for key in ("K1", "D1", "K2", "D2", "R", "T")}
    with pytest.raises(CalibrationError, match="image size"):
        read_calibration(_storage(tmp_path / "nosize.yml", raw))
    assert read_calibration(tmp_path / "nosize.yml", image_size=(480, 640)).size == (480, 640)
    with pytest.raises(CalibrationError, match="no stereo calibration found"):
        read_calibration(_storage(tmp_path / "k.yml", {"K1": rig["K1"]}))
    with pytest.raises(CalibrationError, match="P2 must be 3x4"):
        read_calibration(_storage(tmp_path / "p.yml", {"P1": rig["P1"], "P2": rig["K1"]}))
    (tmp_path / "junk.yml").write_text("%YAML:1.0\n---\nP1: [1, 2\n  : : ]]\n")
    with pytest.raises(CalibrationError, match=r"junk\.yml"):
        read_calibration(tmp_path / "junk.yml")
    swapped = {"P1": rig["P1"], "P2": rig["P2"] * np.array([1, 1, 1, -1])}
    with pytest.raises(CalibrationError, match="swapped"):
        read_calibration(_storage(tmp_path / "swapped.yml", swapped))


def test_rectification_lines_up_rows_and_gives_the_calibrated_disparity(tmp_path):
    """Raw projections of 3-D points, rectified: same row in both views, d = f B / Z with our f, B."""
    rig = _rig()
    calib = read_calibration(_storage(tmp_path / "raw.yml", {k: rig[k] for k in ("K1", "D1", "K2", "D2",
                                                                                 "R", "T")}, size=(640, 480)))
    rng = np.random.default_rng(3)
    points = np.column_stack([rng.uniform(-1, 1, 200), rng.uniform(-0.7, 0.7, 200), rng.uniform(2, 8, 200)])
    left_raw, _ = cv2.projectPoints(points, np.zeros(3), np.zeros(3), rig["K1"], rig["D1"])
    rvec, _ = cv2.Rodrigues(rig["R"])
    right_raw, _ = cv2.projectPoints(points, rvec, rig["T"], rig["K2"], rig["D2"])
    rect = calib.rectification
    left = cv2.undistortPoints(left_raw, rect.k1, rect.d1, R=rect.r1, P=rect.p1).reshape(-1, 2)
    right = cv2.undistortPoints(right_raw, rect.k2, rect.d2, R=rect.r2, P=rect.p2).reshape(-1, 2)
    np.testing.assert_allclose(left[:, 1], right[:, 1], atol=1e-3)
    # depth in the rectified left frame: rotate by R1
    z = (rect.r1 @ points.T)[2]
    disparity = left[:, 0] - right[:, 0]
    np.testing.assert_allclose(calib.focal_px * calib.baseline_m / (disparity + calib.doffs), z, rtol=1e-4)

    # the Rectifier gives exactly OpenCV's own maps + remap
    image = rng.integers(0, 256, (480, 640, 3), dtype=np.uint8)
    left_img, right_img = Rectifier(calib)(image, image[:, ::-1].copy())
    map_x, map_y = cv2.initUndistortRectifyMap(rig["K1"], rig["D1"], rig["R1"], rig["P1"], (640, 480),
                                               cv2.CV_32FC1)
    np.testing.assert_array_equal(left_img, cv2.remap(image, map_x, map_y, cv2.INTER_LINEAR))
    assert right_img.shape == image.shape
    with pytest.raises(CalibrationError, match="calibration is for 640x480"):
        Rectifier(calib)(image[:100], image[:100])
    with pytest.raises(CalibrationError, match="nothing to rectify"):
        Rectifier(StereoCalibration(focal_px=1.0, baseline_m=1.0, cx=0.0, cy=0.0))


@pytest.fixture(scope="module")
def cones():
    from service.io import read_image

    folder = cones_folder()
    return read_image(folder / "left.png"), read_image(folder / "right.png")


def _shift_down(image: np.ndarray, rows: int) -> np.ndarray:
    shifted = np.empty_like(image)
    shifted[rows:] = image[:-rows]
    shifted[:rows] = image[:1]
    return shifted


def test_pair_check_on_cones(cones):
    """Measured (docs/service.md): Cones 1.8 % negative, swapped 98 %; vertical offsets found to 0.1 px."""
    left, right = cones
    normal = check_pair(left, right, max_disparity=64)
    assert normal.negative_share < 0.05 and abs(normal.vertical_offset_px) < 0.5
    assert normal.warnings(valid_share=0.88) == []
    swapped = check_pair(right, left, max_disparity=64)
    assert swapped.negative_share > 0.95 > SWAPPED_SHARE
    assert any("swapped" in warning for warning in swapped.warnings())
    lowered = check_pair(left, _shift_down(right, 3), max_disparity=64)
    assert lowered.vertical_offset_px == pytest.approx(3.0, abs=0.3)
    assert abs(lowered.vertical_offset_px) > VERTICAL_PX
    assert any("rectified" in warning for warning in lowered.warnings())
    assert any("left-right check" in warning for warning in normal.warnings(valid_share=0.3))


@pytest.mark.parametrize("shape", [(64, 32768), (8, 262144), (3, 3), (2048, 6)])
def test_pair_check_judges_nothing_on_strips_too_thin_to_measure(shape):
    # A 64 x 32768 strip reduces to no rows at all; the check must say nothing rather than fail the request.
    rng = np.random.default_rng(0)
    left = rng.integers(0, 256, (*shape, 3), dtype=np.uint8)
    found = check_pair(left, left.copy())
    assert found.voting_pixels == 0 and found.tiles == 0
    assert found.warnings() == []
