"""Every example in a docstring of service/, training/, export/ and bench/ runs: each module's examples
as one test (those whose module needs the train extra marked ``torch``). An example that cannot run here
says why in a comment before its ``# doctest: +SKIP``."""

from __future__ import annotations

import doctest
import importlib
import re

import pytest

from tests.train_extra import PACKAGES, ROOT, needs_at_import

SKIP = re.compile(r"#\s*doctest:.*\+SKIP")
SKIP_WITH_REASON = re.compile(r"#\s*\S.*#\s*doctest:.*\+SKIP")  # '# why  # doctest: +SKIP'


def _modules_with_examples() -> dict[str, list[str]]:
    """Module name -> its source lines, for each module of ours with a '>>> ' line."""
    found = {}
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            lines = path.read_text(encoding="utf-8").splitlines()
            if any(line.lstrip().startswith(">>> ") for line in lines):
                parts = path.relative_to(ROOT).with_suffix("").parts
                found[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = lines
    return found


MODULES = _modules_with_examples()


def test_the_examples_are_found():
    assert {"service.filtering.weighted_median", "service.geometry", "training.networks"} <= set(MODULES)


@pytest.mark.parametrize("name", [pytest.param(name, marks=pytest.mark.torch) if needs_at_import(name)
                                  else name for name in MODULES])
def test_examples_run(name: str):
    module = importlib.import_module(name)
    tests = doctest.DocTestFinder().find(module)
    prompts = [line for line in MODULES[name] if line.lstrip().startswith(">>> ")]
    # A '>>>' the finder does not reach (a comment, a Numba kernel's docstring) would never run.
    assert sum(len(test.examples) for test in tests) == len(prompts), f"{name}: examples outside docstrings"
    assert all(SKIP_WITH_REASON.search(line) for line in prompts if SKIP.search(line)), \
        f"{name}: a skipped example says why in a comment before '# doctest: +SKIP'"
    runner = doctest.DocTestRunner()
    report: list[str] = []
    for test in tests:
        runner.run(test, out=report.append)
    assert runner.failures == 0, "".join(report)
