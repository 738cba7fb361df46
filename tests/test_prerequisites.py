"""helpers.require: a missing prerequisite skips a test locally and fails it under CI=true; every test
with a prerequisite goes through it (no bare pytest.skip / skipif / importorskip elsewhere)."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

from tests import helpers
from tests.helpers import ROOT, TESTS, cones_folder, require, require_module

SKIPS = {"skip", "skipif", "importorskip"}


@pytest.fixture(params=["local", "ci"])
def where(request, monkeypatch) -> str:
    if request.param == "ci":
        monkeypatch.setenv("CI", "true")
    else:
        monkeypatch.delenv("CI", raising=False)
    return request.param


def _outcome(call) -> str:
    try:
        call()
    except pytest.skip.Exception:
        return "skipped"
    except pytest.fail.Exception as failure:
        assert "missing prerequisite under CI=true" in str(failure)
        return "failed"
    return "ran"


def test_a_missing_prerequisite_skips_locally_and_fails_in_ci(where):
    expected = {"local": "skipped", "ci": "failed"}[where]
    assert _outcome(lambda: require(True, "present")) == "ran"
    assert _outcome(lambda: require(False, "absent")) == expected
    assert _outcome(lambda: require_module("json")) == "ran"
    assert _outcome(lambda: require_module("adsm_no_such_module")) == expected


def test_the_cones_pair_goes_through_require(where, monkeypatch, tmp_path):
    monkeypatch.setattr(helpers, "CONES", tmp_path / "absent")
    assert _outcome(cones_folder) == {"local": "skipped", "ci": "failed"}[where]
    folder = tmp_path / "cones"
    folder.mkdir()
    for name in ("left.png", "disp_left.png"):
        (folder / name).write_bytes(b"")
    monkeypatch.setattr(helpers, "CONES", folder)
    assert cones_folder() == folder


def test_ci_run_reports_a_failure_not_a_skip(tmp_path):
    """Through pytest itself: the same missing prerequisite is a skip, and under CI=true an exit code of 1."""
    (tmp_path / "test_needs.py").write_text(
        f"import sys; sys.path.insert(0, {str(ROOT)!r})\n"
        "from tests.helpers import require\n\n"
        "def test_needs():\n    require(False, 'a thing that is not here')\n")
    runs = {}
    for ci in ("", "true"):
        runs[ci] = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                                   "--rootdir", str(tmp_path), str(tmp_path / "test_needs.py")],
                                  capture_output=True, text=True, timeout=120, cwd=tmp_path,
                                  env={"PATH": "/usr/bin:/bin", "CI": ci})
    assert runs[""].returncode == 0 and "1 skipped" in runs[""].stdout, runs[""].stdout
    assert runs["true"].returncode == 1 and "1 failed" in runs["true"].stdout, runs["true"].stdout
    assert "missing prerequisite under CI=true: a thing that is not here" in runs["true"].stdout


def test_no_test_skips_on_its_own():
    """Every skip goes through helpers.require, so that CI=true turns it into a failure."""
    offenders = []
    for path in sorted(TESTS.rglob("*.py")):
        if path in (TESTS / "helpers.py", Path(__file__).resolve()):  # the helper, and this test of it
            continue
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Attribute) and node.attr in SKIPS:
                offenders.append(f"{path.relative_to(TESTS)}:{node.lineno} .{node.attr}")
    assert offenders == [], "use helpers.require / require_module / cones_folder instead"
