"""Writing a model folder without ever leaving it half-written by a bad argument.

The manifest is validated (with the file entries the towers will have) before the first byte is
written, so a value the schema refuses (P1 = nan, a bad name, ...) fails before an existing folder's
towers are replaced: otherwise they would no longer match its old manifest, and the folder would be
refused by every loader.
"""

from __future__ import annotations

import hashlib
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import onnx

from service.features.manifest import SCHEMA_ID, TOWER_FILES, validate_manifest, write_manifest


def read_graph(path: str | Path) -> onnx.ModelProto:
    """An ONNX file, or a ValueError naming it (its sha256 may match a manifest and still not parse)."""
    try:
        return onnx.load(str(path))
    except Exception as error:  # protobuf's DecodeError and friends
        raise ValueError(f"{path} is not a readable ONNX graph ({error})") from None


def write_folder(out: str | Path, towers: Mapping[str, bytes], manifest: dict[str, Any]) -> Path:
    """Validate ``manifest`` for the serialised ``towers`` (file name -> bytes), then write the towers and
    the manifest (and card) into ``out``; returns the manifest path."""
    if sorted(towers) != sorted(TOWER_FILES):
        raise ValueError(f"a model folder holds {', '.join(TOWER_FILES)}, got {', '.join(towers)}")
    entries = {name: {"sha256": hashlib.sha256(data).hexdigest(), "bytes": len(data)}
               for name, data in towers.items()}
    validate_manifest({**manifest, "schema": SCHEMA_ID, "files": entries})
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    for name in TOWER_FILES:
        (out / name).write_bytes(towers[name])
    return write_manifest(out, manifest)
