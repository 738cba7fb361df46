"""First-call preparation (issue 12, item 6): kernels loaded without running, volumes mapped in advance.
Timings are measured by ``python -m bench first_call``, not here."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from service.cli import main
from service.matcher import Matcher, MatchOptions, MemoryLimitError
from tests.helpers import slanted_plane_pair

# In a fresh process (here every kernel is loaded already): load_kernels, then calls down every path of
# the pipeline; print the kernels that gained a specialisation, i.e. that the call still had to load.
_FRESH = """
import json, numpy as np
from service import jit
jit.configure_cache()
from service.kernels import load_kernels
load_kernels(confidence=True)
from service.matcher import Matcher, MatchOptions
counts = lambda: {f"{d.py_func.__module__}.{d.py_func.__qualname__}": len(d.signatures)
                  for d in jit._dispatchers}
before = counts()
matcher = Matcher.from_folder(threads=1)
left = np.random.default_rng(0).integers(0, 256, (24, 48, 3), dtype=np.uint8)
paths = ({"confidence": True}, {"lr_check": False, "fill": False}, {"min_disparity": -2}, {"sgm": False})
for options in paths:
    matcher(left, np.roll(left, -3, axis=1), MatchOptions(max_disparity=8, **options))
print(json.dumps(sorted(name for name, count in counts().items() if count != before.get(name))))
"""


def test_load_kernels_covers_every_kernel_a_call_runs() -> None:
    done = subprocess.run([sys.executable, "-c", _FRESH], capture_output=True, text=True, timeout=300,
                          check=False)
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout.strip().splitlines()[-1]) == [], (
        "these kernels were loaded by the call, not by service.kernels.load_kernels: list them there")


@pytest.fixture(scope="module")
def matcher() -> Matcher:
    return Matcher.from_folder(threads=2)


def test_a_prepared_call_gives_the_same_result(matcher) -> None:
    left, right, _, _ = slanted_plane_pair(height=40, width=100)
    options = MatchOptions(max_disparity=24, confidence=True)
    plain = matcher(left, right, options)
    fresh = Matcher(matcher.towers, threads=2)
    fresh.prepare(40, 100, options)
    fresh._prepared()
    assert fresh.workspace.nbytes == 2 * 2 * 40 * 100 * 24  # both volumes mapped before the call
    prepared = fresh(left, right, options)
    np.testing.assert_array_equal(prepared.disparity, plain.disparity)
    np.testing.assert_array_equal(prepared.confidence, plain.confidence)
    tight = Matcher(matcher.towers, threads=2, max_request_bytes=2**20)
    with pytest.raises(MemoryLimitError):
        tight.prepare(1000, 1000, options)


def test_cli_output_does_not_depend_on_preparation(capsys, monkeypatch, tmp_path) -> None:
    from PIL import Image

    left, right, _, _ = slanted_plane_pair(height=40, width=100)
    Image.fromarray(left).save(tmp_path / "l.png")
    Image.fromarray(right).save(tmp_path / "r.png")
    outputs = []
    for prepare in ("1", "0"):
        monkeypatch.setenv("ADSM_PREPARE", prepare)
        out = tmp_path / f"d{prepare}.npy"
        assert main(["predict", str(tmp_path / "l.png"), str(tmp_path / "r.png"), "-o", str(out),
                     "--max-disparity", "24", "--no-check"]) == 0, capsys.readouterr().err
        outputs.append(np.load(out))
    np.testing.assert_array_equal(*outputs)
