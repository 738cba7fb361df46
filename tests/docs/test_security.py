"""Security guarantees of SECURITY.md, each checked: non-root container, nothing unpickles input, safe
checkpoints, a bound on every input, pinned image dependencies, metrics without request data, errors
without internals, loopback by default."""

from __future__ import annotations

import ast
import io
import pickle
import re
import tomllib
from pathlib import Path

import httpx
import numpy as np
import pytest
import yaml

from service.api import Settings, create_app
from service.io import read_disparity
from tests.helpers import ROOT, TINY_PAIR, InstantMatcher, ready_client, require_module, tiny_png

CODE_DIRS = ("service", "training", "export", "bench")
SECRET = "s3cr3t-7f1c"  # planted in every part of a request; must never come back from /metrics


def _sources() -> list[Path]:
    return sorted(path for folder in CODE_DIRS for path in (ROOT / folder).rglob("*.py"))


class _Touch:
    """Unpickling this creates ``marker``: proof that something unpickled attacker data."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return Path.touch, (self.marker,)


@pytest.fixture
def anyio_backend() -> str:
    return "asyncio"


async def _client(app):
    transport = httpx.ASGITransport(app=app)
    return httpx.AsyncClient(transport=transport, base_url="http://test", timeout=30)


# --- container -------------------------------------------------------------------------------------------

def test_container_user_is_not_root() -> None:
    lines = [line.strip() for line in (ROOT / "docker" / "Dockerfile").read_text().splitlines()]
    users = [line.split()[1] for line in lines if line.upper().startswith("USER ")]
    assert users, "the Dockerfile never leaves root"
    uid = users[-1].split(":")[0]
    assert uid not in ("0", "root") and int(uid) >= 1000
    last_user = max(i for i, line in enumerate(lines) if line.upper().startswith("USER "))
    # Nothing after it runs as root.
    assert not any(line.upper().startswith("RUN ") for line in lines[last_user:])

    documents = list(yaml.safe_load_all((ROOT / "docker" / "k8s.yaml").read_text()))
    deployment = next(doc for doc in documents if doc and doc.get("kind") == "Deployment")
    pod = deployment["spec"]["template"]["spec"]
    assert pod["securityContext"]["runAsNonRoot"] is True and pod["securityContext"]["runAsUser"] == int(uid)
    for container in pod["containers"]:
        assert container["securityContext"]["allowPrivilegeEscalation"] is False
        assert container["securityContext"]["readOnlyRootFilesystem"] is True


def test_image_dependencies_are_pinned() -> None:
    constraints = (ROOT / "docker" / "constraints.txt").read_text().splitlines()
    pins = {}
    for line in constraints:
        line = line.split("#")[0].strip()
        if line:
            name, separator, version = line.partition("==")
            assert separator and re.fullmatch(r"[0-9][0-9A-Za-z.+!-]*", version), f"not an exact pin: {line}"
            pins[re.sub(r"[-_.]+", "-", name.lower())] = version
    serve = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["optional-dependencies"]["serve"]
    for requirement in serve:
        name = re.sub(r"[-_.]+", "-", re.split(r"[<>=!~\[; ]", requirement)[0].lower())
        assert name in pins, f"{name} (serve extra) is not pinned in docker/constraints.txt"
    dockerfile = (ROOT / "docker" / "Dockerfile").read_text()
    assert re.search(r"pip install --constraint docker/constraints\.txt \"\.\[serve\]\"", dockerfile)
    assert "torch" not in pins


# --- nothing unpickles input ----------------------------------------------------------------------------

def _call_name(node: ast.Call) -> str:
    return ast.unparse(node.func)


def _keyword(node: ast.Call, name: str) -> object:
    for keyword in node.keywords:
        if keyword.arg == name and isinstance(keyword.value, ast.Constant):
            return keyword.value.value
    return None


def test_no_code_path_can_unpickle() -> None:
    problems = []
    for path in _sources():
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
        where = path.relative_to(ROOT)
        for node in ast.walk(tree):
            if isinstance(node, ast.Import | ast.ImportFrom):
                is_import = isinstance(node, ast.Import)
                modules = [alias.name for alias in node.names] if is_import else [node.module]
                for module in modules:
                    if (module or "").split(".")[0] in ("pickle", "dill", "cloudpickle", "joblib", "shelve",
                                                        "marshal"):
                        problems.append(f"{where}:{node.lineno} imports {module}")
            if not isinstance(node, ast.Call):
                continue
            name = _call_name(node)
            if name in ("np.load", "numpy.load") and _keyword(node, "allow_pickle") is not False:
                problems.append(f"{where}:{node.lineno} {name} without allow_pickle=False")
            if name == "torch.load" and _keyword(node, "weights_only") is not True:
                problems.append(f"{where}:{node.lineno} torch.load without weights_only=True")
            if name in ("yaml.load", "yaml.unsafe_load", "eval", "exec"):
                problems.append(f"{where}:{node.lineno} calls {name}")
    assert not problems, "\n".join(problems)


@pytest.mark.anyio
async def test_pickles_uploaded_as_images_are_never_unpickled(tmp_path: Path) -> None:
    marker = tmp_path / "unpickled"
    payloads = {
        "pickle": pickle.dumps(_Touch(marker)),
        "npy of objects": _npy_of_objects(marker),
    }
    app = create_app(Settings(), matcher=InstantMatcher())
    async with ready_client(app) as client:
        for kind, payload in payloads.items():
            files = {"left": ("l.npy", payload, "application/octet-stream"), "right": TINY_PAIR["right"]}
            response = await client.post("/disparity", files=files)
            assert response.status_code == 415, (kind, response.text)
    assert not marker.exists()


def _npy_of_objects(marker: Path) -> bytes:
    buffer = io.BytesIO()
    np.save(buffer, np.array([_Touch(marker)], dtype=object), allow_pickle=True)
    return buffer.getvalue()


def test_disparity_files_with_objects_are_refused(tmp_path: Path) -> None:
    marker = tmp_path / "unpickled"
    path = tmp_path / "d.npy"
    path.write_bytes(_npy_of_objects(marker))
    with pytest.raises(ValueError, match="allow_pickle"):
        read_disparity(path)
    assert not marker.exists()


@pytest.mark.torch
def test_checkpoints_refuse_pickled_code(tmp_path: Path) -> None:
    torch = require_module("torch")
    from training.checkpoint import load_checkpoint

    marker = tmp_path / "unpickled"
    path = tmp_path / "evil.pt"
    torch.save({"format": "adsm", "model": _Touch(marker)}, path)
    with pytest.raises(ValueError, match="not a readable ADSM checkpoint"):
        load_checkpoint(path)
    assert not marker.exists()


# --- a bound on every input -----------------------------------------------------------------------------

def test_every_stereo_parameter_is_bounded() -> None:
    schema = create_app(Settings(), matcher=InstantMatcher()).openapi()
    for path in ("/disparity", "/depth", "/pointcloud"):
        for parameter in schema["paths"][path]["post"]["parameters"]:
            variants = parameter["schema"].get("anyOf", [parameter["schema"]])
            for variant in variants:
                kind = variant.get("type")
                if kind in ("number", "integer") and parameter["name"] != "max_disparity":
                    assert {"maximum", "exclusiveMaximum"} & set(variant), (path, parameter["name"])
                    assert {"minimum", "exclusiveMinimum"} & set(variant), (path, parameter["name"])
                elif kind == "string":  # a choice, or a bounded pattern (colormap_range's "low,high")
                    bounded = "enum" in variant or {"pattern", "maxLength"} <= set(variant)
                    assert bounded, (path, parameter["name"])
                else:
                    assert kind in ("boolean", "null", "integer"), (path, parameter["name"], kind)
    # max_disparity's upper bound is a setting (ADSM_MAX_DISPARITY), checked per request: see
    # tests/service/api/test_bad_input.py ("max_disparity above the server limit", "max_disparity 10^30").


# --- what the service gives away ------------------------------------------------------------------------

@pytest.mark.anyio
async def test_metrics_expose_no_request_data() -> None:
    app = create_app(Settings(max_body_bytes=50_000), matcher=InstantMatcher())
    files = {"left": (f"{SECRET}.png", tiny_png(), "image/png"),
             "right": (f"{SECRET}-r.png", tiny_png(), "image/png")}
    headers = {"X-Request-ID": SECRET, "User-Agent": SECRET, "Cookie": f"session={SECRET}",
               "Authorization": f"Bearer {SECRET}"}
    async with ready_client(app) as client:
        assert (await client.post("/disparity", files=files, headers=headers)).status_code == 200
        await client.post("/disparity", params={SECRET: "1"}, files=files, headers=headers)
        await client.post("/disparity", params={"max_disparity": SECRET}, files=files)
        await client.post("/disparity",
                          files={"left": (SECRET, SECRET.encode()), "right": TINY_PAIR["right"]})
        await client.post("/disparity", content=SECRET.encode() * 10_000)
        await client.get(f"/{SECRET}")
        await client.get(f"/static/{SECRET}.js")
        await client.request("DELETE", f"/disparity?{SECRET}=1")
        text = (await client.get("/metrics")).text
    assert SECRET not in text
    routes = set(re.findall(r'route="([^"]*)"', text))
    assert routes <= {"/disparity", "/depth", "/pointcloud", "/healthz", "/readyz", "/metrics", "/v1/model",
                      "/", "/static", "unmatched"}, routes
    statuses = set(re.findall(r'status="([^"]*)"', text))
    assert all(re.fullmatch(r"[1-5][0-9][0-9]", status) for status in statuses), statuses


@pytest.mark.anyio
async def test_a_crash_reveals_no_internals() -> None:
    app = create_app(Settings(), matcher=InstantMatcher(error=RuntimeError(f"boom in /secret/{SECRET}.py")))
    async with ready_client(app) as client:
        response = await client.post("/disparity", files=TINY_PAIR)
        assert (await client.get("/healthz")).status_code == 200  # still up
    assert response.status_code == 500
    assert response.json() == {"detail": f"internal error (request {response.headers['x-request-id']})"}
    assert SECRET not in response.text


@pytest.mark.anyio
async def test_static_files_do_not_escape_their_folder() -> None:
    app = create_app(Settings(), matcher=InstantMatcher())
    client = await _client(app)
    async with client:
        for path in ("/static/../app.py", "/static/%2e%2e/app.py", "/static/..%2fapp.py",
                     "/static/%2e%2e%2f%2e%2e%2fpyproject.toml"):
            response = await client.get(path)
            assert response.status_code == 404, path
            assert "create_app" not in response.text and "[project]" not in response.text


def test_serve_binds_loopback_by_default(monkeypatch) -> None:
    import uvicorn

    from service.cli import main

    for name in ("ADSM_HOST", "ADSM_PORT", "ADSM_MODEL_DIR", "ADSM_THREADS"):
        monkeypatch.setenv(name, "")
    calls = []
    monkeypatch.setattr(uvicorn, "run", lambda *args, **kwargs: calls.append(kwargs))
    assert main(["serve"]) == 0
    assert calls[0]["host"] == "127.0.0.1"
