"""Faults: a bad model folder stops `adsm serve` at start-up with one line; clients that vanish mid-upload
or mid-inference leave no queue place behind; SIGTERM lets in-flight requests finish and turns new ones
away with 503.

The running-server tests start the real `adsm serve` code path (``service.cli.main``) on a loopback port
with a gated stand-in matcher (``gated_app`` below, imported by the child process): inference call k
blocks until the test creates the file ``release-k``, so "one request is in flight" is a state the test
controls, not a race against a sleep. Queue states are read from the server's own /metrics.
"""

from __future__ import annotations

import asyncio
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import httpx
import numpy as np
import pytest

from service.api import Settings, create_app
from service.features import default_model_dir, load_manifest
from service.matcher import MatchOptions, StereoResult
from tests.helpers import ROOT
from tests.stand_in import MatcherRules

GATE_ENV = "ADSM_TEST_GATE_DIR"


class GatedMatcher(MatcherRules):
    """Stands in for the Matcher; call k waits for ``<gate>/release-k`` (and announces ``called-k``)."""

    def __init__(self, gate: Path) -> None:
        self.manifest = load_manifest(default_model_dir())
        self.gate = gate
        self.calls = 0

    def warmup(self) -> None:
        pass

    def __call__(self, left: np.ndarray, right: np.ndarray, options: MatchOptions) -> StereoResult:
        self.calls += 1
        (self.gate / f"called-{self.calls}").touch()
        deadline = time.monotonic() + 60
        while not (self.gate / f"release-{self.calls}").exists():
            if time.monotonic() > deadline:
                raise RuntimeError("the test never released the matcher")
            time.sleep(0.01)
        shape = left.shape[:2]
        return StereoResult(np.full(shape, 2.0, np.float32), np.zeros(shape, np.uint8), {"towers": 0.0})


def gated_app():
    """App factory for the child process: queue of one, the gated matcher."""
    return create_app(Settings(queue_size=1), matcher=GatedMatcher(Path(os.environ[GATE_ENV])))


def _png() -> bytes:
    import io

    from PIL import Image

    buffer = io.BytesIO()
    Image.fromarray(np.zeros((8, 12, 3), np.uint8)).save(buffer, format="PNG")
    return buffer.getvalue()


PAIR = {"left": ("l.png", _png(), "image/png"), "right": ("r.png", _png(), "image/png")}


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def _serve_env(**extra: str) -> dict[str, str]:
    env = {key: value for key, value in os.environ.items() if not key.startswith("ADSM_")}
    if "ADSM_NUMBA_CACHE_DIR" in os.environ:
        env["ADSM_NUMBA_CACHE_DIR"] = os.environ["ADSM_NUMBA_CACHE_DIR"]
    return {**env, "PYTHONPATH": str(ROOT), **extra}


# --- start-up faults: `adsm serve` exits non-zero with one line on stderr --------------------------------

def _broken_model(tmp_path: Path, fault: str) -> Path:
    folder = tmp_path / "model"
    shutil.copytree(default_model_dir(), folder)
    manifest_path = folder / "manifest.json"
    if fault == "missing folder":
        shutil.rmtree(folder)
    elif fault == "tampered onnx":
        onnx = folder / "right.onnx"
        data = bytearray(onnx.read_bytes())
        data[len(data) // 2] ^= 0xFF  # one flipped byte, same size
        onnx.write_bytes(bytes(data))
    elif fault == "missing onnx":
        (folder / "left.onnx").unlink()
    elif fault == "wrong schema":
        manifest = json.loads(manifest_path.read_text())
        manifest_path.write_text(json.dumps({**manifest, "schema": "adsm-model/2"}))
    elif fault == "manifest not json":
        manifest_path.write_text('{"schema": "adsm-model/1", ')
    return folder


@pytest.mark.parametrize(
    ("fault", "fragment"),
    [
        ("missing folder", "does not exist"),
        ("tampered onnx", "right.onnx"),
        ("missing onnx", "left.onnx"),
        ("wrong schema", "adsm-model/2"),
        ("manifest not json", "not valid JSON"),
    ],
)
def test_bad_model_fails_start_up_in_one_line(tmp_path: Path, fault: str, fragment: str) -> None:
    folder = _broken_model(tmp_path, fault)
    port = _free_port()
    done = subprocess.run(
        [sys.executable, "-m", "service", "serve", "--model", str(folder), "--port", str(port)],
        env=_serve_env(), capture_output=True, text=True, timeout=120,
    )
    assert done.returncode != 0
    assert done.stderr.count("\n") == 1 and done.stderr.startswith("adsm: error: "), done.stderr
    assert fragment in done.stderr, done.stderr
    assert done.stdout == ""
    with socket.socket() as probe:  # it never listened
        assert probe.connect_ex(("127.0.0.1", port)) != 0


@pytest.mark.parametrize(("variable", "value"), [("ADSM_QUEUE_SIZE", "-1"), ("ADSM_MAX_PIXELS", "lots")])
def test_bad_setting_fails_start_up_in_one_line(variable: str, value: str) -> None:
    done = subprocess.run(
        [sys.executable, "-m", "service", "serve", "--port", str(_free_port())],
        env=_serve_env(**{variable: value}), capture_output=True, text=True, timeout=120,
    )
    assert done.returncode != 0
    assert done.stderr.count("\n") == 1 and done.stderr.startswith("adsm: error: "), done.stderr
    assert variable.removeprefix("ADSM_").lower() in done.stderr.lower(), done.stderr


# --- clients that vanish: in process, ASGI messages under the test's control --------------------------

class _InstantMatcher(GatedMatcher):
    def __call__(self, left: np.ndarray, right: np.ndarray, options: MatchOptions) -> StereoResult:
        self.calls += 1
        shape = left.shape[:2]
        return StereoResult(np.ones(shape, np.float32), np.zeros(shape, np.uint8), {"towers": 0.0})


def _scope(body_length: int, content_type: str) -> dict:
    return {
        "type": "http", "asgi": {"version": "3.0"}, "http_version": "1.1", "method": "POST", "scheme": "http",
        "path": "/disparity", "raw_path": b"/disparity", "query_string": b"", "root_path": "",
        "headers": [(b"content-type", content_type.encode()), (b"content-length", str(body_length).encode())],
        "client": ("127.0.0.1", 5000), "server": ("127.0.0.1", 80),
    }


@pytest.mark.anyio
@pytest.mark.parametrize("anyio_backend", ["asyncio"])
async def test_disconnect_mid_upload_frees_the_place(anyio_backend: str) -> None:
    matcher = _InstantMatcher(Path("."))
    app = create_app(Settings(queue_size=0), matcher=matcher)  # one place: a leak would 503 the next
    request = httpx.Request("POST", "http://test/disparity", files=PAIR)
    body, content_type = request.read(), request.headers["content-type"]
    sent: list[dict] = []
    chunks = iter([{"type": "http.request", "body": body[: len(body) // 2], "more_body": True}])

    async def receive() -> dict:
        return next(chunks, {"type": "http.disconnect"})  # half the body, then the client is gone

    async def send(message: dict) -> None:
        sent.append(message)

    async with app.router.lifespan_context(app):
        slot = app.state.inference.slot
        while not app.state.inference.ready:
            await asyncio.sleep(0.01)
        await asyncio.wait_for(app(_scope(len(body), content_type), receive, send), 10)
        assert slot.waiting == 0 and not slot.running
        transport = httpx.ASGITransport(app=app)
        async with httpx.AsyncClient(transport=transport, base_url="http://test") as client:
            assert (await client.post("/disparity", files=PAIR)).status_code == 200
            metrics = (await client.get("/metrics")).text
    assert matcher.calls == 1  # the half upload never reached the matcher
    assert sent and sent[0]["status"] == 499  # recorded as "client closed request", not as a server error
    assert 'route="/disparity",status="499"' in metrics and 'status="500"' not in metrics


# --- a real `adsm serve` process --------------------------------------------------------------------------

class Server:
    def __init__(self, process: subprocess.Popen, port: int, gate: Path) -> None:
        self.process, self.port, self.gate = process, port, gate
        self.url = f"http://127.0.0.1:{port}"

    def release(self, call: int) -> None:
        (self.gate / f"release-{call}").touch()

    def wait_called(self, call: int, timeout: float = 30) -> None:
        _until(lambda: (self.gate / f"called-{call}").exists(), timeout)

    def metric(self, name: str) -> float:
        text = httpx.get(f"{self.url}/metrics", timeout=10).text
        return float(next(line.split()[-1] for line in text.splitlines() if line.startswith(f"{name} ")))


def _until(condition, timeout: float = 30) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.02)


@pytest.fixture
def server(tmp_path: Path) -> Iterator[Server]:
    """`adsm serve` (the real CLI and uvicorn settings) serving ``gated_app`` on a free loopback port."""
    port = _free_port()
    code = (
        f"import sys; from service.cli import main, serve; serve._APP_FACTORY = '{__name__}:gated_app'; "
        f"sys.exit(main(['serve', '--port', '{port}', '--log-level', 'warning']))"
    )
    process = subprocess.Popen([sys.executable, "-c", code], env=_serve_env(**{GATE_ENV: str(tmp_path)}),
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    server = Server(process, port, tmp_path)
    try:
        def ready() -> bool:
            assert process.poll() is None, process.communicate()[1]
            try:
                return httpx.get(f"{server.url}/readyz", timeout=2).status_code == 200
            except httpx.TransportError:
                return False

        _until(ready, 60)
        yield server
    finally:
        for call in range(1, 10):  # never leave the child blocked
            server.release(call)
        if process.poll() is None:
            process.kill()
        process.communicate(timeout=30)


def _post(url: str, **kwargs) -> httpx.Response:
    return httpx.post(f"{url}/disparity", files=PAIR, timeout=60, **kwargs)


@pytest.mark.slow
def test_disconnects_mid_upload_and_mid_inference_leak_nothing(server: Server) -> None:
    # Mid-upload: the headers promise 100 kB, 1 kB arrives, the socket closes.
    with socket.create_connection(("127.0.0.1", server.port)) as sock:
        sock.sendall(b"POST /disparity HTTP/1.1\r\nHost: x\r\nContent-Length: 100000\r\n"
                     b"Content-Type: multipart/form-data; boundary=b\r\n\r\n--b\r\n"
                     b'Content-Disposition: form-data; name="left"; filename="l.png"\r\n\r\n' + b"\0" * 1000)
        _until(lambda: server.metric("adsm_queue_waiting") == 1)
    _until(lambda: server.metric("adsm_queue_waiting") == 0)

    # Mid-inference: the first request runs (gated); its client goes away; the work ends; nothing leaks.
    request = httpx.Request("POST", f"{server.url}/disparity", files=PAIR)
    body = request.read()
    head = "".join(f"{k}: {v}\r\n" for k, v in request.headers.items() if k.lower() != "host")
    with socket.create_connection(("127.0.0.1", server.port)) as sock:
        sock.sendall(f"POST /disparity HTTP/1.1\r\nHost: x\r\n{head}\r\n".encode() + body)
        server.wait_called(1)
        assert server.metric("adsm_inference_running") == 1
    server.release(1)
    _until(lambda: server.metric("adsm_inference_running") == 0 and server.metric("adsm_queue_waiting") == 0)

    # Both places (running + queue of one) are free: two concurrent requests are admitted and answered.
    with ThreadPoolExecutor(2) as pool:
        first = pool.submit(_post, server.url)
        server.wait_called(2)
        second = pool.submit(_post, server.url)
        _until(lambda: server.metric("adsm_queue_waiting") == 1)
        server.release(2)
        server.wait_called(3)
        server.release(3)
        assert first.result().status_code == 200 and second.result().status_code == 200


@pytest.mark.slow
def test_sigterm_finishes_in_flight_requests_and_refuses_new_ones(server: Server) -> None:
    with ThreadPoolExecutor(2) as pool:
        running = pool.submit(_post, server.url)
        server.wait_called(1)
        queued = pool.submit(_post, server.url)
        _until(lambda: server.metric("adsm_queue_waiting") == 1)

        server.process.send_signal(signal.SIGTERM)
        _until(lambda: httpx.get(f"{server.url}/readyz", timeout=5).status_code == 503, 10)
        refused = _post(server.url)
        assert refused.status_code == 503, refused.text
        assert "shutting down" in refused.json()["detail"] and int(refused.headers["retry-after"]) >= 1
        assert server.process.poll() is None  # still draining: two requests are in flight

        server.release(1)
        server.wait_called(2)
        server.release(2)
        answers = [running.result(), queued.result()]
    assert [answer.status_code for answer in answers] == [200, 200]
    assert all(answer.headers["x-disparity-format"] == "png16" for answer in answers)
    server.process.wait(timeout=30)  # then it exits by itself, without a second signal
    assert server.process.returncode in (0, -signal.SIGTERM)
    assert "Traceback" not in server.process.communicate()[1]
