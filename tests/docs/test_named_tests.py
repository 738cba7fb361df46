"""Every test file that the docs, the deployment files or a code comment name exists, and so does every test
they name in it (``tests/e2e/test_faults.py::test_bad_model_fails_start_up_in_one_line``): a moved or
renamed test leaves no reader looking for it."""

from __future__ import annotations

import ast
import re
from pathlib import Path

from tests.helpers import ROOT

NAMED = re.compile(r"(?<![\w/.-])(tests/[\w/]+\.py)(?:::(\w+))?")
READ = ("*.md", "docs/*.md", "bench/*.md", "docker/*", ".ci/*", "Makefile", "pyproject.toml",
        "service/**/*.py", "service/**/*.js", "service/**/*.md", "training/**/*.py", "export/**/*.py",
        "bench/**/*.py", "tests/**/*.py")


def named_tests(text: str) -> list[tuple[str, str | None]]:
    """(file, test or None) for each ``tests/...py`` or ``tests/...py::test`` in ``text``."""
    return [(match.group(1), match.group(2)) for match in NAMED.finditer(text)]


def missing(text: str) -> list[str]:
    """What ``text`` names that is not there."""
    found = []
    for named, test in named_tests(text):
        path = ROOT / named
        if not path.is_file():
            found.append(named)
        elif test and test not in {node.name for node in ast.walk(ast.parse(path.read_text(encoding="utf-8")))
                                   if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef)}:
            found.append(f"{named}::{test}")
    return found


def test_the_reader_finds_files_and_tests():
    text = "see tests/e2e/test_faults.py::test_sigterm, `tests/helpers.py`, not my_tests/x.py, b/tests/y.py"
    assert named_tests(text) == [("tests/e2e/test_faults.py", "test_sigterm"), ("tests/helpers.py", None)]
    # The layout before tests/ mirrored the packages, a test that is not there, and both as they are now.
    assert missing("tests/test_faults.py, tests/helpers.py::no_such_test, tests/helpers.py::require, "
                   "tests/e2e/test_faults.py::test_bad_model_fails_start_up_in_one_line") == [
        "tests/test_faults.py", "tests/helpers.py::no_such_test"]


def test_every_named_test_exists():
    sources = sorted({path for pattern in READ for path in ROOT.glob(pattern) if path.is_file()}
                     - {Path(__file__).resolve()})  # its own examples above name what is not there
    assert ROOT / "SECURITY.md" in sources and ROOT / "docs" / "architecture.md" in sources
    problems = [f"{source.relative_to(ROOT)} names {named}" for source in sources
                for named in missing(source.read_text(encoding="utf-8", errors="replace"))]
    assert problems == [], "\n".join(problems)
