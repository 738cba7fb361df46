"""The arena bound (issue 15, finding 3): `adsm serve` at the default limits, sent a growing sequence of
the worst valid shapes, stays under its idle size + memory_bound() (docs/service.md#memory), measured on
the server process alone by `python -m bench memory`."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from tests.helpers import ROOT


@pytest.mark.slow
def test_rss_stays_under_the_documented_bound_over_a_growing_sequence_of_requests(tmp_path: Path) -> None:
    out = tmp_path / "memory.json"
    shapes = ["375,1242,192", "64,32768", "1080,1920", "1449,1449", "8,262144"]
    subprocess.run([sys.executable, "-m", "bench", "memory", "--threads", "2", "--json", str(out),
                    "--shapes", *shapes], cwd=ROOT, check=True, timeout=900, capture_output=True)
    result = json.loads(out.read_text())
    statuses = [row["status"] for row in result["rows"]]
    assert statuses == [200, 200, 200, 200, 413], result  # the thin one: tower work over the limit
    for row in result["rows"]:
        assert row["peak_mib"] <= result["bound_mib"], result
        assert row["rss_mib"] <= result["bound_mib"], result
