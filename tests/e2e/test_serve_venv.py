"""`.[serve]` alone in a fresh venv (no torch) runs the image's exact entry point and command.

Reads docker/Dockerfile so the test and the image cannot drift: the same constraints file, the same
cache-seeding command, the same ENV, ENTRYPOINT and CMD (only the port, the listening address and the
cache folders point at this machine). pip installs from the local caches and indexes where present.
"""

from __future__ import annotations

import io
import json
import os
import shlex
import socket
import subprocess
import sys
import time
from pathlib import Path

import httpx
import numpy as np
import pytest
from PIL import Image

from tests.helpers import ROOT

DOCKERFILE = ROOT / "docker" / "Dockerfile"
SAMPLE = ROOT / "service" / "api" / "static"

pytestmark = pytest.mark.slow


def dockerfile_instructions() -> list[tuple[str, str]]:
    """(INSTRUCTION, arguments) pairs, continuation lines joined, comments dropped."""
    logical, current = [], ""
    for line in DOCKERFILE.read_text(encoding="utf-8").splitlines():
        if not current and (not line.strip() or line.lstrip().startswith("#")):
            continue
        current += line.rstrip("\\").strip() + " " if line.endswith("\\") else line.strip()
        if not line.endswith("\\"):
            logical.append(current)
            current = ""
    return [(text.split(None, 1)[0].upper(), text.split(None, 1)[1]) for text in logical]


def image_env() -> dict[str, str]:
    env: dict[str, str] = {}
    for instruction, arguments in dockerfile_instructions():
        if instruction == "ENV":
            for assignment in shlex.split(arguments):
                key, _, value = assignment.partition("=")
                env[key] = value
    return env


def seed_command() -> list[str]:
    """The `python -c "..."` of the RUN line that compiles the Numba cache at build time."""
    for instruction, arguments in dockerfile_instructions():
        if instruction == "RUN" and "warmup()" in arguments:
            words = shlex.split(arguments)
            start = words.index("python")
            return words[start:start + 3]
    raise AssertionError("no cache-seeding RUN line in docker/Dockerfile")


def exec_form(name: str) -> list[str]:
    return json.loads(next(args for instruction, args in dockerfile_instructions() if instruction == name))


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


@pytest.fixture(scope="module")
def serve_venv(tmp_path_factory) -> Path:
    venv = tmp_path_factory.mktemp("serve-venv") / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True, timeout=120)
    install = subprocess.run(
        [str(venv / "bin" / "pip"), "install", "--quiet",
         "--constraint", str(ROOT / "docker" / "constraints.txt"), f"{ROOT}[serve]"],
        capture_output=True, text=True, timeout=900,
    )
    assert install.returncode == 0, install.stderr[-3000:]
    return venv


def test_serve_extra_has_no_torch(serve_venv: Path) -> None:
    probe = subprocess.run([str(serve_venv / "bin" / "python"), "-c", "import torch"], capture_output=True,
                           text=True, timeout=60)
    assert probe.returncode != 0 and "No module named 'torch'" in probe.stderr


def test_eval_on_synthetic_names_the_train_extra(serve_venv: Path, tmp_path: Path) -> None:
    finished = subprocess.run([str(serve_venv / "bin" / "adsm"), "eval", "--data", "synthetic:1"],
                              capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert finished.returncode == 1 and "Traceback" not in finished.stderr, finished.stderr[-3000:]
    assert finished.stderr.startswith("adsm: error: dataset 'synthetic:1' needs the train extra "
                                      "(pip install -e '.[train]')") and finished.stderr.count("\n") == 1


def test_image_command_serves_from_the_venv(serve_venv: Path, tmp_path: Path) -> None:
    env = {**os.environ, **image_env()}
    env["PATH"] = f"{serve_venv / 'bin'}{os.pathsep}{env['PATH']}"
    env.pop("PYTHONPATH", None)
    env["ADSM_NUMBA_CACHE_SEED"] = str(tmp_path / "seed")
    subprocess.run(seed_command(), env={**env, "ADSM_NUMBA_CACHE_DIR": env["ADSM_NUMBA_CACHE_SEED"]},
                   cwd=tmp_path, check=True, timeout=600)
    assert list((tmp_path / "seed").rglob("*.nbi")), "the seeding command wrote no Numba cache"

    port = _free_port()
    env.update(ADSM_PORT=str(port), ADSM_HOST="127.0.0.1", ADSM_NUMBA_CACHE_DIR=str(tmp_path / "cache"))
    entrypoint, command = exec_form("ENTRYPOINT"), exec_form("CMD")
    assert entrypoint == ["adsm-entrypoint"]  # COPY docker/entrypoint.sh /usr/local/bin/adsm-entrypoint
    argv = [str(ROOT / "docker" / "entrypoint.sh"), *command]
    server = subprocess.Popen(argv, env=env, cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    base = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + 300
        while True:
            assert server.poll() is None, server.stdout.read().decode(errors="replace")[-3000:]
            try:
                if httpx.get(f"{base}/readyz", timeout=5).status_code == 200:
                    break
            except httpx.TransportError:
                pass
            assert time.monotonic() < deadline, "not ready within 300 s"
            time.sleep(0.25)
        # The entry point copied the seeded cache into a fresh private folder.
        cache = tmp_path / "cache"
        assert list(cache.rglob("*.nbi")) and cache.stat().st_mode & 0o777 == 0o700
        files = {side: (f"{side}.png", (SAMPLE / f"sample-{side}.png").read_bytes())
                 for side in ("left", "right")}
        response = httpx.post(f"{base}/disparity", params={"max_disparity": 32}, files=files, timeout=120)
        assert response.status_code == 200, response.text
        disparity = np.asarray(Image.open(io.BytesIO(response.content)))
        assert disparity.dtype == np.uint16 and disparity.shape == (187, 225)
        assert (disparity > 0).mean() > 0.5
        assert "sgm;dur=" in response.headers["server-timing"]
        # /docs from the installed package's vendored Swagger UI (package data), not from a CDN.
        docs = httpx.get(f"{base}/docs", timeout=10)
        assert docs.status_code == 200 and "https://" not in docs.text
        for name in ("swagger-ui-bundle.js", "swagger-ui.css", "favicon-32x32.png"):
            asset = httpx.get(f"{base}/static/vendor/swagger-ui/{name}", timeout=10)
            assert asset.status_code == 200 and asset.content, name
    finally:
        server.terminate()
        output = server.communicate(timeout=60)[0].decode(errors="replace")
    # uvicorn shuts down gracefully on SIGTERM, then re-raises the signal: exit status -15 is expected.
    assert server.returncode in (0, -15) and "Finished server process" in output, output[-3000:]
