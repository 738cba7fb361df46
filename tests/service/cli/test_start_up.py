"""`adsm serve` start-up (issue 15, finding 5): a model folder whose manifest was edited by hand (it is not
hashed) or that fails its warm-up stops the start with exit status 1 and one line on stderr before the
port opens; /healthz and /readyz never show an absolute path."""

from __future__ import annotations

import json
import os
import shutil
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from service.api import Settings, create_app
from service.cli import main
from service.features import ModelError, default_model_dir, load_manifest
from service.features.towers import FeatureTowers
from tests.helpers import ROOT, InstantMatcher


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def _edited_copy(tmp_path: Path, **changes: object) -> Path:
    folder = tmp_path / "model"
    shutil.copytree(default_model_dir(), folder)
    path = folder / "manifest.json"
    path.write_text(json.dumps({**json.loads(path.read_text()), **changes}))
    return folder


# A channel count the default's towers do not have (48 was one until adsm-rf17-int8 became the default).
WRONG_CHANNELS = int(load_manifest(default_model_dir())["channels"]) + 16
EDITS = [({"channels": WRONG_CHANNELS}, f"channels {WRONG_CHANNELS}"),
         ({"receptive_field": 21}, "receptive_field 21"), ({"receptive_field": 61}, "receptive_field 61")]


@pytest.mark.parametrize(("changes", "fragment"), EDITS, ids=["channels", "receptive-field-low",
                                                               "receptive-field-high"])
def test_towers_are_checked_against_the_manifest(tmp_path: Path, changes: dict, fragment: str) -> None:
    towers = FeatureTowers(_edited_copy(tmp_path, **changes), threads=1)
    with pytest.raises(ModelError, match=fragment) as raised:
        towers.warmup()
    assert "\n" not in str(raised.value) and str(tmp_path) not in str(raised.value)


def test_every_shipped_model_passes_its_tower_check() -> None:
    for folder in sorted(path for path in default_model_dir().parent.iterdir() if path.is_dir()):
        FeatureTowers(folder, threads=1).warmup()


@pytest.mark.slow
@pytest.mark.parametrize(("changes", "fragment"), EDITS[:2], ids=["channels", "receptive-field"])
def test_edited_manifest_stops_serve_in_one_line_before_the_port_opens(
    tmp_path: Path, changes: dict, fragment: str
) -> None:
    folder = _edited_copy(tmp_path, **changes)
    port = _free_port()
    env = {key: value for key, value in os.environ.items() if not key.startswith("ADSM_")}
    env["ADSM_NUMBA_CACHE_DIR"] = os.environ["ADSM_NUMBA_CACHE_DIR"]
    done = subprocess.run(
        [sys.executable, "-m", "service", "serve", "--model", str(folder), "--port", str(port)],
        env={**env, "PYTHONPATH": str(ROOT)}, capture_output=True, text=True, timeout=300,
    )
    assert done.returncode == 1
    assert done.stderr.count("\n") == 1 and done.stderr.startswith("adsm: error: "), done.stderr
    assert fragment in done.stderr and done.stdout == ""
    with socket.socket() as probe:  # it never listened
        assert probe.connect_ex(("127.0.0.1", port)) != 0


def test_a_warm_up_failure_stops_serve_in_one_line_before_the_port_opens(monkeypatch, capsys) -> None:
    import uvicorn

    from service.matcher import Matcher

    def failing_warmup(self) -> None:
        raise RuntimeError("no kernels\nfor you")

    def never(*args, **kwargs) -> None:
        raise AssertionError("the server started")

    monkeypatch.setattr(Matcher, "warmup", failing_warmup)
    monkeypatch.setattr(uvicorn, "run", never)
    assert main(["serve", "--port", str(_free_port())]) == 1
    err = capsys.readouterr().err
    assert err == "adsm: error: model warm-up failed: RuntimeError: no kernels for you\n"


class _FailingWarmup(InstantMatcher):
    def warmup(self) -> None:
        raise ModelError("/home/alice/models/x/left.onnx returned float32 (1, 16, 64, 64), expected "
                         "float32 (1, 32, 64, 64)")


@pytest.mark.anyio
@pytest.mark.parametrize("anyio_backend", ["asyncio"])
async def test_probes_show_no_absolute_path(anyio_backend: str) -> None:
    app = create_app(Settings(), matcher=_FailingWarmup())
    async with app.router.lifespan_context(app):
        import anyio
        import httpx

        transport = httpx.ASGITransport(app=app)
        async with httpx.AsyncClient(transport=transport, base_url="http://test") as client:
            with anyio.fail_after(10):
                while app.state.inference.failure is None:
                    await anyio.sleep(0.01)
            health, ready = await client.get("/healthz"), await client.get("/readyz")
    for answer in (health, ready):
        assert answer.status_code == 503
        assert "/home/alice" not in answer.text and "left.onnx" in answer.text, answer.text


