"""Model cards (issue 13, item 5): each shipped folder's README.md is its manifest's card, regenerated
here and compared; writing a manifest rewrites the card; the card does not disturb hash verification;
GET /v1/model/card serves the served manifest's card; the demo page links it."""

from __future__ import annotations

import json
import shutil
import tomllib
from pathlib import Path

import httpx
import pytest

from export import card as card_command
from service.api import Settings, create_app
from service.features import load_manifest, verify_files, write_manifest
from service.features.card import CARD_NAME, PROJECT_LICENCE, model_card
from service.features.manifest import MODELS_DIR, TOWER_FILES, default_model_dir
from tests.helpers import ROOT, InstantMatcher, ready_client

SHIPPED = sorted(path.parent for path in MODELS_DIR.glob("*/manifest.json"))
MAX_FOLDER_BYTES = 20 * 1000 * 1000  # a model folder stays under 20 MB (the wheel ships all of them)


@pytest.mark.parametrize("folder", SHIPPED, ids=lambda folder: folder.name)
def test_card_is_the_manifest_card(folder: Path) -> None:
    card = folder / CARD_NAME
    assert card.is_file(), f"{card} is missing: python -m export.card --model {folder} --write"
    assert card.read_text(encoding="utf-8") == model_card(load_manifest(folder)), (
        f"{card} does not match its manifest: python -m export.card --model service/models/{folder.name} "
        "--write (export.measure --write and every export rewrite it)")


@pytest.mark.parametrize("folder", SHIPPED, ids=lambda folder: folder.name)
def test_card_says_what_a_user_asks(folder: Path) -> None:
    manifest = load_manifest(folder)
    card = (folder / CARD_NAME).read_text(encoding="utf-8")
    assert card.startswith(f"# {manifest['name']}\n")
    for heading in ("## Intended use", "## Metrics", "## Speed", "## Licence", PROJECT_LICENCE):
        assert heading in card, heading
    for name, entry in manifest["metrics"].items():
        # This folder's own figures, measured on its own ONNX files (int8 included: issue 18's fix).
        assert f"--model service/models/{folder.name} " in entry["command"], (name, entry["command"])
        row = next(line for line in card.splitlines() if line.startswith(f"| {name} "))
        assert f"| {entry['bad2']:.2f} |" in row and f"| {entry['epe']:.2f} |" in row
        assert f"{entry['seconds_per_pair']:.3f} s per pair" in card
    if manifest["training"] is not None:
        assert "**Synthetic only: no real stereo pair was used**" in card
        assert manifest["training"]["command"] in card
    if manifest["onnx"]["precision"] == "int8":
        assert "## Quantisation" in card and manifest["onnx"]["quantization"]["method"] in card


@pytest.mark.parametrize("folder", SHIPPED, ids=lambda folder: folder.name)
def test_card_leaves_hash_verification_and_size_alone(folder: Path) -> None:
    """The card is derived from the manifest, not loaded: it is not in ``files`` (whose schema allows the two
    towers only), so adding or regenerating it changes no hash, and verification passes with it there."""
    manifest = load_manifest(folder)
    assert sorted(manifest["files"]) == sorted(TOWER_FILES)
    verify_files(folder, manifest)
    size = sum(path.stat().st_size for path in folder.iterdir() if path.is_file())
    assert size < MAX_FOLDER_BYTES, f"{folder.name}: {size} bytes"


def test_writing_a_manifest_rewrites_its_card(tmp_path: Path) -> None:
    folder = tmp_path / "model"
    shutil.copytree(MODELS_DIR / "ncc-baseline", folder)
    manifest = load_manifest(folder)
    manifest["metrics"]["middlebury2003-cones"]["bad2"] = 42.4242
    write_manifest(folder, manifest)
    assert "| 42.42 |" in (folder / CARD_NAME).read_text(encoding="utf-8")
    assert card_command.main(["--model", str(folder)]) == 0

    # A manifest edited by hand (not through write_manifest): the check names the stale card, --write fixes.
    edited = json.loads((folder / "manifest.json").read_text(encoding="utf-8"))
    edited["metrics"]["middlebury2003-cones"]["bad2"] = 1.5
    (folder / "manifest.json").write_text(json.dumps(edited), encoding="utf-8")
    assert card_command.main(["--model", str(folder)]) == 1
    assert card_command.main(["--model", str(folder), "--write"]) == 0
    assert "| 1.50 |" in (folder / CARD_NAME).read_text(encoding="utf-8")
    assert card_command.main(["--model", str(folder)]) == 0


def test_every_shipped_card_passes_the_command_check() -> None:
    assert card_command.stale_cards(card_command.shipped_folders()) == []


def test_card_of_a_minimal_manifest() -> None:
    """Any schema-valid manifest has a card: no training, no build, odd metric values."""
    manifest = load_manifest(MODELS_DIR / "ncc-baseline")
    manifest = {**manifest, "metrics": {"cones": {"bad2": 12.5, "note": "x", "seconds": None}}}
    manifest.pop("build")
    card = model_card(manifest)
    assert "| cones | – | – | – | 12.50 |" in card
    assert "## Speed" not in card and "## How it was made" not in card


def test_licence_is_the_project_licence() -> None:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]
    assert project["license"]["text"] == PROJECT_LICENCE


@pytest.fixture(scope="module")
def anyio_backend() -> str:
    return "asyncio"


@pytest.mark.anyio
async def test_card_is_served_and_linked() -> None:
    async with ready_client(create_app(Settings(), matcher=InstantMatcher())) as client:
        response = await client.get("/v1/model/card")
        page = (await client.get("/")).text
        listed = (await client.get("/openapi.json")).json()["paths"]
        model = (await client.get("/v1/model")).json()
    assert response.status_code == 200 and response.headers["content-type"] == "text/markdown; charset=utf-8"
    assert response.text == (default_model_dir() / CARD_NAME).read_text(encoding="utf-8")
    assert model == load_manifest(default_model_dir())  # /v1/model keeps its fields (the manifest)
    assert 'href="/v1/model/card"' in page
    assert "text/markdown" in listed["/v1/model/card"]["get"]["responses"]["200"]["content"]


@pytest.mark.anyio
async def test_served_card_cuts_build_machine_paths() -> None:
    matcher = InstantMatcher()
    matcher.manifest = {**matcher.manifest, "build": {"command": "python -m export.to_onnx --out "
                                                      "/home/alice/secret-runs/model", "date": "today"}}
    async with ready_client(create_app(Settings(), matcher=matcher)) as client:
        text = (await client.get("/v1/model/card")).text
    assert "/home/alice" not in text and "<path>/model" in text


def test_client_reads_the_card() -> None:
    from service.client import StereoClient

    body = model_card(load_manifest(default_model_dir()))
    transport = httpx.MockTransport(lambda request: httpx.Response(200, text=body))
    assert StereoClient("http://fake", transport=transport).card() == body
