"""The queue under real load: `adsm serve` (uvicorn, the default model) with ADSM_QUEUE_SIZE=1 and several
clients posting the Cones pair at once. One inference runs and one request waits; every other gets 503
with Retry-After at once; no request ever gets a 500. (The queue's logic alone, with a stand-in matcher,
is tests/service/api/test_api_queue.py.)"""

from __future__ import annotations

import io
import os
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator

import httpx
import numpy as np
import pytest

from service.io import read_disparity
from tests.helpers import ROOT, cones_folder

CLIENTS = 8
QUEUE_SIZE = 1  # one waiting place: at most two admitted at a time (running + waiting)


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


@pytest.fixture(scope="module")
def server_url() -> Iterator[str]:
    port = _free_port()
    env = {key: value for key, value in os.environ.items() if not key.startswith("ADSM_")}
    env.update(ADSM_QUEUE_SIZE=str(QUEUE_SIZE), ADSM_NUMBA_CACHE_DIR=os.environ["ADSM_NUMBA_CACHE_DIR"],
               PYTHONPATH=str(ROOT))
    process = subprocess.Popen([sys.executable, "-m", "service", "serve", "--port", str(port),
                                "--log-level", "warning"], env=env, stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True)
    url = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + 180
        while True:
            assert process.poll() is None, process.communicate()[1][-3000:]
            assert time.monotonic() < deadline, "the server never became ready"
            try:
                if httpx.get(f"{url}/readyz", timeout=2).status_code == 200:
                    break
            except httpx.TransportError:
                pass
            time.sleep(0.1)
        yield url
    finally:
        process.terminate()
        try:
            _, stderr = process.communicate(timeout=60)
        except subprocess.TimeoutExpired:
            process.kill()
            _, stderr = process.communicate(timeout=30)
        assert "Traceback" not in stderr, stderr[-3000:]


def _rejections(url: str) -> float:
    text = httpx.get(f"{url}/metrics", timeout=10).text
    return sum(float(line.split()[-1]) for line in text.splitlines()
               if line.startswith("adsm_queue_rejections_total"))


def test_concurrent_cones_posts_get_200_or_503_with_retry_after(server_url: str) -> None:
    cones = cones_folder()
    files = {side: (f"{side}.png", (cones / f"{side}.png").read_bytes(), "image/png")
             for side in ("left", "right")}  # 690 kB together
    before = _rejections(server_url)
    start = threading.Barrier(CLIENTS)
    answers: list[httpx.Response | BaseException | None] = [None] * CLIENTS

    def post(index: int) -> None:
        try:
            with httpx.Client(timeout=120) as client:
                start.wait()
                answers[index] = client.post(f"{server_url}/disparity", files=files,
                                             params={"max_disparity": 64, "format": "npy"})
        except BaseException as error:
            answers[index] = error

    threads = [threading.Thread(target=post, args=(index,)) for index in range(CLIENTS)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(timeout=300)
    assert all(isinstance(answer, httpx.Response) for answer in answers), answers
    codes = sorted(answer.status_code for answer in answers)
    ok = [answer for answer in answers if answer.status_code == 200]
    refused = [answer for answer in answers if answer.status_code == 503]
    print(f"status codes of {CLIENTS} simultaneous Cones posts: {codes}")
    assert len(ok) + len(refused) == CLIENTS, f"only 200 and 503 expected, got {codes}"
    # Measured: exactly 2 served (the running and the waiting request), 6 refused. A third may slip in if
    # one inference (~1 s) ends before the last client's headers arrive on a loaded machine; five served
    # would be the default queue size (4 + 1): ADSM_QUEUE_SIZE not taken.
    assert QUEUE_SIZE + 1 <= len(ok) <= CLIENTS // 2, f"one running and one waiting place: {codes}"
    assert refused, f"{CLIENTS} simultaneous requests against one running and one waiting place: {codes}"
    for answer in refused:
        assert int(answer.headers["Retry-After"]) >= 1
        assert "queue is full" in answer.json()["detail"]
    # The served answers are the pair's disparity, all the same (the matcher is deterministic), and good.
    maps = [np.load(io.BytesIO(answer.content), allow_pickle=False) for answer in ok]
    assert all(m.shape == (375, 450) for m in maps)
    for other in maps[1:]:
        np.testing.assert_array_equal(other, maps[0])
    truth = read_disparity(cones / "disp_left.png")
    known = np.isfinite(truth)
    assert np.mean(np.abs(maps[0][known] - truth[known]) <= 2) > 0.85  # bad-2 ~9 % (README table)
    assert _rejections(server_url) - before == len(refused)
