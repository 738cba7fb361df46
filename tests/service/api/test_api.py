"""HTTP API against the real default model: every endpoint, format and error code (small 64x96 pairs)."""

from __future__ import annotations

import email.parser
import io
import json
import re
import zlib

import httpx
import numpy as np
import pytest
from PIL import Image

from service.api import Settings, create_app
from service.api.app import DESCRIPTION
from service.api.routes.ops import public_manifest
from service.features import default_model_dir, load_manifest
from service.io import read_disparity
from service.validation import Validity
from tests.helpers import ready_client

SHIFT = 4  # true disparity of the synthetic pair
HEIGHT, WIDTH = 64, 96
SETTINGS = Settings(
    queue_size=2, max_body_bytes=120_000, max_pixels=HEIGHT * WIDTH, max_disparity=32,
    max_cost_cells=HEIGHT * WIDTH * 16,
)
INTERIOR = (slice(8, HEIGHT - 8), slice(16, WIDTH - 8))  # away from borders and the occluded left strip


def png(image: np.ndarray) -> bytes:
    buffer = io.BytesIO()
    Image.fromarray(image).save(buffer, format="PNG")
    return buffer.getvalue()


def stereo_pair(height: int = HEIGHT, width: int = WIDTH, shift: int = SHIFT) -> tuple[np.ndarray, ...]:
    """Random texture seen with disparity ``shift``: left[y, x] == right[y, x - shift]."""
    texture = np.random.default_rng(7).integers(0, 256, (height, width + shift, 3), dtype=np.uint8)
    return np.ascontiguousarray(texture[:, :width]), np.ascontiguousarray(texture[:, shift:])


LEFT, RIGHT = stereo_pair()
PAIR = {"left": ("left.png", png(LEFT), "image/png"), "right": ("right.png", png(RIGHT), "image/png")}


@pytest.fixture(scope="module")
def anyio_backend() -> str:
    return "asyncio"


@pytest.fixture(scope="module")
async def client():
    async with ready_client(create_app(SETTINGS)) as client:
        yield client


def stage_names(response: httpx.Response) -> list[str]:
    return [metric.split(";")[0].strip() for metric in response.headers["server-timing"].split(",")]


def npy(response: httpx.Response) -> np.ndarray:
    return np.load(io.BytesIO(response.content), allow_pickle=False)


pytestmark = pytest.mark.anyio


# --- operations -------------------------------------------------------------------------------------------

async def test_health_and_readiness(client: httpx.AsyncClient) -> None:
    health = await client.get("/healthz")
    ready = await client.get("/readyz")
    assert health.status_code == 200 and health.json() == {"status": "ok"}
    assert ready.status_code == 200
    assert ready.json() == {"status": "ready", "model": load_manifest(default_model_dir())["name"]}


async def test_request_id_is_generated_or_kept(client: httpx.AsyncClient) -> None:
    generated = (await client.get("/healthz")).headers["x-request-id"]
    assert re.fullmatch(r"[0-9a-f]{32}", generated)
    kept = (await client.get("/healthz", headers={"X-Request-ID": "abc-123"})).headers
    assert kept["x-request-id"] == "abc-123"
    replaced = (await client.get("/healthz", headers={"X-Request-ID": "bad id\twith spaces"})).headers
    assert re.fullmatch(r"[0-9a-f]{32}", replaced["x-request-id"])


async def test_model_manifest(client: httpx.AsyncClient) -> None:
    response = await client.get("/v1/model")
    assert response.status_code == 200
    manifest = load_manifest(default_model_dir())
    assert response.json() == public_manifest(manifest)
    # A shipped manifest may name a build machine's folder; the public copy does not (issue 15).
    assert ":/" not in response.text and '"/' not in response.text


async def test_openapi_documents_the_error_rule(client: httpx.AsyncClient) -> None:
    schema = (await client.get("/openapi.json")).json()
    assert {"/disparity", "/depth", "/pointcloud", "/healthz", "/readyz", "/metrics", "/v1/model"} <= set(
        schema["paths"]
    )
    for path in ("/disparity", "/depth", "/pointcloud"):
        operation = schema["paths"][path]["post"]
        assert set(operation["responses"]) == {"200", "400", "408", "413", "415", "503"}
        assert "multipart/form-data" in operation["requestBody"]["content"]
    assert "422" in DESCRIPTION  # the folding of 422 into 400 is stated on the docs page
    docs = await client.get("/docs")
    assert docs.status_code == 200 and "swagger" in docs.text.lower()


async def test_demo_page_and_sample_pair_are_served(client: httpx.AsyncClient) -> None:
    page = await client.get("/")
    assert page.status_code == 200 and page.headers["content-type"].startswith("text/html")
    assert 'id="pair-form"' in page.text and "/static/app.js" in page.text
    assert (await client.get("/static/app.js")).status_code == 200
    sizes = set()
    for side in ("left", "right"):
        sample = await client.get(f"/static/sample-{side}.png")
        sizes.add(Image.open(io.BytesIO(sample.content)).size)
    assert sizes == {(225, 187)}


# --- POST /disparity ----------------------------------------------------------------------------------------

async def test_disparity_png16_default(client: httpx.AsyncClient) -> None:
    response = await client.post("/disparity", params={"max_disparity": 16}, files=PAIR)
    assert response.status_code == 200, response.text
    assert response.headers["content-type"] == "image/png"
    assert response.headers["x-disparity-format"] == "png16"
    stages = {"decode", "queue", "towers", "cost_volume", "sgm", "right_sgm", "encode", "total"}
    assert stages <= set(stage_names(response))
    assert "x-request-id" in response.headers
    stored = np.asarray(Image.open(io.BytesIO(response.content)))
    assert stored.dtype == np.uint16 and stored.shape == (HEIGHT, WIDTH)
    assert np.median(stored[INTERIOR]) / 256.0 == pytest.approx(SHIFT, abs=0.25)


async def test_disparity_npy_values(client: httpx.AsyncClient) -> None:
    response = await client.post("/disparity", params={"max_disparity": 16, "format": "npy"}, files=PAIR)
    assert response.headers["content-type"] == "application/x-npy"
    disparity = npy(response)
    assert disparity.dtype == np.float32 and disparity.shape == (HEIGHT, WIDTH)
    assert np.mean(np.abs(disparity[INTERIOR] - SHIFT) < 0.5) > 0.95


async def test_disparity_pfm(client: httpx.AsyncClient, tmp_path) -> None:
    response = await client.post("/disparity", params={"max_disparity": 16, "format": "pfm"}, files=PAIR)
    assert response.headers["content-type"] == "image/x-portable-floatmap"
    (tmp_path / "d.pfm").write_bytes(response.content)
    disparity = read_disparity(tmp_path / "d.pfm")
    assert disparity.shape == (HEIGHT, WIDTH)
    assert np.nanmedian(disparity[INTERIOR]) == pytest.approx(SHIFT, abs=0.25)


async def test_disparity_color(client: httpx.AsyncClient) -> None:
    response = await client.post("/disparity", params={"max_disparity": 16, "format": "color"}, files=PAIR)
    image = Image.open(io.BytesIO(response.content))
    assert response.headers["content-type"] == "image/png"
    assert image.mode == "RGB" and image.size == (WIDTH, HEIGHT)
    assert len(np.unique(np.asarray(image).reshape(-1, 3), axis=0)) > 1


@pytest.mark.parametrize(
    ("accept", "expected"),
    [
        ("application/x-npy", "npy"),
        ("image/x-portable-floatmap", "pfm"),
        ("image/png", "png16"),
        ("application/x-npy;q=0.5, image/x-portable-floatmap", "pfm"),
        ("text/html, */*;q=0.8", "png16"),
    ],
)
async def test_format_from_accept_header(client: httpx.AsyncClient, accept: str, expected: str) -> None:
    response = await client.post(
        "/disparity", params={"max_disparity": 8}, files=PAIR, headers={"Accept": accept}
    )
    assert response.status_code == 200 and response.headers["x-disparity-format"] == expected


async def test_format_query_beats_accept(client: httpx.AsyncClient) -> None:
    response = await client.post(
        "/disparity", params={"max_disparity": 8, "format": "npy"}, files=PAIR,
        headers={"Accept": "image/png"},
    )
    assert response.headers["content-type"] == "application/x-npy"


def multipart_parts(response: httpx.Response) -> dict[str, tuple[str, bytes]]:
    raw = f"Content-Type: {response.headers['content-type']}\r\n\r\n".encode() + response.content
    message = email.parser.BytesParser().parsebytes(raw)
    assert message.is_multipart()
    return {
        part.get_param("name", header="content-disposition"): (
            part.get_content_type(), part.get_payload(decode=True)
        )
        for part in message.get_payload()
    }


async def test_validity_as_multipart_mixed(client: httpx.AsyncClient) -> None:
    response = await client.post(
        "/disparity", params={"max_disparity": 16, "format": "npy", "validity": "true", "fill": "false",
                              "border": "false"},
        files=PAIR,
    )
    assert response.headers["content-type"].startswith("multipart/mixed; boundary=")
    parts = multipart_parts(response)
    assert set(parts) == {"disparity", "validity"}
    assert parts["disparity"][0] == "application/x-npy" and parts["validity"][0] == "image/png"
    disparity = np.load(io.BytesIO(parts["disparity"][1]))
    validity = np.asarray(Image.open(io.BytesIO(parts["validity"][1])))
    assert validity.dtype == np.uint8 and validity.shape == (HEIGHT, WIDTH)
    assert set(np.unique(validity)) <= {int(code) for code in Validity}
    # Without filling or the border band, exactly the pixels that failed the check have no disparity;
    # the left strip (x < SHIFT) has no match in the right view at all.
    np.testing.assert_array_equal(np.isnan(disparity), validity != Validity.VALID)
    assert (validity[:, :SHIFT] != Validity.VALID).mean() > 0.75  # a few chance matches remain


async def test_switches_change_the_result(client: httpx.AsyncClient) -> None:
    async def disparity(**params: object) -> np.ndarray:
        response = await client.post("/disparity", params={"max_disparity": 16, "format": "npy", **params},
                                     files=PAIR)
        assert response.status_code == 200, response.text
        return npy(response)

    unchecked = await disparity(lr_check="false")
    assert not np.isnan(unchecked).any()  # nothing rejected without the check
    integer = await disparity(subpixel="false")
    finite = integer[np.isfinite(integer)]
    np.testing.assert_array_equal(finite, np.round(finite))
    assert np.isnan(await disparity(fill="false")).any()
    assert not np.isnan(await disparity(fill="true")).any()
    smooth = await disparity(p1=0, p2=0, lr_check="false")  # no smoothness: a plain NCC winner
    assert not np.array_equal(smooth, unchecked)
    # The border band step gives the left strip (x < SHIFT, match outside the right image) the shift.
    banded, unbanded = await disparity(border="true"), await disparity(border="false")
    strip = (slice(None), slice(0, SHIFT))
    assert np.mean(np.abs(banded[strip] - SHIFT) <= 1) > 0.95 and not np.array_equal(banded, unbanded)
    assert not np.array_equal(await disparity(adaptive_p2="false"), banded)
    assert not np.array_equal(await disparity(shiftable_windows="true"), banded)
    # MC-CNN's 1 px check keeps pixels the default 0.75 px rejects (then filled): another map.
    assert not np.array_equal(await disparity(lr_check_threshold=1), banded)
    # right_sgm=false reads the check's right winners off the left view's aggregated costs (no second
    # pass), which keeps a few chance matches inside the strip: another map ...
    single = await client.post("/disparity", files=PAIR, params={"max_disparity": 16, "format": "npy",
                                                                 "right_sgm": "false", "border": "true"})
    assert single.status_code == 200 and "right_sgm" not in stage_names(single)
    assert not np.array_equal(npy(single), banded)
    # ... and there a surface run of 1 lets a single chance match end the band: another map again.
    assert not np.array_equal(await disparity(right_sgm="false", border="true", border_surface_run=1),
                              npy(single))


async def test_tower_scale_matches_in_image_pixels_within_the_work_limit(client: httpx.AsyncClient) -> None:
    # The towers on the pair upsampled by 2: the same shift, in the image's pixels.
    left, right = (image[:HEIGHT // 2, :WIDTH // 2] for image in (LEFT, RIGHT))
    half = {"left": ("l.png", png(left), "image/png"), "right": ("r.png", png(right), "image/png")}
    params = {"max_disparity": 16, "format": "npy"}
    plain = await client.post("/disparity", params=params, files=half)
    scaled = await client.post("/disparity", params=params | {"tower_scale": 2}, files=half)
    assert plain.status_code == scaled.status_code == 200, scaled.text
    assert not np.array_equal(npy(scaled), npy(plain))
    assert np.mean(np.abs(npy(scaled)[8:-8, 16:-8] - SHIFT) <= 1) > 0.95
    # At the pixel limit, 4 x the towers' work is over the server's work limit: refused, saying why.
    assert_error(await client.post("/disparity", params=params | {"tower_scale": 2}, files=PAIR), 413,
                 "lower tower_scale")


# --- POST /depth and /pointcloud ----------------------------------------------------------------------------

FOCAL, BASELINE = 200.0, 0.1  # z = 0.1 * 200 / 4 = 5 m


async def test_depth_npy_in_metres(client: httpx.AsyncClient) -> None:
    response = await client.post(
        "/depth", params={"focal_px": FOCAL, "baseline_m": BASELINE, "max_disparity": 16}, files=PAIR
    )
    assert response.status_code == 200 and response.headers["content-type"] == "application/x-npy"
    assert "sgm" in stage_names(response)
    depth = npy(response)
    assert depth.dtype == np.float32 and depth.shape == (HEIGHT, WIDTH)
    assert np.nanmedian(depth[INTERIOR]) == pytest.approx(FOCAL * BASELINE / SHIFT, rel=0.03)


async def test_depth_png16_in_millimetres(client: httpx.AsyncClient) -> None:
    response = await client.post(
        "/depth", params={"focal_px": FOCAL, "baseline_m": BASELINE, "max_disparity": 16, "format": "png16"},
        files=PAIR,
    )
    assert response.headers["content-type"] == "image/png"
    millimetres = np.asarray(Image.open(io.BytesIO(response.content)))
    assert millimetres.dtype == np.uint16
    assert np.median(millimetres[INTERIOR]) == pytest.approx(1000 * FOCAL * BASELINE / SHIFT, rel=0.03)


async def test_depth_format_from_accept(client: httpx.AsyncClient) -> None:
    response = await client.post(
        "/depth", params={"focal_px": FOCAL, "baseline_m": BASELINE, "max_disparity": 8}, files=PAIR,
        headers={"Accept": "image/png"},
    )
    assert response.headers["x-depth-format"] == "png16"


def read_ply(data: bytes) -> tuple[str, np.ndarray]:
    header, _, body = data.partition(b"end_header\n")
    dtype = [("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("red", "u1"), ("green", "u1"), ("blue", "u1")]
    return header.decode("ascii"), np.frombuffer(body, dtype=dtype)


async def test_pointcloud_binary_ply(client: httpx.AsyncClient) -> None:
    cx, cy = 40.0, 30.0
    response = await client.post(
        "/pointcloud",
        params={"focal_px": FOCAL, "baseline_m": BASELINE, "cx": cx, "cy": cy, "max_disparity": 16,
                "fill": "false"},
        files=PAIR,
    )
    assert response.status_code == 200 and response.headers["content-type"] == "application/x-ply"
    header, vertices = read_ply(response.content)
    assert header.startswith("ply\nformat binary_little_endian 1.0\n")
    count = int(response.headers["x-point-count"])
    assert f"element vertex {count}\n" in header and vertices.shape == (count,)
    assert 0 < count < HEIGHT * WIDTH  # the unmatched left strip is dropped
    assert np.median(vertices["z"]) == pytest.approx(FOCAL * BASELINE / SHIFT, rel=0.03)
    # Back-project each point to its pixel: the colour must be that pixel's colour in the left image.
    cols = np.round(vertices["x"] * FOCAL / vertices["z"] + cx).astype(int)
    rows = np.round(vertices["y"] * FOCAL / vertices["z"] + cy).astype(int)
    colours = np.stack([vertices["red"], vertices["green"], vertices["blue"]], axis=1)
    np.testing.assert_array_equal(colours, LEFT[rows, cols])


# --- errors -------------------------------------------------------------------------------------------------

def assert_error(response: httpx.Response, status: int, *fragments: str) -> None:
    assert response.status_code == status, response.text
    assert response.headers["content-type"] == "application/json"
    assert "x-request-id" in response.headers
    detail = response.json()["detail"]
    assert isinstance(detail, str)
    for fragment in fragments:
        assert fragment in detail, detail


@pytest.mark.parametrize(
    ("path", "params", "fragment"),
    [
        ("/disparity", {"max_disparity": 0}, "max_disparity"),
        ("/disparity", {"max_disparity": "many"}, "max_disparity"),
        ("/disparity", {"format": "jpeg"}, "format"),
        ("/disparity", {"lr_check": "maybe"}, "lr_check"),
        ("/disparity", {"p2": -1}, "p2"),
        ("/disparity", {"tower_scale": 0}, "tower_scale"),
        ("/disparity", {"tower_scale": 5}, "tower_scale"),
        ("/disparity", {"tower_scale": 1.5}, "tower_scale"),
        ("/disparity", {"max_disparity": 64}, "ADSM_MAX_DISPARITY"),
        ("/depth", {"baseline_m": 0.1}, "focal_px"),
        ("/depth", {"focal_px": -5, "baseline_m": 0.1}, "focal_px"),
        ("/depth", {"focal_px": 5, "baseline_m": 0.1, "format": "color"}, "format"),
        ("/pointcloud", {"focal_px": 5, "baseline_m": "far"}, "baseline_m"),
    ],
)
async def test_bad_parameters_are_400(
    client: httpx.AsyncClient, path: str, params: dict, fragment: str
) -> None:
    assert_error(await client.post(path, params=params, files=PAIR), 400, fragment)


async def test_validation_errors_list_each_problem(client: httpx.AsyncClient) -> None:
    response = await client.post("/depth", params={"focal_px": "x", "baseline_m": "y"}, files=PAIR)
    assert_error(response, 400, "focal_px", "baseline_m")
    assert {tuple(problem["loc"]) for problem in response.json()["errors"]} == {
        ("query", "focal_px"), ("query", "baseline_m")
    }


async def test_missing_or_wrong_fields_are_400(client: httpx.AsyncClient) -> None:
    assert_error(await client.post("/disparity", files={"left": PAIR["left"]}), 400, "'right' is missing")
    text_field = await client.post("/disparity", files={"left": PAIR["left"]}, data={"right": "not a file"})
    assert_error(text_field, 400, "'right' must be a file")
    assert_error(await client.post("/disparity", content=b"{}", headers={"Content-Type": "application/json"}),
                 400, "multipart/form-data")
    broken = await client.post("/disparity", content=b"--x\r\ngarbage",
                               headers={"Content-Type": "multipart/form-data; boundary=x"})
    assert broken.status_code == 400


async def test_mismatched_sizes_are_400(client: httpx.AsyncClient) -> None:
    small = png(LEFT[:, :80])
    response = await client.post("/disparity", files={"left": PAIR["left"], "right": ("r.png", small)})
    assert_error(response, 400, "differ in size", "96 x 64", "80 x 64")


async def test_not_an_image_is_415(client: httpx.AsyncClient) -> None:
    not_image = {"left": ("l.png", b"GIF? no, text"), "right": PAIR["right"]}
    response = await client.post("/disparity", files=not_image)
    assert_error(response, 415, "left")


async def test_pixel_limit_is_413_before_decoding(client: httpx.AsyncClient) -> None:
    # A PNG whose header announces 5000 x 5000 pixels but carries one pixel of data: decoding it would
    # fail, so a 413 proves the header alone was judged.
    bomb = bytearray(png(np.zeros((1, 1), np.uint8)))
    bomb[16:24] = (5000).to_bytes(4, "big") * 2
    bomb[29:33] = zlib.crc32(bytes(bomb[12:29])).to_bytes(4, "big")  # IHDR checksum
    response = await client.post("/disparity", files={"left": ("l.png", bytes(bomb)), "right": PAIR["right"]})
    assert_error(response, 413, "5000 x 5000", "exceeds the limit of 6144")
    taller = png(stereo_pair(height=HEIGHT + 1)[0])
    response = await client.post("/disparity", files={"left": ("l.png", taller), "right": ("r.png", taller)})
    assert_error(response, 413, "pixels")


async def test_cost_volume_limit_is_413(client: httpx.AsyncClient) -> None:
    too_deep = await client.post("/disparity", params={"max_disparity": 17}, files=PAIR)
    assert_error(too_deep, 413, "96 x 64 pixels x 17 disparities", "ADSM_MAX_COST_CELLS")
    # Without max_disparity the model's default range applies, clipped to the width (96).
    assert_error(await client.post("/disparity", files=PAIR), 413, "x 96 disparities")


async def test_body_limit_by_content_length_is_413(client: httpx.AsyncClient) -> None:
    big = {"left": ("l.png", b"\0" * 130_000), "right": PAIR["right"]}
    assert_error(await client.post("/disparity", files=big), 413, "120000 bytes")


async def test_body_limit_while_streaming_is_413(client: httpx.AsyncClient) -> None:
    sent = 0

    async def chunks():  # no Content-Length: a chunked upload that never ends on its own
        nonlocal sent
        yield b"--x\r\nContent-Disposition: form-data; name=\"left\"; filename=\"l.png\"\r\n\r\n"
        for _ in range(1000):
            sent += 10_000
            yield b"\0" * 10_000

    response = await client.post("/disparity", content=chunks(),
                                 headers={"Content-Type": "multipart/form-data; boundary=x"})
    assert_error(response, 413, "120000 bytes")
    assert sent < 200_000  # refused as soon as the limit was crossed, not after reading everything


# --- metrics (last: it checks what the tests above left behind) -------------------------------------------

def metric_samples(text: str) -> dict[str, float]:
    """``name{labels}`` -> value of every sample line of a Prometheus exposition."""
    samples = {}
    for line in text.splitlines():
        if line and not line.startswith("#"):
            name, _, value = line.rpartition(" ")
            samples[name] = float(value)
    return samples


async def test_metrics_exposition(client: httpx.AsyncClient) -> None:
    # Counted as differences around this test's own requests: the module's client is shared, and what
    # the tests before it did (or did not do, when this test runs alone) must not matter.
    before = metric_samples((await client.get("/metrics")).text)
    disparity = await client.post("/disparity", params={"max_disparity": 16}, files=PAIR,
                                  headers={"X-Request-ID": "abc-123"})
    too_deep = await client.post("/disparity", params={"max_disparity": 17}, files=PAIR)
    depth = await client.post("/depth", params={"focal_px": FOCAL, "baseline_m": BASELINE,
                                                "max_disparity": 16}, files=PAIR)
    assert (disparity.status_code, too_deep.status_code, depth.status_code) == (200, 413, 200)
    response = await client.get("/metrics")
    assert response.status_code == 200 and response.headers["content-type"].startswith("text/plain")
    text = response.text
    after = metric_samples(text)
    for sample, added in (
        ('adsm_http_requests_total{method="POST",route="/disparity",status="200"}', 1),
        ('adsm_http_requests_total{method="POST",route="/disparity",status="413"}', 1),
        ('adsm_http_request_duration_seconds_bucket{le="+Inf",method="POST",route="/depth",status="200"}', 1),
        ('adsm_stage_duration_seconds_count{stage="sgm"}', 2),
        ('adsm_stage_duration_seconds_count{stage="queue"}', 2),
    ):
        assert after.get(sample, 0.0) - before.get(sample, 0.0) == added, sample
    for sample, value in (("adsm_queue_waiting", 0.0), ("adsm_inference_running", 0.0),
                          ("adsm_queue_rejections_total", 0.0), ("adsm_ready", 1.0)):
        assert after[sample] == value, sample
    assert "abc-123" not in text and "left.png" not in text  # no request data in labels
    assert json.dumps(load_manifest(default_model_dir())["name"]) in text  # adsm_model_info{name="..."}
