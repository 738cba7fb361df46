"""The demo page in headless Chromium (Debian's /usr/bin/chromium driven by Playwright) against a real
uvicorn on 127.0.0.1: upload a pair, and the sample pair, and check the disparity image rendered."""

from __future__ import annotations

import io
import os
import shutil
import socket
import threading
import time
import urllib.request
from pathlib import Path

import numpy as np
import pytest
from conftest import require, require_module
from PIL import Image

CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = [
    "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
    "--disable-background-networking", "--disable-component-update", "--disable-sync",
]



@pytest.fixture(scope="module")
def server_url():
    import uvicorn

    from service.api import Settings, create_app

    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    app = create_app(Settings(queue_size=2))
    config = uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning")
    server = uvicorn.Server(config)
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    url = f"http://127.0.0.1:{port}"
    deadline = time.monotonic() + 120
    while True:
        try:
            with urllib.request.urlopen(f"{url}/readyz", timeout=2):
                break
        except OSError:
            if time.monotonic() > deadline or not thread.is_alive():
                raise
            time.sleep(0.1)
    yield url
    server.should_exit = True
    thread.join(timeout=30)


@pytest.fixture(scope="module")
def browser():
    # .ci/run installs Chromium when it runs as root; without it (or as another user) CI fails here.
    require(os.access(CHROMIUM, os.X_OK) or shutil.which("chromium") is not None,
            f"Chromium at {CHROMIUM} (apt-get install chromium; .ci/run does as root)")
    playwright_api = require_module("playwright.sync_api")
    with playwright_api.sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=shutil.which("chromium") or CHROMIUM,
                                             args=CHROMIUM_ARGS)
        yield browser
        browser.close()


@pytest.fixture
def page(browser, server_url):
    page = browser.new_page()
    page.set_default_timeout(60_000)
    page.goto(server_url + "/")
    page.wait_for_function("document.getElementById('readiness').textContent === 'ready'")
    yield page
    page.close()


def _write_pair(folder: Path, width: int = 80, height: int = 48, shift: int = 3) -> tuple[Path, Path]:
    texture = np.random.default_rng(3).integers(0, 256, (height, width + shift, 3), dtype=np.uint8)
    paths = []
    for name, image in (("left.png", texture[:, :width]), ("right.png", texture[:, shift:])):
        buffer = io.BytesIO()
        Image.fromarray(np.ascontiguousarray(image)).save(buffer, format="PNG")
        (folder / name).write_bytes(buffer.getvalue())
        paths.append(folder / name)
    return paths[0], paths[1]


def _rendered(page) -> dict:
    page.wait_for_function("document.getElementById('status').textContent.startsWith('done')")
    return page.evaluate(
        """() => ({
            width: document.getElementById('disparity').naturalWidth,
            height: document.getElementById('disparity').naturalHeight,
            validityWidth: document.getElementById('validity').width,
            legend: document.getElementById('validity-legend').textContent,
            stages: [...document.querySelectorAll('#timings td:first-child')].map((cell) => cell.textContent),
            requestId: document.getElementById('request-id').textContent,
            resultsShown: !document.getElementById('results').hidden,
        })"""
    )


def test_upload_a_pair_and_see_the_disparity(page, tmp_path: Path) -> None:
    left, right = _write_pair(tmp_path)
    page.set_input_files("#left", str(left))
    page.set_input_files("#right", str(right))
    page.fill("#max-disparity", "16")
    page.click("#compute")
    shown = _rendered(page)
    assert (shown["width"], shown["height"]) == (80, 48)
    assert shown["validityWidth"] == 80 and "valid" in shown["legend"]
    assert {"towers", "sgm", "total"} <= set(shown["stages"])
    assert len(shown["requestId"]) == 32 and shown["resultsShown"]
    # The disparity image is the colour PNG: not a blank frame.
    pixels = page.evaluate(
        """() => {
            const img = document.getElementById('disparity');
            const c = document.createElement('canvas');
            c.width = img.naturalWidth;
            c.height = img.naturalHeight;
            const g = c.getContext('2d');
            g.drawImage(img, 0, 0);
            return Array.from(g.getImageData(0, 0, c.width, c.height).data);
        }"""
    )
    rgb = np.asarray(pixels, np.uint8).reshape(48, 80, 4)[:, :, :3]
    assert len(np.unique(rgb.reshape(-1, 3), axis=0)) > 1


def test_sample_pair(page) -> None:
    page.click("#use-sample")
    page.wait_for_function("document.getElementById('pair-source').textContent.includes('sample')")
    page.click("#compute")
    shown = _rendered(page)
    assert (shown["width"], shown["height"]) == (225, 187)
    if folder := os.environ.get("ADSM_DEMO_SCREENSHOT_DIR"):  # for people: see what the page shows
        page.screenshot(path=str(Path(folder) / "demo-page.png"), full_page=True)


def test_error_is_shown(page, tmp_path: Path) -> None:
    narrow = tmp_path / "narrow"
    narrow.mkdir()
    left, _ = _write_pair(tmp_path)
    _, right = _write_pair(narrow, width=64)
    page.set_input_files("#left", str(left))
    page.set_input_files("#right", str(right))
    page.click("#compute")
    page.wait_for_function("document.getElementById('status').className === 'error'")
    assert page.text_content("#status").startswith("400: left and right images differ in size")
