"""Who may import whom, read statically from the sources (docs/architecture.md, ../shared/DESIGN.md).

`service/` imports nothing of `training/` or `export/`, no torch and no scikit-image (the `.[serve]`
runtime has neither), and no module of `service/`, `training/`, `export/` takes part in an import cycle.
Every import statement counts, also one inside a function: a lazy import is still a dependency.
"""

from __future__ import annotations

import ast
import sys
import tomllib
from collections.abc import Iterator
from pathlib import Path

from tests.helpers import ROOT

PACKAGES = ("service", "training", "export")
FORBIDDEN_IN_SERVICE = {"training", "export", "torch", "skimage"}


def module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def modules() -> dict[str, Path]:
    return {module_name(path): path
            for package in PACKAGES for path in sorted((ROOT / package).rglob("*.py"))}


def imported_names(path: Path) -> Iterator[tuple[int, str]]:
    """(line, dotted name) of everything a module imports; ``from a import b`` gives ``a.b``, which names a
    module or, when it does not, something of the module ``a`` (``import_graph`` resolves which)."""
    this = module_name(path)
    package = this if path.name == "__init__.py" else this.rpartition(".")[0]
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), filename=str(path))):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield node.lineno, alias.name
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                origin = ".".join(base + ([node.module] if node.module else []))
            else:
                origin = node.module or ""
            for alias in node.names:
                yield node.lineno, f"{origin}.{alias.name}"


def import_graph() -> dict[str, set[str]]:
    """Module -> the modules of ours it imports (a name that is not a module resolves to its package)."""
    known = modules()
    graph: dict[str, set[str]] = {}
    for name, path in known.items():
        targets = set()
        for _, imported in imported_names(path):
            while imported and imported not in known:
                imported = imported.rpartition(".")[0]
            if imported and imported != name:
                targets.add(imported)
        graph[name] = targets
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for target in sorted(graph.get(node, ())):
            if target not in index:
                visit(target)
                low[node] = min(low[node], low[target])
            elif target in on_stack:
                low[node] = min(low[node], index[target])
        if low[node] == index[node]:
            component = []
            while True:
                member = stack.pop()
                on_stack.discard(member)
                component.append(member)
                if member == node:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for node in sorted(graph):
        if node not in index:
            visit(node)
    return found


def test_service_imports_nothing_of_training_export_torch_or_scikit_image():
    offences = [f"{path.relative_to(ROOT)}:{line} imports {name}"
                for module, path in modules().items() if module.split(".")[0] == "service"
                for line, name in imported_names(path) if name.split(".")[0] in FORBIDDEN_IN_SERVICE]
    assert not offences, "\n".join(offences)


def test_the_check_sees_relative_lazy_and_from_imports(tmp_path, monkeypatch):
    # The rules above are only as good as the import reader: it must see every form of import.
    package = tmp_path / "service" / "sub"
    package.mkdir(parents=True)
    (tmp_path / "service" / "__init__.py").write_text("")
    (package / "__init__.py").write_text("from .leaf import thing\n")
    (package / "leaf.py").write_text("def f():\n    from training.data import synthetic\n"
                                     "    import skimage.io\n    from .. import sub\n")
    monkeypatch.setattr(sys.modules[__name__], "ROOT", tmp_path)
    names = {name for _, name in imported_names(package / "leaf.py")}
    assert names == {"training.data.synthetic", "skimage.io", "service.sub"}
    assert {name for _, name in imported_names(package / "__init__.py")} == {"service.sub.leaf.thing"}
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}
    assert cycles(graph) == [["a", "b", "c"]]


def test_no_import_cycle_among_service_training_and_export():
    graph = import_graph()
    assert len(graph) > 100 and graph["training.data.synthetic.generator"] >= {"service.datasets"}
    found = cycles(graph)
    assert not found, "import cycles:\n" + "\n".join(" <-> ".join(cycle) for cycle in found)


def test_pyproject_registers_the_runtimes_extension_kinds_with_the_extra_they_name():
    from service.datasets.extensions import ENTRY_POINT_GROUP, EXTRA_KINDS

    project = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]
    entries = project["entry-points"][ENTRY_POINT_GROUP]
    assert set(EXTRA_KINDS) <= set(entries)
    for kind, needs in EXTRA_KINDS.items():
        assert needs.extra in project["optional-dependencies"]
        module = entries[kind].partition(":")[0]
        path = ROOT / module.replace(".", "/")
        assert module.split(".")[0] in PACKAGES and (path.is_dir() or path.with_suffix(".py").is_file())


def command_lines(package: str) -> set[str]:
    """Modules of ``package`` that run as a program (an ``if __name__ == "__main__"`` block)."""
    return {name for name, path in modules().items() if name.split(".")[0] == package
            and '__name__ == "__main__"' in path.read_text(encoding="utf-8")}


def test_nothing_imports_a_training_command_line():
    # The trainer once validated through training/validate.py's helpers; they live in
    # training/evaluation.py now, and a command line only parses arguments and calls library code.
    programs = command_lines("training")
    assert {"training.train", "training.validate"} <= programs
    offences = [f"{module} imports {target}" for module, targets in import_graph().items()
                for target in targets & programs]
    assert not offences, "\n".join(offences)


def test_no_private_names_cross_a_package_or_pass_between_benchmarks():
    # A leading underscore says "not part of this module's contract". Inside one package siblings may share
    # such names (a registry of a package's kernels); across packages, and between benchmarks (each a
    # program of its own), what is shared is public: bench/load.py once took service_latency's
    # _free_port, _multipart, _png and _wait_ready.
    offences = []
    for package in (*PACKAGES, "bench"):
        for path in sorted((ROOT / package).rglob("*.py")):
            for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), filename=str(path))):
                if not isinstance(node, ast.ImportFrom) or node.level:
                    continue
                origin = (node.module or "").split(".")[0]
                if origin == package and package != "bench":
                    continue
                offences += [f"{path.relative_to(ROOT)}:{node.lineno} imports {alias.name} from {node.module}"
                             for alias in node.names
                             if alias.name.startswith("_") and not alias.name.startswith("__")]
    assert not offences, "\n".join(offences)


def test_the_runtime_ships_its_types_and_make_test_checks_them():
    # py.typed tells a type checker in a user's project to read service/'s annotations (PEP 561); the
    # wheel must carry it, and `make test` runs the checker configured in pyproject.toml.
    assert (ROOT / "service" / "py.typed").is_file()
    pyproject = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
    assert "py.typed" in pyproject["tool"]["setuptools"]["package-data"]["service"]
    assert pyproject["tool"]["mypy"]["files"] == ["service"]
    dev = pyproject["project"]["optional-dependencies"]["dev"]
    assert any(requirement.startswith("mypy==") for requirement in dev)  # pinned: a new release may flag more
    make_test = (ROOT / "Makefile").read_text(encoding="utf-8").split("\ntest:")[1].split("\n\n")[0]
    assert [line.split()[0] for line in make_test.splitlines()[1:]] == [
        "$(BIN)/ruff", "$(BIN)/mypy", "$(BIN)/pytest", "$(MAKE)"]  # the last: test-serve (test_markers.py)


def test_the_cli_reports_a_bad_model_folder_in_one_place():
    # predict, eval and serve each printed their own copy; `adsm`'s main() now words it for all of them
    # (tests/service/cli/test_predict_cli.py, test_eval.py and test_faults.py hold each command to it).
    cli = ROOT / "service" / "cli"
    wording = [str(path.relative_to(cli)) for path in sorted(cli.rglob("*.py"))
               if "error: bad model folder" in path.read_text(encoding="utf-8")]
    assert wording == ["__init__.py"]


def test_the_http_service_layers_point_one_way():
    # service/api/: app.py wires routes/ and middleware/; routes ask the service object (inference.py) for
    # a match and never import middleware; middleware guards every request whatever the route, so it
    # imports neither routes nor the service object. (docs/architecture.md, "Who may import whom")
    graph = import_graph()
    routes = {name for name in graph if name.startswith("service.api.routes.")}
    middleware = {name for name in graph if name.startswith("service.api.middleware.")}
    service_object = {"service.api.inference", "service.api.queue", "service.api.refusals"}
    assert {"service.api.routes.stereo", "service.api.routes.ops"} <= routes
    assert {"service.api.middleware.delivery", "service.api.middleware.metrics"} <= middleware
    offences = [f"{name} imports {target}" for name in sorted(routes) for target in graph[name] & middleware]
    offences += [f"{name} imports {target}" for name in sorted(middleware)
                 for target in graph[name] & (routes | service_object)]
    offences += [f"{name} imports {target}" for name in sorted(set(graph) - routes - {"service.api.app"})
                 for target in graph[name] & routes]
    assert not offences, "\n".join(offences)


def test_tests_share_helpers_and_conftest_holds_fixtures_only():
    # conftest.py is pytest's to load; a test importing it ran it a second time under another name. What
    # tests share is in tests/helpers.py; conftest keeps fixtures and hooks (and private helpers of those).
    tests = ROOT / "tests"
    importers = [f"{path.relative_to(tests)}:{node.lineno}" for path in sorted(tests.rglob("*.py"))
                 for node in ast.walk(ast.parse(path.read_text(encoding="utf-8")))
                 if isinstance(node, ast.Import | ast.ImportFrom)
                 and any(str(name).rpartition(".")[2] == "conftest"  # conftest, tests.conftest
                         for name in ([alias.name for alias in node.names] if isinstance(node, ast.Import)
                                      else [node.module, *(alias.name for alias in node.names)]))]
    assert importers == [], "import from helpers instead"
    # Another test module is read only for the fixtures of its own package (test_calibration_upload reads
    # test_calibration's files); what crosses folders is shared through helpers.
    crossing = [f"{path.relative_to(tests)}:{node.lineno} imports {node.module}"
                for path in sorted(tests.rglob("*.py"))
                for node in ast.walk(ast.parse(path.read_text(encoding="utf-8")))
                if isinstance(node, ast.ImportFrom) and node.module
                and node.module.rpartition(".")[2].startswith("test_")
                and node.module.rpartition(".")[0] != ".".join(path.relative_to(ROOT).parent.parts)]
    assert crossing == [], "move what tests of several folders share into tests/helpers.py"
    conftest = ast.parse((tests / "conftest.py").read_text(encoding="utf-8"))
    public = [node.name for node in conftest.body if isinstance(node, ast.FunctionDef | ast.ClassDef)
              and not node.name.startswith(("_", "pytest_"))
              and not any("fixture" in ast.unparse(decorator) for decorator in node.decorator_list)]
    assert public == [], "conftest.py: fixtures and hooks only"


# The suite's own rules (imports, markers, prerequisites, doctests): the only tests at tests/ root.
ROOT_TESTS = {"test_structure.py", "test_markers.py", "test_prerequisites.py", "test_doctests.py"}
# Folders that mirror no package: the product from outside (a real server, a browser, a fresh venv, the
# container files) and documents whose claims are held to the code.
OUTSIDE = {"e2e", "docs"}


def test_tests_mirror_the_packages():
    # tests/service/cost/ holds the tests of service/cost/, tests/training/ those of training/, and so on
    # (docs/architecture.md, "Tests"): a renamed or removed package leaves no folder of tests behind.
    # Every folder is a package (__init__.py): two folders may hold test files of the same name, and
    # tests/service/ is only ever tests.service, never found as the runtime's `service`.
    tests = ROOT / "tests"
    folders = sorted(path for path in tests.rglob("*") if path.is_dir() and "__pycache__" not in path.parts)
    assert tests / "service" / "api" / "middleware" in folders
    assert [str(folder.relative_to(ROOT)) for folder in [tests, *folders]
            if not (folder / "__init__.py").is_file()] == []
    stray = [str(folder.relative_to(tests)) for folder in folders if folder.relative_to(tests).parts[0]
             not in OUTSIDE and not (ROOT / folder.relative_to(tests)).is_dir()]
    assert stray == [], "test folders that mirror no package folder"
    at_root = {path.name for path in tests.glob("test_*.py")}
    assert at_root <= ROOT_TESTS, "a package's test goes in its package's folder"
