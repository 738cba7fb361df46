"""The inference slot and the app's start-up states, with a deliberately slow fake matcher.

The fake blocks inside ``__call__`` until the test releases it, so "one inference is running" is a
state the test controls rather than a race against a sleep.
"""

from __future__ import annotations

import asyncio
import io
import shutil
import threading

import anyio
import httpx
import numpy as np
import pytest
from PIL import Image

from service.api import Settings, create_app
from service.api.queue import ClientDisconnected, InferenceSlot, QueueFull
from service.features import ModelError, default_model_dir, load_manifest
from service.matcher import MatchOptions, StereoResult
from tests.helpers import disparity_scope
from tests.stand_in import MatcherRules

pytestmark = pytest.mark.anyio


@pytest.fixture
def anyio_backend() -> str:
    return "asyncio"


class BlockingMatcher(MatcherRules):
    """Stands in for the Matcher; each call waits for ``release`` (and warm-up for ``warmed``)."""

    def __init__(self, *, warm_error: Exception | None = None) -> None:
        self.manifest = load_manifest(default_model_dir())
        self.release = threading.Event()
        self.warmed = threading.Event()
        self.warm_error = warm_error
        self.calls = 0

    def warmup(self) -> None:
        assert self.warmed.wait(10), "test never let the warm-up finish"
        if self.warm_error is not None:
            raise self.warm_error

    def __call__(self, left: np.ndarray, right: np.ndarray, options: MatchOptions) -> StereoResult:
        self.calls += 1
        assert self.release.wait(10), "test never released the matcher"
        disparity = np.ones(left.shape[:2], np.float32)
        return StereoResult(disparity, np.zeros(left.shape[:2], np.uint8), {"towers": 0.0, "total": 0.0})


def _png() -> bytes:
    buffer = io.BytesIO()
    Image.fromarray(np.zeros((8, 12, 3), np.uint8)).save(buffer, format="PNG")
    return buffer.getvalue()


PAIR = {"left": ("l.png", _png()), "right": ("r.png", _png())}


async def _until(condition, timeout: float = 10.0) -> None:
    with anyio.fail_after(timeout):
        while not condition():
            await anyio.sleep(0.01)


# --- InferenceSlot on its own -------------------------------------------------------------------------

async def test_slot_admits_one_running_plus_queue_size() -> None:
    slot = InferenceSlot(queue_size=1)
    with slot.admit(), slot.admit():
        with pytest.raises(QueueFull) as full:
            slot.admit()
        assert full.value.retry_after >= 1
    with slot.admit():  # places come back when a request ends
        assert slot.waiting == 1


async def test_slot_runs_one_at_a_time_in_arrival_order() -> None:
    slot = InferenceSlot(queue_size=3)
    order: list[int] = []
    running = 0

    def work(index: int) -> int:
        nonlocal running
        running += 1
        assert running == 1, "two inferences ran at once"
        order.append(index)
        running -= 1
        return index * 10

    async def request(index: int) -> int:
        with slot.admit():
            return await slot.run(work, index)

    results = await asyncio.gather(*(request(i) for i in range(4)))
    assert results == [0, 10, 20, 30] and order == [0, 1, 2, 3]


async def test_slot_gives_the_place_back_when_the_client_leaves() -> None:
    slot = InferenceSlot(queue_size=1)
    gate = threading.Event()
    gone = False

    async def disconnected() -> bool:
        return gone

    with slot.admit():
        first = asyncio.ensure_future(slot.run(gate.wait, 10))
        await _until(lambda: slot.running)
        with slot.admit():
            second = asyncio.ensure_future(slot.run(pytest.fail, "must not run", disconnected=disconnected))
            await anyio.sleep(0.1)
            assert not second.done()
            gone = True
            with pytest.raises(ClientDisconnected):
                await second
        gate.set()
        assert await first is True
    assert slot.waiting == 0 and not slot.running
    with slot.admit():  # the lock was not leaked
        assert await slot.run(lambda: "free") == "free"


async def test_slot_does_not_leak_the_lock_when_a_waiter_is_cancelled() -> None:
    slot = InferenceSlot(queue_size=1)
    gate = threading.Event()
    first = asyncio.ensure_future(slot.run(gate.wait, 10))
    await _until(lambda: slot.running)
    waiter = asyncio.ensure_future(slot.run(pytest.fail, "must not run"))
    await anyio.sleep(0.05)
    waiter.cancel()
    gate.set()
    await first
    with pytest.raises(asyncio.CancelledError):
        await waiter
    assert await asyncio.wait_for(slot.run(lambda: 1), 5) == 1


# --- the app: queue full, disconnects, start-up states ---------------------------------------------------

def _client(app) -> httpx.AsyncClient:
    return httpx.AsyncClient(transport=httpx.ASGITransport(app=app), base_url="http://test", timeout=30)


async def test_full_queue_answers_503_at_once() -> None:
    matcher = BlockingMatcher()
    matcher.warmed.set()
    app = create_app(Settings(queue_size=1), matcher=matcher)
    slot = app.state.inference.slot
    async with app.router.lifespan_context(app), _client(app) as client:
        await _until(lambda: app.state.inference.ready)
        running = asyncio.ensure_future(client.post("/disparity", files=PAIR))
        await _until(lambda: slot.running)
        queued = asyncio.ensure_future(client.post("/disparity", files=PAIR))
        await _until(lambda: slot.waiting == 1)
        with anyio.fail_after(2):  # answered while the slot is still busy
            rejected = await client.post("/disparity", files=PAIR)
        assert rejected.status_code == 503
        assert int(rejected.headers["retry-after"]) >= 1
        assert "queue is full" in rejected.json()["detail"] and "x-request-id" in rejected.headers
        assert (await client.get("/healthz")).status_code == 200  # the event loop stays free
        metrics = (await client.get("/metrics")).text
        assert "adsm_queue_waiting 1.0" in metrics and "adsm_inference_running 1.0" in metrics
        matcher.release.set()
        assert (await running).status_code == 200 and (await queued).status_code == 200
        metrics = (await client.get("/metrics")).text
    assert matcher.calls == 2
    assert "adsm_queue_rejections_total 1.0" in metrics
    assert 'adsm_http_requests_total{method="POST",route="/disparity",status="503"} 1.0' in metrics


def _multipart_request() -> tuple[bytes, str]:
    request = httpx.Request("POST", "http://test/disparity", files=PAIR)
    return request.read(), request.headers["content-type"]


async def test_client_that_disconnects_while_queued_never_runs() -> None:
    matcher = BlockingMatcher()
    matcher.warmed.set()
    app = create_app(Settings(queue_size=1), matcher=matcher)
    slot = app.state.inference.slot
    body, content_type = _multipart_request()
    leave = asyncio.Event()
    sent: list[dict] = []

    async def receive() -> dict:
        if not sent:
            sent.append({})
            return {"type": "http.request", "body": body, "more_body": False}
        await leave.wait()
        return {"type": "http.disconnect"}

    async def send(message: dict) -> None:
        sent.append(message)

    scope = disparity_scope(body, content_type)
    async with app.router.lifespan_context(app), _client(app) as client:
        await _until(lambda: app.state.inference.ready)
        running = asyncio.ensure_future(client.post("/disparity", files=PAIR))
        await _until(lambda: slot.running)
        queued = asyncio.ensure_future(app(scope, receive, send))
        await _until(lambda: slot.waiting == 1)
        leave.set()  # the queued client hangs up
        await asyncio.wait_for(queued, 5)
        assert slot.waiting == 0  # its place is free again while the first inference still runs
        matcher.release.set()
        assert (await running).status_code == 200
    assert matcher.calls == 1
    assert sent[1]["status"] == 499


async def test_not_ready_until_warm() -> None:
    matcher = BlockingMatcher()
    app = create_app(Settings(), matcher=matcher)
    async with app.router.lifespan_context(app), _client(app) as client:
        assert (await client.get("/healthz")).status_code == 200
        not_ready = await client.get("/readyz")
        assert not_ready.status_code == 503 and not_ready.headers["retry-after"]
        early = await client.post("/disparity", files=PAIR)
        assert early.status_code == 503 and "warming up" in early.json()["detail"]
        assert "adsm_ready 0.0" in (await client.get("/metrics")).text
        matcher.warmed.set()
        await _until(lambda: app.state.inference.ready)
        assert (await client.get("/readyz")).status_code == 200
    assert matcher.calls == 0


async def test_failed_warmup_fails_liveness() -> None:
    matcher = BlockingMatcher(warm_error=RuntimeError("no kernels"))
    matcher.warmed.set()
    app = create_app(Settings(), matcher=matcher)
    async with app.router.lifespan_context(app), _client(app) as client:
        await _until(lambda: app.state.inference.failure is not None)
        health = await client.get("/healthz")
        ready = await client.get("/readyz")
    assert health.status_code == 503 and "no kernels" in health.json()["detail"]
    assert ready.status_code == 503 and "no kernels" in ready.json()["detail"]


async def test_tampered_model_fails_start_up(tmp_path) -> None:
    folder = tmp_path / "model"
    shutil.copytree(default_model_dir(), folder)
    onnx = folder / "left.onnx"
    onnx.write_bytes(onnx.read_bytes() + b"\0")
    app = create_app(Settings(model_dir=folder))
    with pytest.raises(ModelError, match=r"left\.onnx"):
        async with app.router.lifespan_context(app):
            pass
    assert not app.state.inference.ready
