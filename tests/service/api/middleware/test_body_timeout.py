"""ADSM_BODY_TIMEOUT_S: a body that does not arrive in time is a 408 and gives its queue place back.

Slow clients are played by an async generator body that sleeps between chunks (httpx's ASGI transport
hands each chunk to the app as one ``receive``) or by a raw ASGI ``receive`` that never delivers. The
timeouts are tiny and the trickles far longer than them, so no test depends on how fast this machine is:
a broken deadline shows up as a wrong status, not as a slow test.
"""

from __future__ import annotations

import asyncio
import json
import threading
from collections.abc import AsyncIterator

import anyio
import httpx
import pytest

from service.api import Settings, create_app
from service.api.middleware.body_timeout import BodyDeadline
from tests.helpers import TINY_PAIR, InstantMatcher, disparity_scope, ready_client

pytestmark = pytest.mark.anyio

TIMEOUT_S = 0.2


@pytest.fixture
def anyio_backend() -> str:
    return "asyncio"


def _multipart() -> tuple[bytes, str]:
    request = httpx.Request("POST", "http://test/disparity", files=TINY_PAIR)
    return request.read(), request.headers["content-type"]


BODY, CONTENT_TYPE = _multipart()


def _assert_timed_out(response: httpx.Response) -> None:
    assert response.status_code == 408, response.text
    detail = response.json()["detail"]
    assert f"longer than {TIMEOUT_S:g} s" in detail and "ADSM_BODY_TIMEOUT_S" in detail
    assert response.headers["connection"] == "close"  # the unread rest of the body is on the connection
    assert "x-request-id" in response.headers


async def test_trickled_body_is_408_and_gives_its_place_back() -> None:
    # queue_size=0: a single place, so a leaked one would turn the next request into a 503.
    app = create_app(Settings(queue_size=0, body_timeout_s=TIMEOUT_S), matcher=InstantMatcher())
    slot = app.state.inference.slot
    places_held: list[int] = []

    async def trickle() -> AsyncIterator[bytes]:
        yield BODY[:64]
        places_held.append(slot.waiting)  # the server has read the first chunk, inside the route
        for byte in BODY[64:]:  # ~0.05 s a byte: seconds in all, far past the timeout
            await anyio.sleep(0.05)
            yield bytes([byte])

    async with ready_client(app) as client:
        response = await client.post("/disparity", content=trickle(), headers={"Content-Type": CONTENT_TYPE})
        _assert_timed_out(response)
        assert places_held == [1]  # the upload did hold the place...
        assert slot.waiting == 0 and not slot.running  # ...and gave it back
        assert (await client.post("/disparity", files=TINY_PAIR)).status_code == 200  # the server is fine
        metrics = (await client.get("/metrics")).text
    assert 'adsm_http_requests_total{method="POST",route="/disparity",status="408"} 1.0' in metrics
    assert 'adsm_http_requests_total{method="POST",route="/disparity",status="200"} 1.0' in metrics
    assert "adsm_queue_waiting 0.0" in metrics


async def test_a_client_that_stops_sending_is_408() -> None:
    app = create_app(Settings(queue_size=0, body_timeout_s=TIMEOUT_S), matcher=InstantMatcher())
    sent: list[dict] = []
    reads = 0

    async def receive() -> dict:  # headers and a first chunk, then silence (the connection stays open)
        nonlocal reads
        reads += 1
        if reads == 1:
            return {"type": "http.request", "body": BODY[:64], "more_body": True}
        await anyio.sleep_forever()
        raise AssertionError("unreachable")

    async def send(message: dict) -> None:
        sent.append(message)

    scope = disparity_scope(BODY, CONTENT_TYPE)
    async with ready_client(app) as client:
        with anyio.fail_after(10):  # a missing deadline would hang here
            await app(scope, receive, send)
        assert app.state.inference.slot.waiting == 0
        assert (await client.post("/disparity", files=TINY_PAIR)).status_code == 200
    start, body = sent[0], sent[1]
    assert start["status"] == 408 and (b"connection", b"close") in start["headers"]
    detail = json.loads(body["body"])["detail"]
    assert f"longer than {TIMEOUT_S:g} s" in detail and "ADSM_BODY_TIMEOUT_S" in detail


async def test_a_body_read_outside_a_route_is_answered_408_by_the_middleware() -> None:
    async def reads_everything(scope, receive, send) -> None:  # no exception handlers around it
        while (await receive()).get("more_body"):
            pass

    async def receive() -> dict:
        await anyio.sleep_forever()
        raise AssertionError("unreachable")

    sent: list[dict] = []

    async def send(message: dict) -> None:
        sent.append(message)

    scope = {"type": "http", "method": "POST", "path": "/", "headers": []}
    with anyio.fail_after(10):
        await BodyDeadline(reads_everything, timeout_s=TIMEOUT_S)(scope, receive, send)
    assert sent[0]["status"] == 408 and (b"connection", b"close") in sent[0]["headers"]
    assert "ADSM_BODY_TIMEOUT_S" in json.loads(sent[1]["body"])["detail"]


async def test_a_body_sent_in_chunks_within_the_timeout_is_unaffected() -> None:
    app = create_app(Settings(body_timeout_s=60), matcher=InstantMatcher())

    async def chunks() -> AsyncIterator[bytes]:
        for start in range(0, len(BODY), 100):
            await anyio.sleep(0.001)
            yield BODY[start:start + 100]

    async with ready_client(app) as client:
        response = await client.post("/disparity", content=chunks(), headers={"Content-Type": CONTENT_TYPE})
    assert response.status_code == 200, response.text


async def test_waiting_in_the_queue_is_not_counted_as_upload_time() -> None:
    gate = threading.Event()
    matcher = InstantMatcher(gate)
    app = create_app(Settings(queue_size=1, body_timeout_s=TIMEOUT_S), matcher=matcher)
    slot = app.state.inference.slot
    async with ready_client(app) as client:
        running = asyncio.ensure_future(client.post("/disparity", files=TINY_PAIR))
        with anyio.fail_after(10):
            while not slot.running:
                await anyio.sleep(0.01)
        queued = asyncio.ensure_future(client.post("/disparity", files=TINY_PAIR))
        with anyio.fail_after(10):
            while slot.waiting != 1:
                await anyio.sleep(0.01)
        await anyio.sleep(3 * TIMEOUT_S)  # its body is complete; it now waits far longer than the timeout
        gate.set()
        assert (await running).status_code == 200
        assert (await queued).status_code == 200
    assert matcher.calls == 2
