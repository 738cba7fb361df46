"""The demo page in headless Chromium (Debian's /usr/bin/chromium driven by Playwright) against a real
uvicorn on 127.0.0.1 serving the default model: the sample pair and an upload, the maps the page paints
(checked against the service's own arrays and colour table), the 3D view (pixels read back from its
WebGL canvas, before and after a drag and a zoom), downloads, errors, the narrow-screen layout.

Screenshots are kept as test artifacts: in the test's tmp_path and copied to test-artifacts/ at the
repository root (git-ignored), or to ADSM_DEMO_SCREENSHOT_DIR when set.
"""

from __future__ import annotations

import base64
import io
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from service.geometry import read_ply
from service.io import read_disparity
from service.io.colormap import TURBO
from tests.helpers import ROOT, require, require_module, served_in_thread

STATIC = ROOT / "service" / "api" / "static"
CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = [
    "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
    "--disable-background-networking", "--disable-component-update", "--disable-sync",
    "--enable-unsafe-swiftshader",  # WebGL in software, as a GPU-less CI machine has it
]
SAMPLE_SIZE = (187, 225)  # height, width of service/api/static/sample-*.png


@pytest.fixture(scope="module")
def server_url():
    from service.api import Settings, create_app

    with served_in_thread(create_app(Settings(queue_size=2)), timeout=120) as url:
        yield url


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
    context = browser.new_context(accept_downloads=True, viewport={"width": 1200, "height": 900})
    page = context.new_page()
    page.set_default_timeout(60_000)
    page.failed = []  # every answer >= 400 and every request that got none
    page.on("response", lambda r: page.failed.append(f"{r.status} {r.url}") if r.status >= 400 else None)
    page.on("requestfailed", lambda r: page.failed.append(f"failed {r.url}"))
    errors: list[str] = []
    page.on("pageerror", lambda error: errors.append(str(error)))
    page.goto(server_url + "/")
    page.wait_for_function("document.getElementById('readiness').textContent === 'ready'")
    yield page
    context.close()
    assert errors == [], f"the page's scripts threw: {errors}"


def keep_screenshot(page, tmp_path: Path, name: str) -> Path:
    """A full-page screenshot in tmp_path, copied to ADSM_DEMO_SCREENSHOT_DIR or test-artifacts/."""
    shot = tmp_path / name
    page.screenshot(path=str(shot), full_page=True)
    folder = Path(os.environ.get("ADSM_DEMO_SCREENSHOT_DIR") or ROOT / "test-artifacts")
    folder.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(shot, folder / name)
    return shot


def _write_pair(folder: Path, width: int = 80, height: int = 48, shift: int = 3) -> tuple[Path, Path]:
    texture = np.random.default_rng(3).integers(0, 256, (height, width + shift, 3), dtype=np.uint8)
    paths = []
    for name, image in (("left.png", texture[:, :width]), ("right.png", texture[:, shift:])):
        buffer = io.BytesIO()
        Image.fromarray(np.ascontiguousarray(image)).save(buffer, format="PNG")
        (folder / name).write_bytes(buffer.getvalue())
        paths.append(folder / name)
    return paths[0], paths[1]


def _done(page) -> None:
    page.wait_for_function("/^(done|[0-9]{3}:)/.test(document.getElementById('status').textContent)")
    assert page.text_content("#status").startswith("done"), page.text_content("#status")


def canvas_pixels(page, selector: str) -> np.ndarray:
    """The RGB pixels a canvas (2D or WebGL) shows, read back as a PNG (lossless)."""
    url = page.evaluate("(selector) => document.querySelector(selector).toDataURL('image/png')", selector)
    with Image.open(io.BytesIO(base64.b64decode(url.split(",", 1)[1]))) as image:
        return np.asarray(image.convert("RGB"))


def download(page, file: str) -> bytes:
    with page.expect_download() as info:
        page.click(f"button[data-file='{file}']")
    return Path(info.value.path()).read_bytes()


def test_page_loads_clean(page) -> None:
    """No broken-image placeholders on load (display: grid overrode hidden), no failed request (the
    favicon 404), no result section before a result."""
    state = page.evaluate(
        """() => ({
            results: getComputedStyle(document.getElementById('results')).display,
            visibleImages: [...document.images].filter((i) => i.getClientRects().length > 0).length,
        })"""
    )
    assert state == {"results": "none", "visibleImages": 0}
    page.wait_for_load_state("networkidle")
    assert page.failed == []  # the browser asked for /favicon.ico and got a 404 before the page named one
    assert page.evaluate("document.querySelector('link[rel=icon]')?.href") == page.url + "static/favicon.png"


def test_upload_a_pair_and_see_the_disparity(page, tmp_path: Path) -> None:
    left, right = _write_pair(tmp_path)
    page.set_input_files("#left", str(left))
    page.set_input_files("#right", str(right))
    page.fill("#max-disparity", "16")
    page.click("#compute")
    _done(page)
    shown = page.evaluate(
        """() => {
            const $ = (id) => document.getElementById(id);
            return {
                legend: $('validity-legend').textContent,
                stages: [...document.querySelectorAll('#timings td:first-child')].map((td) => td.textContent),
                requestId: $('request-id').textContent,
                hidden: ['results', 'depth-figure', 'cloud-figure'].map((id) => $(id).hidden),
            };
        }"""
    )
    assert "valid" in shown["legend"] and {"towers", "sgm", "total"} <= set(shown["stages"])
    assert len(shown["requestId"]) == 32
    assert shown["hidden"] == [False, True, True]  # no camera given: no depth, no cloud
    disparity = canvas_pixels(page, "#disparity")
    assert disparity.shape == (48, 80, 3) and len(np.unique(disparity.reshape(-1, 3), axis=0)) > 1
    # The service's files for the same request: npy (held), png16 and pfm (asked again) agree.
    held = read_disparity_bytes(download(page, "disparity-npy"), tmp_path / "d.npy")
    png16 = read_disparity_bytes(download(page, "disparity-png16"), tmp_path / "d.png")
    pfm = read_disparity_bytes(download(page, "disparity-pfm"), tmp_path / "d.pfm")
    assert held.shape == (48, 80) and np.nanmedian(held) == pytest.approx(3, abs=0.5)
    # png16 (KITTI's convention) has no code for a disparity <= 0: such a pixel reads back invalid.
    np.testing.assert_allclose(png16, np.where(held > 0, held, np.nan), atol=1 / 256, equal_nan=True)
    np.testing.assert_array_equal(pfm, held)


def read_disparity_bytes(data: bytes, path: Path) -> np.ndarray:
    path.write_bytes(data)
    return read_disparity(path)


def test_sample_pair_depth_and_3d_view(page, tmp_path: Path) -> None:
    page.click("#use-sample")
    page.wait_for_function("document.getElementById('pair-source').textContent.includes('sample')")
    assert page.input_value("#focal-px") and page.input_value("#baseline-m")
    page.click("#compute")
    _done(page)
    assert not page.is_hidden("#depth-figure") and not page.is_hidden("#cloud-figure")
    assert canvas_pixels(page, "#disparity").shape[:2] == SAMPLE_SIZE
    ticks = page.text_content("#depth-scale .ticks")
    assert ticks.endswith(" m") and len(page.query_selector_all("#depth-scale .ticks span")) == 5
    # The confidence part, painted grey; the camera the service used, said back
    assert not page.is_hidden("#confidence-figure")
    confidence = canvas_pixels(page, "#confidence")
    assert confidence.shape[:2] == SAMPLE_SIZE and len(np.unique(confidence[:, :, 0])) > 50
    assert page.text_content("#calibration-read").startswith("Camera: focal length 300 px, baseline 0.05 m")
    assert page.is_hidden("#warnings")

    # The 3D view drew the cloud: a good share of its pixels differ from the background.
    page.wait_for_timeout(200)
    view = canvas_pixels(page, "#cloud")
    background = view[0, 0]
    drawn = np.any(view != background, axis=2)
    assert drawn.mean() > 0.2, f"only {drawn.mean():.1%} of the 3D view differs from its background"
    assert len(np.unique(view[drawn].reshape(-1, 3), axis=0)) > 100  # the image's colours, not one blob
    shot = keep_screenshot(page, tmp_path, "demo-page.png")
    assert shot.stat().st_size > 10_000

    # Drag rotates, the wheel zooms, double-click goes back to the first view.
    page.locator("#cloud").scroll_into_view_if_needed()
    box = page.locator("#cloud").bounding_box()
    centre = (box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
    page.mouse.move(*centre)
    page.mouse.down()
    page.mouse.move(centre[0] + 45, centre[1] + 20, steps=6)  # 0.45 rad about y, 0.2 about x
    page.mouse.up()
    turned = canvas_pixels(page, "#cloud")
    assert np.any(turned != view, axis=2).mean() > 0.05
    keep_screenshot(page, tmp_path, "demo-page-turned.png")  # docs/images/demo-page.png is this one
    page.mouse.wheel(0, 600)  # away: the cloud shrinks
    zoomed = canvas_pixels(page, "#cloud")
    assert np.any(zoomed != zoomed[0, 0], axis=2).mean() < np.any(turned != turned[0, 0], axis=2).mean()
    page.dblclick("#cloud")
    np.testing.assert_array_equal(canvas_pixels(page, "#cloud"), view)

    # The depth map the page paints is /depth's npy, and the cloud /pointcloud's PLY (held for download).
    depth = np.load(io.BytesIO(download(page, "depth-npy")))
    assert depth.shape == SAMPLE_SIZE and np.isfinite(depth).mean() > 0.9
    cloud = read_ply(download(page, "pointcloud-ply"))
    assert page.text_content("#point-count") == f"{len(cloud):,}" and len(cloud) > 30_000
    depth_png = np.asarray(Image.open(io.BytesIO(download(page, "depth-png16"))))
    assert depth_png.dtype == np.uint16 and depth_png.shape == SAMPLE_SIZE


def test_calibration_file_search_start_and_cloud_options(page, tmp_path: Path) -> None:
    """A Middlebury calib.txt instead of typed numbers (they are switched off), min disparity, max depth
    and measured pixels only all reach the service: the cloud shrinks, the disparities start at M."""
    calib = tmp_path / "calib.txt"
    calib.write_text("cam0=[300 0 111; 0 300 92; 0 0 1]\ncam1=[300 0 113; 0 300 92; 0 0 1]\nbaseline=50\n"
                     "width=225\nheight=187\n")
    page.set_input_files("#left", str(STATIC / "sample-left.png"))
    page.set_input_files("#right", str(STATIC / "sample-right.png"))
    page.fill("#max-disparity", "24")
    page.fill("#min-disparity", "6")
    page.set_input_files("#calib", str(calib))
    assert page.is_disabled("#focal-px") and page.is_disabled("#baseline-m")
    page.click("#compute")
    _done(page)
    assert "from calib.txt (Middlebury)" in page.text_content("#calibration-read")
    assert "doffs 2 px" in page.text_content("#calibration-read")
    disparity = read_disparity_bytes(download(page, "disparity-npy"), tmp_path / "d.npy")
    assert np.nanmin(disparity) >= 6 - 1 and np.nanmax(disparity) <= 6 + 24
    everything = int(page.text_content("#point-count").replace(",", ""))
    page.fill("#max-depth", "1.2")
    page.check("#drop-filled")
    page.click("#compute")
    _done(page)
    kept = read_ply(download(page, "pointcloud-ply"))
    assert int(page.text_content("#point-count").replace(",", "")) == len(kept) < everything * 0.9
    assert kept["z"].max() <= 1.2
    depth = np.load(io.BytesIO(download(page, "depth-npy")))
    assert np.nanmax(depth) <= 1.2
    assert download(page, "depth-pfm").startswith(b"Pf\n")
    page.click("#clear-calib")
    assert not page.is_disabled("#focal-px")


def test_pair_warnings_are_shown(page) -> None:
    page.set_input_files("#left", str(STATIC / "sample-right.png"))  # swapped
    page.set_input_files("#right", str(STATIC / "sample-left.png"))
    page.fill("#max-disparity", "32")
    page.click("#compute")
    _done(page)
    assert not page.is_hidden("#warnings")
    assert page.text_content("#warnings li").startswith("swapped: the pair looks swapped")


def test_colours_are_the_service_colour_table_in_a_fixed_range(page, tmp_path: Path) -> None:
    """The page's Turbo table is service/io/colormap.py's; a fixed range paints value v at index
    round((v - low) * 255 / (high - low)), the same in every frame."""
    table = page.evaluate("async () => Array.from((await import('/static/colormap.js')).TURBO)")
    np.testing.assert_array_equal(np.asarray(table, np.uint8).reshape(256, 3), TURBO)
    page.click("#use-sample")
    page.wait_for_function("document.getElementById('pair-source').textContent.includes('sample')")
    page.fill("#focal-px", "")
    page.fill("#baseline-m", "")
    page.click("#compute")
    _done(page)
    disparity = read_disparity_bytes(download(page, "disparity-npy"), tmp_path / "d.npy")
    automatic = canvas_pixels(page, "#disparity")
    page.check("#range-fixed")
    page.fill("#disparity-low", "0")
    page.fill("#disparity-high", "40")
    fixed = canvas_pixels(page, "#disparity")
    assert np.any(fixed != automatic)
    valid = np.isfinite(disparity)
    index = np.clip(np.floor(disparity[valid].astype(np.float64) * (255 / 40) + 0.5), 0, 255).astype(int)
    np.testing.assert_array_equal(fixed[valid], TURBO[index])
    assert (fixed[~valid] == 0).all()
    assert page.text_content("#disparity-scale .ticks") == "0.010.020.030.040.0 px"


def test_an_error_clears_the_old_results(page, tmp_path: Path) -> None:
    left, right = _write_pair(tmp_path)
    page.set_input_files("#left", str(left))
    page.set_input_files("#right", str(right))
    page.click("#compute")
    _done(page)
    assert not page.is_hidden("#results")
    narrow = tmp_path / "narrow"
    narrow.mkdir()
    _, other = _write_pair(narrow, width=64)
    page.set_input_files("#right", str(other))
    page.click("#compute")
    page.wait_for_function("document.getElementById('status').className === 'error'")
    assert page.text_content("#status").startswith("400: left and right images differ in size")
    assert page.is_hidden("#results")
    assert page.evaluate("document.getElementById('disparity').width") == 0
    # A camera half given is refused by the page before anything is sent.
    page.set_input_files("#right", str(right))
    page.fill("#focal-px", "500")
    page.click("#compute")
    page.wait_for_function("document.getElementById('status').className === 'error'")
    assert "baseline" in page.text_content("#status") and page.is_hidden("#results")


def test_narrow_screen_layout(browser, server_url, tmp_path: Path) -> None:
    """On a 360 px wide phone nothing sticks out sideways (fieldsets were min-content wide)."""
    context = browser.new_context(viewport={"width": 360, "height": 740}, device_scale_factor=2,
                                  is_mobile=True, has_touch=True)
    page = context.new_page()
    page.set_default_timeout(60_000)
    try:
        page.goto(server_url + "/")
        page.wait_for_function("document.getElementById('readiness').textContent === 'ready'")
        page.click("#use-sample")
        page.wait_for_function("document.getElementById('pair-source').textContent.includes('sample')")
        page.click("#compute")
        _done(page)
        overflow = page.evaluate(
            """() => [...document.querySelectorAll('body *')]
                .filter((e) => e.getClientRects().length)
                .filter((e) => e.getBoundingClientRect().right > innerWidth + 0.5)
                .map((e) => e.id || e.tagName)"""
        )
        assert overflow == []
        assert page.evaluate("document.documentElement.scrollWidth") <= 360
        # Each control stays on one line with its text (the old page broke "left-right | check" apart and
        # put checkboxes at the end of one line and their words on the next).
        split = page.evaluate(
            """() => [...document.querySelectorAll('label')].filter((label) => {
                if (label.getClientRects().length > 1) return true;
                const control = label.querySelector('input');
                const text = [...label.childNodes].find((n) => n.nodeType === 3 && n.textContent.trim());
                if (!control || !text) return false;
                const range = document.createRange();
                range.selectNodeContents(text);
                const [word, box] = [range.getClientRects()[0], control.getBoundingClientRect()];
                return Math.abs((word.top + word.bottom) / 2 - (box.top + box.bottom) / 2) > word.height / 2;
            }).map((label) => label.textContent.trim())"""
        )
        assert split == []
        keep_screenshot(page, tmp_path, "demo-page-narrow.png")
    finally:
        context.close()
