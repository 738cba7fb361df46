"""The stereo routes' camera and map options (issue 13 item 3, issue 12's HTTP side), against the real default
model in process: the confidence part, min_disparity, max_depth / drop_filled, a calibration file instead of
focal_px / baseline_m (Middlebury, KITTI, OpenCV; a raw rig rectified first), colormap_range, the pair
warnings header, the favicon, and that all of it is in the OpenAPI schema.

Every answer is compared with the Python API on the same pair (the Matcher, service.geometry,
service.calibration), so a parameter that does not arrive, or arrives wrong, fails here.
"""

from __future__ import annotations

import io
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
from PIL import Image

from service.api import Settings, create_app
from service.calibration import StereoCalibration
from service.calibration.rectify import Rectifier
from service.calibration.upload import parse_calibration
from service.client.answers import multipart_parts
from service.geometry import depth_from_disparity, measured, read_ply
from service.io import read_image
from service.io.colormap import TURBO
from service.matcher import MatchOptions
from tests.helpers import ROOT, ready_client, require_module

STATIC = ROOT / "service" / "api" / "static"
LEFT, RIGHT = read_image(STATIC / "sample-left.png"), read_image(STATIC / "sample-right.png")
HEIGHT, WIDTH = LEFT.shape[:2]  # 187 x 225, disparities up to 28
D = 32
MIDDLEBURY = (f"cam0=[300 0 111; 0 300 92; 0 0 1]\ncam1=[300 0 115; 0 300 92; 0 0 1]\ndoffs=4\nbaseline=50\n"
              f"width={WIDTH}\nheight={HEIGHT}\n")

pytestmark = pytest.mark.anyio


def png(image: np.ndarray) -> bytes:
    buffer = io.BytesIO()
    Image.fromarray(image).save(buffer, format="PNG")
    return buffer.getvalue()


PAIR = {"left": ("left.png", png(LEFT), "image/png"), "right": ("right.png", png(RIGHT), "image/png")}


def with_calib(text: bytes | str, name: str = "calib.txt", pair: dict | None = None) -> dict[str, Any]:
    data = text.encode() if isinstance(text, str) else text
    return {**(pair or PAIR), "calib": (name, data, "application/octet-stream")}


@pytest.fixture(scope="module")
def anyio_backend() -> str:
    return "asyncio"


@pytest.fixture(scope="module")
async def service():
    app = create_app(Settings(queue_size=2, max_disparity=64))
    async with ready_client(app) as client:
        yield client, app.state.inference.matcher


def ok(response: httpx.Response) -> httpx.Response:
    assert response.status_code == 200, response.text[:400]
    return response


def refused(response: httpx.Response, *fragments: str) -> str:
    assert response.status_code == 400, (response.status_code, response.text[:400])
    detail = response.json()["detail"]
    for fragment in fragments:
        assert fragment in detail, detail
    return detail


def npy(data: bytes) -> np.ndarray:
    return np.load(io.BytesIO(data), allow_pickle=False)


async def test_confidence_part(service) -> None:
    client, matcher = service
    expected = matcher(LEFT, RIGHT, MatchOptions(max_disparity=D, confidence=True))
    for format, kind in (("npy", "npy"), ("pfm", "npy"), ("png16", "png"), ("color", "png")):
        answer = ok(await client.post("/disparity", params={"max_disparity": D, "format": format,
                                                            "confidence": "true"}, files=PAIR))
        parts = multipart_parts(answer.content, answer.headers["content-type"])
        assert list(parts) == ["disparity", "confidence"], format
        media, body = parts["confidence"]
        if kind == "npy":
            assert media == "application/x-npy"
            confidence = npy(body)
            assert confidence.dtype == np.float32
            np.testing.assert_array_equal(confidence, expected.confidence)
        else:
            assert media == "image/png"
            levels = np.asarray(Image.open(io.BytesIO(body)))
            assert levels.dtype == np.uint8
            np.testing.assert_array_equal(levels, np.rint(expected.confidence * 255).astype(np.uint8))
    both = ok(await client.post("/disparity", params={"max_disparity": D, "format": "npy", "validity": "true",
                                                      "confidence": "true"}, files=PAIR))
    parts = multipart_parts(both.content, both.headers["content-type"])
    assert list(parts) == ["disparity", "validity", "confidence"]
    np.testing.assert_array_equal(npy(parts["disparity"][1]), expected.disparity)
    # Not asked: no confidence, and no multipart either
    plain = ok(await client.post("/disparity", params={"max_disparity": D, "format": "npy"}, files=PAIR))
    assert plain.headers["content-type"] == "application/x-npy"


async def test_min_disparity(service) -> None:
    client, matcher = service
    options = {"max_disparity": 16, "min_disparity": 12}
    expected = matcher(LEFT, RIGHT, MatchOptions(**options)).disparity
    answer = npy(ok(await client.post("/disparity", params={**options, "format": "npy"}, files=PAIR)).content)
    np.testing.assert_array_equal(answer, expected)
    assert np.nanmin(answer) >= 12 - 1 and np.nanmax(answer) <= 12 + 16
    depth = npy(ok(await client.post("/depth", params={**options, "focal_px": 300, "baseline_m": 0.05},
                                     files=PAIR)).content)
    np.testing.assert_allclose(depth, depth_from_disparity(expected, focal_px=300, baseline_m=0.05))
    refused(await client.post("/disparity", params={"max_disparity": 16, "min_disparity": 215}, files=PAIR),
            "min_disparity")
    refused(await client.post("/disparity", params={"min_disparity": -WIDTH}, files=PAIR), "min_disparity")
    refused(await client.post("/disparity", params={"min_disparity": "1.5"}, files=PAIR), "min_disparity")


async def test_pointcloud_max_depth_and_drop_filled(service) -> None:
    client, matcher = service
    result = matcher(LEFT, RIGHT, MatchOptions(max_disparity=D))
    camera = {"max_disparity": D, "focal_px": 300.0, "baseline_m": 0.05}
    everything = read_ply(ok(await client.post("/pointcloud", params=camera, files=PAIR)).content)
    full = depth_from_disparity(result.disparity, focal_px=300, baseline_m=0.05)
    assert len(everything) == np.isfinite(full).sum()
    near = {**camera, "max_depth": 1.0}
    answer = ok(await client.post("/pointcloud", params=near, files=PAIR))
    cloud = read_ply(answer.content)
    assert len(cloud) == int(answer.headers["x-point-count"]) == np.sum(full <= 1.0)
    assert cloud["z"].max() <= 1.0 < full[np.isfinite(full)].max()
    measured_only = {**camera, "drop_filled": "true"}
    cloud = read_ply(ok(await client.post("/pointcloud", params=measured_only, files=PAIR)).content)
    keep = measured(result.validity)
    assert len(cloud) == np.sum(np.isfinite(full) & keep) < len(everything)
    # /depth takes the same two, so that the depth map and the cloud agree
    both = {**measured_only, "max_depth": 1.0}
    depth = npy(ok(await client.post("/depth", params=both, files=PAIR)).content)
    expected = depth_from_disparity(result.disparity, focal_px=300, baseline_m=0.05, max_depth=1.0, keep=keep)
    np.testing.assert_array_equal(depth, expected)
    pfm = ok(await client.post("/depth", params={**camera, "format": "pfm"}, files=PAIR))
    assert pfm.content.startswith(b"Pf\n") and pfm.headers["x-depth-format"] == "pfm"
    for bad in ({"max_depth": 0}, {"max_depth": "inf"}, {"max_depth": -1}, {"drop_filled": "maybe"}):
        refused(await client.post("/pointcloud", params={**camera, **bad}, files=PAIR), next(iter(bad)))


async def test_calibration_file_instead_of_focal_and_baseline(service, tmp_path: Path) -> None:
    client, matcher = service
    disparity = matcher(LEFT, RIGHT, MatchOptions(max_disparity=D)).disparity
    calib = parse_calibration(MIDDLEBURY.encode(), filename="calib.txt")
    expected = depth_from_disparity(disparity, focal_px=300, baseline_m=0.05, doffs=4)
    answer = ok(await client.post("/depth", params={"max_disparity": D}, files=with_calib(MIDDLEBURY)))
    np.testing.assert_allclose(npy(answer.content), expected, rtol=1e-6)
    header = answer.headers["x-adsm-calibration"]
    assert "focal_px=300" in header and "baseline_m=0.05" in header and "doffs=4" in header
    assert 'source="calib.txt (Middlebury)"' in header and "rectified=false" in header
    # The same numbers by hand, doffs included, give the same depth
    by_hand = {"max_disparity": D, "focal_px": 300, "baseline_m": 0.05, "doffs": 4}
    np.testing.assert_array_equal(npy(ok(await client.post("/depth", params=by_hand, files=PAIR)).content),
                                  npy(answer.content))
    # The point cloud takes the principal point from the file
    cloud = read_ply(ok(await client.post("/pointcloud", params={"max_disparity": D},
                                          files=with_calib(MIDDLEBURY))).content)
    rows, cols = np.nonzero(np.isfinite(expected))
    np.testing.assert_allclose(cloud["x"], (cols - calib.cx) * expected[rows, cols] / 300,
                               rtol=1e-5, atol=1e-7)
    # A Middlebury file for twice the size is scaled to these images
    double = MIDDLEBURY.replace(f"width={WIDTH}", f"width={2 * WIDTH}").replace(
        f"height={HEIGHT}", f"height={2 * HEIGHT}")
    half = npy(ok(await client.post("/depth", params={"max_disparity": D}, files=with_calib(double))).content)
    np.testing.assert_allclose(half, depth_from_disparity(disparity, focal_px=150, baseline_m=0.05, doffs=2),
                               rtol=1e-6)
    # KITTI and OpenCV files
    kitti = ("P_rect_02: 300 0 111 0 0 300 92 0 0 0 1 0\n"
             "P_rect_03: 300 0 111 -15 0 300 92 0 0 0 1 0\n")
    np.testing.assert_allclose(
        npy(ok(await client.post("/depth", params={"max_disparity": D},
                                 files=with_calib(kitti, "calib_cam_to_cam.txt"))).content),
        depth_from_disparity(disparity, focal_px=300, baseline_m=0.05), rtol=1e-6)
    cv2 = require_module("cv2")
    path = str(tmp_path / "rig.yml")
    storage = cv2.FileStorage(path, cv2.FILE_STORAGE_WRITE)
    storage.write("P1", np.array([[300.0, 0, 111, 0], [0, 300, 92, 0], [0, 0, 1, 0]]))
    storage.write("P2", np.array([[300.0, 0, 111, -15000], [0, 300, 92, 0], [0, 0, 1, 0]]))  # millimetres
    storage.release()
    answer = ok(await client.post("/depth", params={"max_disparity": D, "calib_units": "mm"},
                                  files=with_calib(Path(path).read_bytes(), "rig.yml")))
    np.testing.assert_allclose(npy(answer.content), depth_from_disparity(disparity, focal_px=300,
                                                                         baseline_m=0.05), rtol=1e-6)
    assert 'source="rig.yml (OpenCV)"' in answer.headers["x-adsm-calibration"]


async def test_calibration_refusals(service) -> None:
    client, _ = service
    params = {"max_disparity": D}
    refused(await client.post("/depth", params=params, files=PAIR), "focal_px", "baseline_m", "calib")
    refused(await client.post("/depth", params={**params, "focal_px": 300, "baseline_m": 0.05},
                              files=with_calib(MIDDLEBURY)), "calib", "not both")
    refused(await client.post("/pointcloud", params={**params, "cx": 10}, files=with_calib(MIDDLEBURY)),
            "cx", "calib")
    refused(await client.post("/depth", params={**params, "focal_px": 300, "baseline_m": 0.05,
                                                "calib_units": "mm"}, files=PAIR), "calib_units", "calib")
    refused(await client.post("/depth", params=params, files=with_calib("hello")),
            "calib.txt: unknown calibration format")
    no_baseline = with_calib(MIDDLEBURY.replace("baseline=50", ""))
    refused(await client.post("/depth", params=params, files=no_baseline),
            "calib.txt (Middlebury): no 'baseline=' line")
    wrong_size = MIDDLEBURY.replace(f"height={HEIGHT}", "height=50")
    refused(await client.post("/depth", params=params, files=with_calib(wrong_size)),
            f"calibrated for {WIDTH}x50 images, got {WIDTH}x{HEIGHT}")
    text_field = {**PAIR, "calib": (None, MIDDLEBURY)}
    refused(await client.post("/depth", params=params, files=text_field), "'calib' must be a file")
    inches = {**params, "calib_units": "inch"}
    refused(await client.post("/depth", params=inches, files=with_calib(MIDDLEBURY)), "calib_units")


async def test_a_raw_rig_is_rectified_before_matching(service, tmp_path: Path) -> None:
    client, matcher = service
    cv2 = require_module("cv2")
    k = np.array([[300.0, 0, 112], [0, 300, 93], [0, 0, 1]])
    distortion = np.array([[-0.05, 0.01, 0.0, 0.0, 0.0]])
    rotation, _ = cv2.Rodrigues(np.array([0.0, 0.01, 0.0]))
    translation = np.array([[-0.05], [0.0], [0.0]])
    r1, r2, p1, p2, *_ = cv2.stereoRectify(k, distortion, k, distortion, (WIDTH, HEIGHT), rotation,
                                           translation, flags=cv2.CALIB_ZERO_DISPARITY, alpha=0)
    path = str(tmp_path / "raw.yml")
    storage = cv2.FileStorage(path, cv2.FILE_STORAGE_WRITE)  # stereoRectify's output: a raw rig
    for key, value in {"K1": k, "D1": distortion, "K2": k, "D2": distortion, "R1": r1, "R2": r2, "P1": p1,
                       "P2": p2, "image_width": WIDTH, "image_height": HEIGHT}.items():
        storage.write(key, value)
    storage.release()
    data = Path(path).read_bytes()
    calib = parse_calibration(data, filename="raw.yml", image_size=(HEIGHT, WIDTH))
    assert calib.needs_rectification
    left, right = Rectifier(calib)(LEFT, RIGHT)
    expected = matcher(left, right, MatchOptions(max_disparity=D)).disparity
    answer = ok(await client.post("/disparity", params={"max_disparity": D, "format": "npy"},
                                  files=with_calib(data, "raw.yml")))
    np.testing.assert_array_equal(npy(answer.content), expected)
    assert "rectified=true" in answer.headers["x-adsm-calibration"]
    assert stages(answer)[:2] == ["decode", "rectify"]
    depth = npy(ok(await client.post("/depth", params={"max_disparity": D},
                                     files=with_calib(data, "raw.yml"))).content)
    np.testing.assert_allclose(depth, depth_from_disparity(expected, focal_px=calib.focal_px,
                                                           baseline_m=calib.baseline_m, doffs=calib.doffs),
                               rtol=1e-6)
    # Said to be rectified already: matched as sent (the file's rotations ignored)
    as_sent = ok(await client.post("/disparity", params={"max_disparity": D, "format": "npy",
                                                         "calib_rectified": "true"},
                                   files=with_calib(data, "raw.yml")))
    assert "rectified=false" in as_sent.headers["x-adsm-calibration"]
    plain = matcher(LEFT, RIGHT, MatchOptions(max_disparity=D)).disparity
    np.testing.assert_array_equal(npy(as_sent.content), plain)


async def test_colormap_range(service) -> None:
    client, matcher = service
    disparity = matcher(LEFT, RIGHT, MatchOptions(max_disparity=D)).disparity
    answer = ok(await client.post("/disparity", params={"max_disparity": D, "format": "color",
                                                        "colormap_range": "0,40"}, files=PAIR))
    colours = np.asarray(Image.open(io.BytesIO(answer.content)))
    valid = np.isfinite(disparity) & (disparity > 0)
    index = np.clip(np.round(disparity[valid].astype(np.float64) * 255 / 40), 0, 255).astype(int)
    assert np.mean(np.all(colours[valid] == TURBO[index], axis=1)) > 0.999  # float32 rounding at .5
    automatic = ok(await client.post("/disparity", params={"max_disparity": D, "format": "color"},
                                     files=PAIR))
    assert automatic.content != answer.content
    malformed = ("a,b", "1", "1e9,2e9", "nan,1", "1,2,3", "")
    for bad, fragment in (("5,5", "below"), ("9,1", "below"), *((m, "colormap_range") for m in malformed)):
        params = {"format": "color", "colormap_range": bad}
        refused(await client.post("/disparity", params=params, files=PAIR), fragment)
    refused(await client.post("/disparity", params={"colormap_range": "0,40"}, files=PAIR),
            "colormap_range", "format=color")


def _lowered(image: np.ndarray, rows: int) -> np.ndarray:
    moved = np.empty_like(image)
    moved[rows:] = image[:-rows]
    moved[:rows] = image[:1]
    return moved


def stages(response: httpx.Response) -> list[str]:
    return [metric.split(";")[0].strip() for metric in response.headers["server-timing"].split(",")]


def said(response: httpx.Response) -> list[str]:
    return ok(response).headers.get_list("x-adsm-warning")


async def test_pair_warnings_header(service) -> None:
    client, _ = service
    params = {"max_disparity": D}
    good = ok(await client.post("/disparity", params=params, files=PAIR))
    assert "x-adsm-warning" not in good.headers and "check" in stages(good)
    swapped = {"left": PAIR["right"], "right": PAIR["left"]}
    warnings = said(await client.post("/disparity", params=params, files=swapped))
    assert warnings[0].startswith("swapped: the pair looks swapped: ") and len(warnings) <= 2  # + few-valid
    lowered = {**PAIR, "right": ("right.png", png(_lowered(RIGHT, 3)), "image/png")}
    warnings = said(await client.post("/depth", params={**params, "focal_px": 300, "baseline_m": 0.05},
                                      files=lowered))
    assert any(w.startswith("unrectified: the pair does not look rectified") and "the calib file field" in w
               for w in warnings), warnings
    unrelated = {**PAIR, "right": ("right.png", png(np.ascontiguousarray(LEFT[::-1, ::-1])), "image/png")}
    warnings = said(await client.post("/disparity", params=params, files=unrelated))
    assert any(w.startswith("few-valid: only ") and "wrong max_disparity" in w for w in warnings), warnings
    quiet = ok(await client.post("/disparity", params={**params, "diagnostics": "false"}, files=swapped))
    assert "x-adsm-warning" not in quiet.headers and "check" not in stages(quiet)


async def test_favicon(service) -> None:
    client, _ = service
    icon = await client.get("/favicon.ico")
    assert icon.status_code == 200 and icon.headers["content-type"] == "image/png"
    assert icon.content == (STATIC / "favicon.png").read_bytes()


async def test_the_schema_names_every_new_parameter(service) -> None:
    client, _ = service
    schema = (await client.get("/openapi.json")).json()

    def parameters(path: str) -> set[str]:
        return {parameter["name"] for parameter in schema["paths"][path]["post"]["parameters"]}

    shared = {"min_disparity", "diagnostics", "calib_units", "calib_rectified"}
    assert shared | {"confidence", "colormap_range", "validity"} <= parameters("/disparity")
    camera = {"focal_px", "baseline_m", "doffs", "max_depth", "drop_filled"}
    assert shared | camera <= parameters("/depth")
    assert shared | camera | {"cx", "cy"} <= parameters("/pointcloud")
    for path in ("/disparity", "/depth", "/pointcloud"):
        operation = schema["paths"][path]["post"]
        body = operation["requestBody"]["content"]["multipart/form-data"]["schema"]
        assert body["properties"]["calib"]["format"] == "binary" and body["required"] == ["left", "right"]
        assert {"X-ADSM-Warning", "X-ADSM-Calibration"} <= set(operation["responses"]["200"]["headers"])
    depth_parameters = {p["name"]: p for p in schema["paths"]["/depth"]["post"]["parameters"]}
    assert not depth_parameters["focal_px"]["required"]  # a calib file may give it instead
    assert StereoCalibration  # the type the calib field becomes
