"""service.client.StereoClient (issue 13, item 4): against the in-process app with the real default model,
against the app with a stand-in matcher (a full queue, then a place), and against fakes (httpx.MockTransport)
for what the service cannot be made to do on demand (a Retry-After sequence, a timeout, a 500)."""

from __future__ import annotations

import contextlib
import io
import json
import subprocess
import sys
import threading
import time
import tomllib
from collections.abc import Iterator
from datetime import UTC, datetime
from pathlib import Path

import anyio.from_thread
import httpx
import numpy as np
import pytest
from PIL import Image

from service.api import Settings, create_app
from service.api.routes.encoding import multipart_mixed, validity_png
from service.client import (
    AnswerFormatError,
    BadRequestError,
    DisparityMaps,
    PairWarning,
    RequestTimeoutError,
    RetryPolicy,
    ServerBusyError,
    ServerError,
    StereoClient,
    TransportError,
)
from service.client.answers import multipart_parts
from service.client.retry import retry_after_seconds
from service.geometry import depth_from_disparity
from service.io import encode_disparity
from service.matcher import MatchOptions
from tests.helpers import ROOT, InstantMatcher

HEIGHT, WIDTH, SHIFT = 48, 80, 4
SETTINGS = Settings(queue_size=2, max_pixels=HEIGHT * WIDTH, max_disparity=32)


def stereo_pair() -> tuple[np.ndarray, np.ndarray]:
    """Random texture seen with disparity SHIFT: left[y, x] == right[y, x - SHIFT]."""
    texture = np.random.default_rng(11).integers(0, 256, (HEIGHT, WIDTH + SHIFT, 3), dtype=np.uint8)
    return np.ascontiguousarray(texture[:, :WIDTH]), np.ascontiguousarray(texture[:, SHIFT:])


LEFT, RIGHT = stereo_pair()


def png(image: np.ndarray) -> bytes:
    buffer = io.BytesIO()
    Image.fromarray(image).save(buffer, format="PNG")
    return buffer.getvalue()


class InProcess(httpx.BaseTransport):
    """The synchronous client's way into an ASGI app: httpx.ASGITransport run on an anyio portal's loop."""

    def __init__(self, app, portal) -> None:
        self.asgi = httpx.ASGITransport(app=app)
        self.portal = portal

    def handle_request(self, request: httpx.Request) -> httpx.Response:
        async def send() -> tuple[int, httpx.Headers, bytes]:
            response = await self.asgi.handle_async_request(request)
            return response.status_code, response.headers, await response.aread()

        status, headers, content = self.portal.call(send)
        return httpx.Response(status, headers=headers, content=content, request=request)


@contextlib.contextmanager
def in_process(app, **client_options) -> Iterator[StereoClient]:
    """A StereoClient of ``app`` inside its lifespan, once /readyz answers 200."""
    with contextlib.ExitStack() as stack:
        portal = stack.enter_context(anyio.from_thread.start_blocking_portal())
        stack.enter_context(portal.wrap_async_context_manager(app.router.lifespan_context(app)))
        client = stack.enter_context(StereoClient("http://test", transport=InProcess(app, portal),
                                                  **client_options))
        deadline = time.monotonic() + 120
        while not client.ready():
            assert time.monotonic() < deadline, "the app did not turn ready"
            time.sleep(0.05)
        yield client


# --- the real default model ---------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def real():
    app = create_app(SETTINGS)
    with in_process(app) as client:
        yield client, app.state.inference.matcher


def test_disparity_equals_the_python_api_for_every_input_kind_and_format(real, tmp_path: Path) -> None:
    client, matcher = real
    expected = matcher(LEFT, RIGHT, MatchOptions(max_disparity=16)).disparity
    (tmp_path / "l.png").write_bytes(png(LEFT))
    (tmp_path / "r.png").write_bytes(png(RIGHT))
    inputs = {"arrays": (LEFT, RIGHT), "bytes": (png(LEFT), png(RIGHT)),
              "paths": (tmp_path / "l.png", str(tmp_path / "r.png")),
              "pil": (Image.fromarray(LEFT), Image.fromarray(RIGHT))}
    for kind, (left, right) in inputs.items():
        disparity = client.disparity(left, right, max_disparity=16)
        assert disparity.dtype == np.float32 and disparity.shape == (HEIGHT, WIDTH), kind
        np.testing.assert_array_equal(disparity, expected, err_msg=kind)
    np.testing.assert_array_equal(client.disparity(LEFT, RIGHT, max_disparity=16, format="pfm"), expected)
    png16 = client.disparity(LEFT, RIGHT, max_disparity=16, format="png16")
    assert np.array_equal(np.isnan(png16), np.isnan(expected) | (expected <= 0))
    np.testing.assert_allclose(png16[expected > 0], expected[expected > 0], atol=0.5 / 256)
    interior = disparity[8:-8, 16:-8]
    assert np.nanmedian(interior) == pytest.approx(SHIFT, abs=0.25)


def test_options_reach_the_matcher(real) -> None:
    client, matcher = real
    options = {"max_disparity": 12, "subpixel": False, "fill": False, "p1": 20, "p2": 100.0}
    expected = matcher(LEFT, RIGHT, MatchOptions(**options))
    maps = client.disparity(LEFT, RIGHT, validity=True, **options)
    assert isinstance(maps, DisparityMaps) and maps.confidence is None
    np.testing.assert_array_equal(maps.disparity, expected.disparity)
    np.testing.assert_array_equal(maps.validity, expected.validity)
    assert maps.validity.dtype == np.uint8
    assert np.all(np.mod(maps.disparity[np.isfinite(maps.disparity)], 1) == 0)  # subpixel=false arrived


def test_depth_and_point_cloud(real) -> None:
    client, matcher = real
    disparity = matcher(LEFT, RIGHT, MatchOptions(max_disparity=16)).disparity
    depth = client.depth(LEFT, RIGHT, focal_px=700.0, baseline_m=0.1, max_disparity=16)
    has_depth = np.isfinite(disparity) & (disparity > 0)
    assert np.array_equal(np.isfinite(depth), has_depth)
    np.testing.assert_allclose(depth[has_depth], 70.0 / disparity[has_depth], rtol=1e-6)
    millimetres = client.depth(LEFT, RIGHT, focal_px=700.0, baseline_m=0.1, max_disparity=16, format="png16")
    np.testing.assert_allclose(millimetres[has_depth], depth[has_depth], atol=0.0005 + 1e-6)

    cloud = client.pointcloud(LEFT, RIGHT, focal_px=700.0, baseline_m=0.1, cx=10.0, max_disparity=16)
    rows, cols = np.nonzero(has_depth)
    assert len(cloud) == rows.size and cloud.points.dtype == np.float32
    np.testing.assert_allclose(cloud.points[:, 2], depth[rows, cols], rtol=1e-6)
    np.testing.assert_allclose(cloud.points[:, 0], (cols - 10.0) * depth[rows, cols] / 700.0, rtol=1e-5)
    np.testing.assert_array_equal(cloud.colors, LEFT[rows, cols])


def test_confidence_from_the_service(real) -> None:
    client, matcher = real
    expected = matcher(LEFT, RIGHT, MatchOptions(max_disparity=16, confidence=True))
    maps = client.disparity(LEFT, RIGHT, max_disparity=16, confidence=True)  # npy: the exact floats
    assert maps.validity is None and maps.confidence.dtype == np.float32
    np.testing.assert_array_equal(maps.confidence, expected.confidence)
    np.testing.assert_array_equal(maps.disparity, expected.disparity)
    both = client.disparity(LEFT, RIGHT, max_disparity=16, confidence=True, validity=True, format="png16")
    np.testing.assert_allclose(both.confidence, expected.confidence, atol=0.5 / 255 + 1e-6)  # 8-bit PNG
    np.testing.assert_array_equal(both.validity, expected.validity)
    assert 0 < float(np.mean(maps.confidence)) < 1


def test_calibration_file_and_pair_warnings(real, tmp_path: Path) -> None:
    client, matcher = real
    disparity = matcher(LEFT, RIGHT, MatchOptions(max_disparity=16)).disparity
    calib = tmp_path / "calib.txt"
    calib.write_text(f"cam0=[700 0 40; 0 700 24; 0 0 1]\ncam1=[700 0 42; 0 700 24; 0 0 1]\nbaseline=100\n"
                     f"width={WIDTH}\nheight={HEIGHT}\n")
    expected = depth_from_disparity(disparity, focal_px=700, baseline_m=0.1, doffs=2)
    for given in (calib, str(calib), calib.read_bytes()):
        depth = client.depth(LEFT, RIGHT, calib=given, max_disparity=16)
        np.testing.assert_allclose(depth, expected, rtol=1e-6)
    cloud = client.pointcloud(LEFT, RIGHT, calib=calib, max_disparity=16)
    rows, cols = np.nonzero(np.isfinite(expected))
    np.testing.assert_allclose(cloud.points[:, 0], (cols - 40) * expected[rows, cols] / 700,
                               rtol=1e-5, atol=1e-7)
    twice = {"focal_px": 700.0, "baseline_m": 0.1, "calib": calib}
    for camera, fragment in (({}, "neither"), (twice, "both"), ({"focal_px": 700.0}, "together")):
        with pytest.raises(ValueError, match=fragment):
            client.depth(LEFT, RIGHT, **camera)
    with pytest.raises(BadRequestError, match="unknown calibration format"):
        client.depth(LEFT, RIGHT, calib=b"not a calibration")
    # The service's pair warnings arrive as Python warnings; the answer still comes back
    with pytest.warns(PairWarning, match="^swapped: the pair looks swapped") as caught:
        swapped = client.disparity(RIGHT, LEFT, max_disparity=16)
    assert swapped.shape == (HEIGHT, WIDTH) and caught[0].message.kind == "swapped"
    assert caught[0].filename == __file__  # pointed at the caller's line


def test_bad_requests_raise_with_the_service_detail(real) -> None:
    client, _ = real
    with pytest.raises(BadRequestError) as caught:
        client.disparity(LEFT, RIGHT, max_disparty=16)  # misspelt
    assert caught.value.status_code == 400
    assert caught.value.detail.startswith("unknown query parameter 'max_disparty'")
    assert len(caught.value.request_id) == 32 and caught.value.detail in str(caught.value)
    with pytest.raises(BadRequestError) as caught:
        client.disparity(LEFT, RIGHT[:, :-1])
    assert caught.value.status_code == 400 and "differ in size" in caught.value.detail
    with pytest.raises(BadRequestError) as caught:
        client.disparity(LEFT, RIGHT, max_disparity=0)
    assert caught.value.status_code == 400 and caught.value.errors  # FastAPI's validation list
    with pytest.raises(BadRequestError) as caught:
        client.disparity(b"not an image", png(RIGHT))
    assert caught.value.status_code == 415
    with pytest.raises(BadRequestError) as caught:
        client.depth(LEFT, RIGHT, focal_px=float("nan"), baseline_m=0.1)
    assert caught.value.status_code == 400


def test_bad_arguments_fail_before_sending() -> None:
    client = StereoClient("http://test", transport=httpx.MockTransport(lambda r: pytest.fail("sent")))
    with pytest.raises(ValueError, match="uint8"):
        client.disparity(LEFT.astype(np.float32), RIGHT)
    with pytest.raises(ValueError, match="format must be one of npy, png16, pfm"):
        client.disparity(LEFT, RIGHT, format="color")
    with pytest.raises(TypeError, match="option max_disparity"):
        client.disparity(LEFT, RIGHT, max_disparity=[16])
    with pytest.raises(FileNotFoundError):
        client.disparity("/nonexistent/left.png", RIGHT)


# --- 503: a full queue of the real app, then fakes ----------------------------------------------------------

def test_a_full_queue_is_retried_after_retry_after() -> None:
    gate = threading.Event()
    matcher = InstantMatcher(gate=gate)
    waits: list[float] = []

    def sleep(seconds: float) -> None:  # the running request finishes while the client waits
        waits.append(seconds)
        gate.set()
        time.sleep(0.05)

    app = create_app(Settings(queue_size=0), matcher=matcher)
    with in_process(app, retry=RetryPolicy(retries=20, max_wait_s=100, sleep=sleep)) as client:
        first = threading.Thread(target=client.disparity, args=(LEFT, RIGHT))
        first.start()
        deadline = time.monotonic() + 10
        while matcher.calls < 1:  # the first request holds the only place
            assert time.monotonic() < deadline
            time.sleep(0.01)
        disparity = client.disparity(LEFT, RIGHT)
        first.join(10)
    assert waits and all(wait >= 1 for wait in waits)  # the queue's own estimate, whole seconds
    assert np.all(disparity == 1.0) and matcher.calls == 2


def _npy_answer() -> httpx.Response:
    return httpx.Response(200, content=encode_disparity(np.full((2, 3), 7.5, np.float32), "npy"),
                          headers={"content-type": "application/x-npy"})


def _busy(retry_after: str | None = "2") -> httpx.Response:
    headers = {"x-request-id": "r1"} | ({"retry-after": retry_after} if retry_after else {})
    return httpx.Response(503, json={"detail": "the inference queue is full; retry in 2 s"}, headers=headers)


def _fake(answers: list[httpx.Response], seen: list[httpx.Request]) -> httpx.MockTransport:
    def handle(request: httpx.Request) -> httpx.Response:
        request.read()
        seen.append(request)
        return answers.pop(0)

    return httpx.MockTransport(handle)


def test_503_then_200_waits_as_told_and_resends_the_pair() -> None:
    seen: list[httpx.Request] = []
    waits: list[float] = []
    client = StereoClient("http://fake", transport=_fake([_busy("2"), _busy("3"), _npy_answer()], seen),
                          retry=RetryPolicy(sleep=waits.append))
    disparity = client.disparity(LEFT, RIGHT, max_disparity=16)
    assert waits == [2.0, 3.0] and len(seen) == 3
    assert np.all(disparity == 7.5)
    for request in seen:
        assert request.url.params["max_disparity"] == "16" and request.url.params["format"] == "npy"
        assert b'name="left"' in request.content and b'name="right"' in request.content


def test_busy_gives_up_within_its_bounds() -> None:
    waits: list[float] = []
    # Without Retry-After: doubling backoff, then ServerBusyError after the last retry.
    client = StereoClient("http://fake", transport=_fake([_busy(None)] * 4, []),
                          retry=RetryPolicy(retries=3, backoff_s=0.5, sleep=waits.append))
    with pytest.raises(ServerBusyError) as caught:
        client.disparity(LEFT, RIGHT)
    assert waits == [0.5, 1.0, 2.0] and caught.value.attempts == 4
    assert caught.value.status_code == 503 and "queue is full" in caught.value.detail
    assert caught.value.request_id == "r1" and caught.value.retry_after is None
    # A Retry-After beyond what is left of max_wait_s: give up at once rather than sleep and fail.
    waits.clear()
    client = StereoClient("http://fake", transport=_fake([_busy("4"), _busy("30")], []),
                          retry=RetryPolicy(max_wait_s=10, sleep=waits.append))
    with pytest.raises(ServerBusyError) as caught:
        client.disparity(LEFT, RIGHT)
    assert waits == [4.0] and caught.value.attempts == 2 and caught.value.retry_after == 30.0
    # retries=0: no retry at all.
    client = StereoClient("http://fake", transport=_fake([_busy("1")], []), retry=RetryPolicy(retries=0))
    with pytest.raises(ServerBusyError):
        client.disparity(LEFT, RIGHT)


def test_retry_after_forms() -> None:
    now = datetime(2026, 1, 1, 12, 0, 0, tzinfo=UTC)
    assert retry_after_seconds("7") == 7.0
    assert retry_after_seconds("Thu, 01 Jan 2026 12:00:09 GMT", now=now) == 9.0
    assert retry_after_seconds("Thu, 01 Jan 2026 11:00:00 GMT", now=now) == 0.0
    assert retry_after_seconds("soon") is None and retry_after_seconds(None) is None


# --- other failures -----------------------------------------------------------------------------------------

def test_transport_errors_timeouts_and_server_faults() -> None:
    def timeout(request: httpx.Request) -> httpx.Response:
        raise httpx.ReadTimeout("timed out", request=request)

    with pytest.raises(RequestTimeoutError, match="no answer from http://fake in time") as caught:
        StereoClient("http://fake", transport=httpx.MockTransport(timeout)).disparity(LEFT, RIGHT)
    assert isinstance(caught.value.__cause__, httpx.ReadTimeout) and isinstance(caught.value, TransportError)

    with pytest.raises(TransportError, match=r"cannot talk to http://127\.0\.0\.1:9"):
        StereoClient("http://127.0.0.1:9", timeout=5).disparity(LEFT, RIGHT)  # discard port: refused

    crash = httpx.Response(500, json={"detail": "internal error (request abc)"},
                           headers={"x-request-id": "abc"})
    with pytest.raises(ServerError) as caught:
        StereoClient("http://fake", transport=_fake([crash], [])).disparity(LEFT, RIGHT)
    assert caught.value.status_code == 500 and caught.value.request_id == "abc"

    garbage = httpx.Response(200, content=b"<html>proxy login</html>", headers={"content-type": "text/html"})
    with pytest.raises(AnswerFormatError, match="not a png16, PFM or npy"):
        StereoClient("http://fake", transport=_fake([garbage], [])).disparity(LEFT, RIGHT)


def test_multipart_parts_round_trip_the_service_encoder() -> None:
    tricky = b"\r\n--adsm-\r\n\r\n" * 3 + bytes(range(256))  # looks like framing, is data
    body, content_type = multipart_mixed([("disparity", "d.npy", "application/x-npy", tricky),
                                          ("validity", "v.png", "image/png", b"")])
    assert multipart_parts(body, content_type) == {"disparity": ("application/x-npy", tricky),
                                                   "validity": ("image/png", b"")}
    with pytest.raises(AnswerFormatError, match="truncated"):
        multipart_parts(body[:-40], content_type)
    with pytest.raises(AnswerFormatError, match="expected a multipart answer"):
        multipart_parts(body, "application/x-npy")


def test_confidence_part_is_decoded_when_the_service_sends_it() -> None:
    """Both forms of the confidence part (npy float32, 8-bit PNG = confidence x 255), and a missing part,
    from a fake (the real service's part: test_confidence_from_the_service)."""
    disparity = np.full((2, 3), 5.0, np.float32)
    confidence = np.array([[0.0, 0.5, 1.0], [0.25, 0.75, 1.0]], np.float32)
    buffer = io.BytesIO()
    np.save(buffer, confidence)
    eight_bit = png((confidence * 255).round().astype(np.uint8))
    for media, part, tolerance in (("application/x-npy", buffer.getvalue(), 0.0),
                                   ("image/png", eight_bit, 0.5 / 255)):
        body, content_type = multipart_mixed([
            ("disparity", "disparity.npy", "application/x-npy", encode_disparity(disparity, "npy")),
            ("validity", "validity.png", "image/png", validity_png(np.zeros((2, 3), np.uint8))),
            ("confidence", "confidence", media, part)])
        seen: list[httpx.Request] = []
        answer = httpx.Response(200, content=body, headers={"content-type": content_type})
        maps = StereoClient("http://fake", transport=_fake([answer], seen)).disparity(
            LEFT, RIGHT, validity=True, confidence=True)
        assert seen[0].url.params["confidence"] == "true" and seen[0].url.params["validity"] == "true"
        np.testing.assert_allclose(maps.confidence, confidence, atol=tolerance)
        assert maps.validity.shape == (2, 3) and np.all(maps.disparity == 5.0)
    # Asked for but absent: said, not silently None.
    body, content_type = multipart_mixed([("disparity", "d.npy", "application/x-npy",
                                           encode_disparity(disparity, "npy"))])
    answer = httpx.Response(200, content=body, headers={"content-type": content_type})
    with pytest.raises(AnswerFormatError, match="no part named confidence"):
        StereoClient("http://fake", transport=_fake([answer], [])).disparity(LEFT, RIGHT, confidence=True)


# --- what it needs -----------------------------------------------------------------------------------------

RUNTIME = ("numba", "llvmlite", "onnxruntime", "fastapi", "starlette", "uvicorn", "multipart",
           "python_multipart", "prometheus_client", "cv2", "torch", "training", "export")
PROBE = """
import json, sys
import service.client
print(json.dumps(sorted(sys.modules)))
"""


def test_the_client_imports_none_of_the_service_runtime() -> None:
    loaded = json.loads(subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True,
                                       check=True, cwd=ROOT, timeout=60).stdout)
    assert "httpx" in loaded and "service.client" in loaded  # the probe ran
    assert [name for name in loaded if name.partition(".")[0] in RUNTIME] == []
    # Of the service, only the client and the file codecs (NumPy and Pillow): not the matcher, not the app.
    assert {name.split(".")[1] for name in loaded if name.startswith("service.")} == {"client", "io"}
    extra = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"][
        "optional-dependencies"]["client"]
    names = sorted(requirement.split(">")[0].split("<")[0].split("=")[0] for requirement in extra)
    assert names == ["httpx", "numpy", "pillow"]
