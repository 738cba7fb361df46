"""The ``torch`` marker tells the truth: every test that needs the train extra carries it, so that
``pytest -m "not torch"`` collects and passes on a serve-only install (``make test-serve``)."""

from __future__ import annotations

import importlib.metadata
import itertools
import re
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from tests.train_extra import ROOT, TESTS, TRAIN_ONLY, needs_at_import, unmarked_needs

# Loaded with -p before conftest: `import torch` fails and find_spec finds nothing, as without torch.
HIDE_TORCH = 'import sys\nsys.modules["torch"] = None\n'


def test_every_test_that_needs_the_train_extra_is_marked():
    paths = sorted(TESTS.rglob("test_*.py"))
    assert TESTS / "service" / "api" / "middleware" in {path.parent for path in paths}  # every folder, nested
    problems = [problem for path in paths for problem in unmarked_needs(path)]
    assert problems == [], "mark with pytest.mark.torch (pyproject.toml [tool.pytest.ini_options].markers)"


def test_make_test_ends_with_the_serve_only_suite():
    """CI runs `make test` (.ci/run, README); its last step is test-serve: a venv without the train and
    bench extras, every test not marked torch."""
    lines = (ROOT / "Makefile").read_text(encoding="utf-8").splitlines()

    def recipe(target: str) -> list[str]:
        start = next(number for number, line in enumerate(lines) if line.startswith(f"{target}:"))
        return list(itertools.takewhile(lambda line: line.startswith("\t"), lines[start + 1:]))

    assert recipe("test")[-1].split()[-1] == "test-serve"
    install, run = recipe("test-serve")
    extras = re.search(r"'\.\[(.*)\]'", install).group(1).split(",")
    assert "-e" in install.split() and set(extras) == {"serve", "video", "test"}
    assert run.split()[0] == "$(SERVE_VENV)/bin/pytest" and '-m "not torch and not slow"' in run
    assert (ROOT / ".ci" / "run").read_text(encoding="utf-8").rstrip().endswith("\nmake test")
    assert "\nmake test    # " in (ROOT / "README.md").read_text(encoding="utf-8")  # the README's command


def test_what_every_run_loads_needs_no_train_extra():
    for module in ("tests.conftest", "tests.helpers", "tests.stand_in", "tests.train_extra"):
        assert needs_at_import(module) is None, module


def _extra(extras: dict[str, list[str]], name: str) -> set[str]:
    """Distribution names of an extra, our own extras' expanded."""
    names = set()
    for requirement in extras[name]:
        distribution = re.match(r"[A-Za-z0-9_.-]+", requirement).group().lower()
        if distribution == "adsm-stereo":
            for inner in re.search(r"\[(.*)\]", requirement).group(1).split(","):
                names |= _extra(extras, inner.strip())
        else:
            names.add(distribution)
    return names


def test_train_only_packages_are_pyprojects():
    extras = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"][
        "optional-dependencies"]
    torch_free = _extra(extras, "serve") | _extra(extras, "video") | _extra(extras, "test")
    assert set(TRAIN_ONLY) == (_extra(extras, "train") | _extra(extras, "bench")) - torch_free
    installed = importlib.metadata.packages_distributions()
    for distribution, module in TRAIN_ONLY.items():
        if module in installed:
            assert distribution in {name.lower() for name in installed[module]}, (distribution, module)


UNMARKED_AND_MARKED = [
    ("import torch\n\ndef test_a():\n    pass\n",
     "import pytest\nimport torch\n\npytestmark = [pytest.mark.slow, pytest.mark.torch]\n"),
    ("from training.networks import build_tower_pair\n",                  # torch through our own module
     "import pytest\nfrom training.networks import build_tower_pair\n\npytestmark = pytest.mark.torch\n"),
    ("def test_a():\n    import torch.nn\n",
     "import pytest\n\n@pytest.mark.torch\ndef test_a():\n    import torch.nn\n"),
    ("class TestA:\n    def test_a(self):\n        require_module('torch')\n",
     "import pytest\n\n@pytest.mark.torch\nclass TestA:\n"
     "    def test_a(self):\n        require_module('torch')\n"),
    ("import pytest\n\n@pytest.fixture\ndef towers():\n    from training.evaluation import TorchTowers\n\n"
     "@pytest.mark.torch\ndef test_a(towers):\n    pass\n\ndef test_b(towers):\n    pass\n",
     "import pytest\n\n@pytest.fixture\ndef towers():\n    from training.evaluation import TorchTowers\n\n"
     "@pytest.mark.torch\ndef test_a(towers):\n    pass\n"),
]


@pytest.mark.parametrize(("unmarked", "marked"), UNMARKED_AND_MARKED)
def test_the_rule_finds_each_unmarked_need(tmp_path: Path, unmarked: str, marked: str):
    path = tmp_path / "test_case.py"
    path.write_text(unmarked)
    assert unmarked_needs(path)
    path.write_text(marked)
    assert unmarked_needs(path) == []


def test_without_torch_not_torch_leaves_marked_files_unimported(tmp_path: Path):
    """A file marked as a whole that imports torch: left out by -m "not torch" on an install without torch;
    any other run imports it and fails, as does a file that imports torch unmarked."""
    (tmp_path / "hide_torch.py").write_text(HIDE_TORCH)
    cases = tmp_path / "cases"
    cases.mkdir()
    (cases / "test_whole.py").write_text("import pytest\nimport torch\n\npytestmark = pytest.mark.torch\n\n"
                                         "def test_trains():\n    assert torch\n")
    (cases / "test_part.py").write_text("import pytest\n\n@pytest.mark.torch\ndef test_trains():\n"
                                        "    import torch\n\ndef test_serves():\n    pass\n")

    def pytest_run(*args: str) -> subprocess.CompletedProcess:
        return subprocess.run(
            [sys.executable, "-m", "pytest", "-p", "hide_torch", "-p", "tests.conftest",
             "-p", "no:cacheprovider", "-q", "--rootdir", str(cases), *args, str(cases)],
            capture_output=True, text=True, timeout=300, cwd=cases,
            env={"PATH": "/usr/bin:/bin", "PYTHONPATH": f"{tmp_path}:{ROOT}"})

    serve_only = pytest_run("-m", "not torch")
    assert serve_only.returncode == 0 and "1 passed, 1 deselected" in serve_only.stdout, serve_only.stdout
    everything = pytest_run()
    assert everything.returncode == 2 and "ERROR" in everything.stdout, everything.stdout
    assert "import of torch halted" in everything.stdout
    (cases / "test_whole.py").write_text("import torch\n\ndef test_trains():\n    assert torch\n")
    unmarked = pytest_run("-m", "not torch")
    assert unmarked.returncode == 2 and "ERROR" in unmarked.stdout, unmarked.stdout
