"""Model folder manifest (`manifest.json`, schema `adsm-model/1`): read, validate, write, verify hashes.

The JSON schema next to this module is the source of truth. The service extra does not ship
`jsonschema` (it pulls four more packages into the runtime image for one file), so
:func:`validate_manifest` implements exactly the keywords that schema uses; the tests check it agrees
with `jsonschema` on the shipped schema.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import re
from functools import cache
from pathlib import Path
from typing import Any

from service.features.card import write_card

SCHEMA_ID = "adsm-model/1"
MANIFEST_NAME = "manifest.json"
TOWER_FILES = ("left.onnx", "right.onnx")
SCHEMA_PATH = Path(__file__).with_name("manifest.schema.json")
# The shipped default model is named by one line in this file, so a trained model replaces the baseline
# by editing a file, not code; ADSM_MODEL_DIR overrides it at run time.
MODELS_DIR = Path(__file__).resolve().parent.parent / "models"
DEFAULT_POINTER = MODELS_DIR / "DEFAULT"
MODEL_DIR_ENV = "ADSM_MODEL_DIR"


class ModelError(Exception):
    """A model folder cannot be used: missing files, invalid manifest, or a file whose hash differs."""


def default_model_dir() -> Path:
    """The model folder used when none is given: ``$ADSM_MODEL_DIR`` or the one named in models/DEFAULT."""
    override = os.environ.get(MODEL_DIR_ENV)
    if override:
        return Path(override)
    try:
        name = DEFAULT_POINTER.read_text(encoding="utf-8").strip()
    except OSError as error:
        raise ModelError(f"cannot read the default model pointer {DEFAULT_POINTER}: {error}") from error
    if not name or "/" in name or "\\" in name or name.startswith("."):
        raise ModelError(f"{DEFAULT_POINTER} must contain one model folder name, got {name!r}")
    return MODELS_DIR / name


@cache
def schema() -> dict[str, Any]:
    """The manifest JSON schema as a dict (read once)."""
    return json.loads(SCHEMA_PATH.read_text(encoding="utf-8"))


def load_manifest(folder: str | Path) -> dict[str, Any]:
    """Parse and validate ``folder/manifest.json``; raise :class:`ModelError` saying what is wrong."""
    path = Path(folder) / MANIFEST_NAME
    if not Path(folder).is_dir():
        raise ModelError(f"model folder {folder} does not exist or is not a directory")
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as error:
        raise ModelError(f"cannot read {path}: {error.strerror or error}") from error
    except UnicodeDecodeError as error:
        raise ModelError(f"{path} is not UTF-8 text ({error.reason} at byte {error.start})") from error
    try:
        manifest = json.loads(text)
    except json.JSONDecodeError as error:
        raise ModelError(f"{path} is not valid JSON: {error}") from error
    try:
        validate_manifest(manifest)
    except ModelError as error:
        raise ModelError(f"{path}: {error}") from error
    return manifest


def validate_manifest(manifest: dict[str, Any]) -> None:
    """Raise :class:`ModelError` naming the first key that does not satisfy the schema."""
    root = schema()
    problem = _check(manifest, root, root, "manifest")
    if problem:
        raise ModelError(problem)


def file_entry(path: str | Path) -> dict[str, Any]:
    """The manifest's record of one file: ``{"sha256": hex digest, "bytes": size}``."""
    digest = hashlib.sha256()
    size = 0
    with open(path, "rb") as stream:
        for block in iter(lambda: stream.read(1 << 20), b""):
            digest.update(block)
            size += len(block)
    return {"sha256": digest.hexdigest(), "bytes": size}


def write_manifest(folder: str | Path, manifest: dict[str, Any]) -> Path:
    """Fill ``files`` from the tower files in ``folder``, validate, and write ``manifest.json`` and the
    folder's card (``README.md``, generated from it: service/features/card.py)."""
    folder = Path(folder)
    missing = [name for name in TOWER_FILES if not (folder / name).is_file()]
    if missing:
        raise ModelError(f"cannot write a manifest for {folder}: missing {', '.join(missing)}")
    manifest = {**manifest, "schema": SCHEMA_ID}
    manifest["files"] = {name: file_entry(folder / name) for name in TOWER_FILES}
    validate_manifest(manifest)
    path = folder / MANIFEST_NAME
    path.write_text(json.dumps(manifest, indent=2, sort_keys=False) + "\n", encoding="utf-8")
    write_card(folder, manifest)  # whoever rewrites the figures rewrites the card: it cannot drift
    return path


def verify_files(folder: str | Path, manifest: dict[str, Any]) -> None:
    """Check every file listed in ``manifest.files`` against its sha256; refuse a folder that differs."""
    for name, expected in manifest["files"].items():
        path = Path(folder) / name
        if not path.is_file():
            raise ModelError(f"model file {path} is missing")
        actual = file_entry(path)["sha256"]
        if actual != expected["sha256"]:
            raise ModelError(
                f"model file {path} does not match its manifest: sha256 {actual}, expected "
                f"{expected['sha256']} (modified or corrupted; re-export the model folder)"
            )


_TYPES: dict[str, Any] = {
    "object": lambda v: isinstance(v, dict),
    "array": lambda v: isinstance(v, list),
    "string": lambda v: isinstance(v, str),
    "boolean": lambda v: isinstance(v, bool),
    "null": lambda v: v is None,
    # JSON has no int/float split; bool is a Python int but never a JSON number.
    "integer": lambda v: (isinstance(v, int) and not isinstance(v, bool))
    or (isinstance(v, float) and v.is_integer()),
    "number": lambda v: isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v),
}


def _check(value: Any, node: dict[str, Any], root: dict[str, Any], where: str) -> str | None:
    """Return a message for the first violation of schema ``node`` by ``value``, else None."""
    if "$ref" in node:
        ref = node["$ref"]
        if not ref.startswith("#/$defs/"):
            raise ValueError(f"unsupported $ref {ref} in {SCHEMA_PATH}")
        node = root["$defs"][ref.removeprefix("#/$defs/")]
    if "oneOf" in node:
        matches = [s for s in node["oneOf"] if _check(value, s, root, where) is None]
        if len(matches) != 1:
            alternatives = " | ".join(str(s.get("type", "?")) for s in node["oneOf"])
            return f"{where} must be exactly one of: {alternatives}; got {value!r:.60}"
    if "const" in node and value != node["const"]:
        return f"{where} must be {node['const']!r}, got {value!r:.60}"
    if "enum" in node and value not in node["enum"]:
        return f"{where} must be one of {node['enum']}, got {value!r:.60}"
    if "type" in node:
        kinds = node["type"] if isinstance(node["type"], list) else [node["type"]]
        if not any(_TYPES[k](value) for k in kinds):
            return f"{where} must be of type {' or '.join(kinds)}, got {type(value).__name__} {value!r:.60}"
    if isinstance(value, int | float) and not isinstance(value, bool):
        if "minimum" in node and value < node["minimum"]:
            return f"{where} must be >= {node['minimum']}, got {value}"
        if "exclusiveMinimum" in node and value <= node["exclusiveMinimum"]:
            return f"{where} must be > {node['exclusiveMinimum']}, got {value}"
        if "maximum" in node and value > node["maximum"]:
            return f"{where} must be <= {node['maximum']}, got {value}"
    if isinstance(value, str) and "pattern" in node and not re.search(node["pattern"], value):
        return f"{where} must match {node['pattern']}, got {value!r:.60}"
    if isinstance(value, list):
        if len(value) < node.get("minItems", 0) or len(value) > node.get("maxItems", math.inf):
            return f"{where} must have {node.get('minItems')}..{node.get('maxItems')} items, got {len(value)}"
        for index, item in enumerate(value):
            if "items" in node and (problem := _check(item, node["items"], root, f"{where}[{index}]")):
                return problem
    if isinstance(value, dict):
        return _check_object(value, node, root, where)
    return None


def _check_object(
    value: dict[str, Any], node: dict[str, Any], root: dict[str, Any], where: str
) -> str | None:
    for key in node.get("required", ()):
        if key not in value:
            return f"{where} is missing the required key {key!r}"
    properties = node.get("properties", {})
    extra = node.get("additionalProperties", True)
    for key, item in value.items():
        if key in properties:
            sub = properties[key]
        elif extra is False:
            return f"{where} has an unknown key {key!r} (allowed: {', '.join(properties)})"
        elif isinstance(extra, dict):
            sub = extra
        else:
            continue
        if problem := _check(item, sub, root, f"{where}.{key}"):
            return problem
    return None
