"""Offline pages: every page the service serves loads only from the service itself (issue 13, item 1).

/docs used to load Swagger UI from a CDN (a blank page without internet). Its files now ship in
service/api/static/vendor/swagger-ui/; these tests check the pages' references, that each answers 200
with its content type, that the vendored files are the ones the README there names, that a
non-editable install carries them (package data), and (Chromium) that the page renders the API with no
request leaving the server.
"""

from __future__ import annotations

import hashlib
import html.parser
import os
import re
import shutil
import tomllib
from pathlib import Path

import httpx
import pytest

from service.api import Settings, create_app
from tests.helpers import ROOT, InstantMatcher, ready_client, require, require_module, served_in_thread

STATIC = ROOT / "service" / "api" / "static"
VENDOR = STATIC / "vendor" / "swagger-ui"
PAGES = ("/", "/docs")  # every HTML page the app serves (the demo page is "/")
# What a reference must answer with, by the file's ending; links to other pages answer HTML or JSON.
CONTENT_TYPES = {".js": ("text/javascript", "application/javascript"), ".css": ("text/css",),
                 ".png": ("image/png",), ".json": ("application/json",)}


class _References(html.parser.HTMLParser):
    """Every src / href of a page, and the URLs its inline scripts name in ``url: '...'``."""

    def __init__(self) -> None:
        super().__init__()
        self.found: list[tuple[str, str]] = []
        self._script = False

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        self.found += [(tag, value) for name, value in attrs if name in ("src", "href") and value]
        self._script = tag == "script"

    def handle_endtag(self, tag: str) -> None:
        self._script = False

    def handle_data(self, data: str) -> None:
        if self._script:
            self.found += [("script-url", url) for url in re.findall(r"""\burl:\s*['"]([^'"]+)['"]""", data)]


def references(page: str) -> list[tuple[str, str]]:
    parser = _References()
    parser.feed(page)
    return parser.found


@pytest.fixture(scope="module")
def anyio_backend() -> str:
    return "asyncio"


@pytest.mark.anyio
async def test_pages_reference_only_the_service_and_every_reference_answers() -> None:
    async with ready_client(create_app(Settings(), matcher=InstantMatcher())) as client:
        for path in PAGES:
            page = await client.get(path)
            assert page.status_code == 200 and page.headers["content-type"].startswith("text/html"), path
            found = references(page.text)
            assert found, f"{path} references nothing: the parser missed its assets"
            outside = [url for _, url in found if "://" in url or url.startswith("//")]
            assert not outside, f"{path} references outside URLs: {outside}"
            for tag, url in found:
                answer = await client.get(url)
                assert answer.status_code == 200, f"{path}: {tag} {url} answers {answer.status_code}"
                expected = CONTENT_TYPES.get(Path(url.split("?")[0]).suffix)
                if expected is not None:
                    assert answer.headers["content-type"].startswith(expected), (url, answer.headers)
        docs = (await client.get("/docs")).text
        assert {url for _, url in references(docs)} >= {
            "/static/vendor/swagger-ui/swagger-ui-bundle.js", "/static/vendor/swagger-ui/swagger-ui.css",
            "/static/vendor/swagger-ui/favicon-32x32.png", "/openapi.json"}
        assert '"validatorUrl": null' in docs  # no badge fetched from validator.swagger.io
        # ReDoc is not served (service/api/routes/docs.py says why); FastAPI's OAuth2 redirect page is not
        # needed.
        assert (await client.get("/redoc")).status_code == 404


@pytest.mark.anyio
async def test_docs_honour_a_root_path() -> None:
    """Behind a proxy that strips /stereo, the page must name /stereo/... or every asset 404s."""
    app = create_app(Settings(), matcher=InstantMatcher())
    async with app.router.lifespan_context(app):
        transport = httpx.ASGITransport(app=app, root_path="/stereo")
        async with httpx.AsyncClient(transport=transport, base_url="http://test") as client:
            docs = (await client.get("/docs")).text
    urls = {url for _, url in references(docs)}
    assert "/stereo/static/vendor/swagger-ui/swagger-ui-bundle.js" in urls and "/stereo/openapi.json" in urls


def test_vendored_files_are_those_the_readme_names() -> None:
    readme = (VENDOR / "README.md").read_text(encoding="utf-8")
    table = dict(re.findall(r"^\| (\S+) \| ([0-9a-f]{64}) \|$", readme, flags=re.M))
    assert table, "no sha256 table in the vendored README"
    assert {path.name for path in VENDOR.iterdir()} == {*table, "README.md"}
    for name, digest in table.items():
        assert hashlib.sha256((VENDOR / name).read_bytes()).hexdigest() == digest, f"{name} was modified"
    assert "npm pack swagger-ui-dist@" in readme
    assert "Apache License" in (VENDOR / "LICENSE").read_text(encoding="utf-8")


def test_package_data_ships_every_static_file() -> None:
    """setuptools copies only what `package-data` globs match (relative to service/); a missed vendored file
    would 404 on every non-editable install (the image included) while tests in the checkout pass."""
    config = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
    patterns = config["tool"]["setuptools"]["package-data"]["service"]
    package = ROOT / "service"
    shipped = {path for pattern in patterns for path in package.glob(pattern) if path.is_file()}
    files = {path for path in STATIC.rglob("*") if path.is_file() and "__pycache__" not in path.parts}
    missing = sorted(str(path.relative_to(package)) for path in files - shipped)
    assert not missing, f"not in pyproject.toml [tool.setuptools.package-data]: {missing}"


# --- in Chromium: the page renders, and no request leaves the server --------------------------------------

CHROMIUM = "/usr/bin/chromium"


@pytest.fixture(scope="module")
def server_url():
    with served_in_thread(create_app(Settings(), matcher=InstantMatcher()), timeout=60) as url:
        yield url


def test_docs_render_in_chromium_without_outside_requests(server_url: str) -> None:
    require(os.access(CHROMIUM, os.X_OK) or shutil.which("chromium") is not None,
            f"Chromium at {CHROMIUM} (apt-get install chromium; .ci/run does as root)")
    playwright_api = require_module("playwright.sync_api")
    requested: list[str] = []
    failed: list[str] = []
    with playwright_api.sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=shutil.which("chromium") or CHROMIUM,
                                             args=["--headless", "--no-sandbox", "--disable-gpu",
                                                   "--disable-background-networking"])
        try:
            page = browser.new_page()
            page.set_default_timeout(30_000)

            def record(route) -> None:
                # Anything not aimed at the server is refused, as it would fail on an offline machine.
                requested.append(route.request.url)
                if route.request.url.startswith(server_url + "/"):
                    route.continue_()
                else:
                    route.abort()

            page.route("**/*", record)
            page.on("response", lambda response: failed.append(f"{response.status} {response.url}")
                    if response.status >= 400 else None)
            page.goto(server_url + "/docs")
            page.wait_for_selector(".swagger-ui .info .title")
            title = page.inner_text(".swagger-ui .info .title")
            page.wait_for_selector(".opblock")
            operations = page.eval_on_selector_all(".opblock-summary-path",
                                                   "nodes => nodes.map(n => n.innerText)")
            page.goto(server_url + "/")
            page.wait_for_load_state("networkidle")
        finally:
            browser.close()
    assert "ADSM stereo service" in title
    assert {"/disparity", "/depth", "/pointcloud", "/v1/model"} <= {op.strip() for op in operations}
    outside = [url for url in requested if not url.startswith(server_url + "/")]
    assert not outside, f"requests that leave the server: {outside}"
    assert not failed, failed  # the demo page's icon included (it was a /favicon.ico 404)
