"""The ``--json OUT`` report of the measuring subcommands (`adsm eval`, `adsm stats`): its file is checked
before any work, and the report goes to stdout as JSON (``-``), or as a table with the JSON in OUT."""

from __future__ import annotations

import json
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any


def report_path(text: str | None) -> Path | None:
    """The file of ``--json`` (None: no file, or ``-`` for stdout), refused when it cannot be written: the
    report is written once every pair is measured, which on a large dataset is hours later."""
    if text is None or text == "-":
        return None
    path = Path(text)
    if path.is_dir():
        raise ValueError(f"--json {text!r} is a folder; name the report's file")
    if not path.parent.is_dir():
        raise ValueError(f"--json {text!r}: the folder {str(path.parent)!r} does not exist")
    return path


def emit_report(report: dict[str, Any], text: str | None, table: Callable[[dict[str, Any]], str]) -> None:
    """``--json -``: the report as JSON on stdout; otherwise ``table(report)`` on stdout and, with
    ``--json OUT``, the report in OUT (checked by :func:`report_path` before the work)."""
    if text == "-":
        json.dump(report, sys.stdout, indent=2)
        print()
        return
    print(table(report))
    path = report_path(text)
    if path is not None:
        path.write_text(json.dumps(report, indent=2) + "\n")
