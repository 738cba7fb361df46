"""Which tests need the train extra, read from the source, for the ``torch`` marker's rule.

A serve-only install (``pip install -e '.[serve,test]'``, ``make test-serve``) has no torch, so the tests
that need it carry ``pytest.mark.torch`` and ``pytest -m "not torch"`` leaves them out. What needs the
train extra at import is known from the code: an ``import`` of a package only the train or bench extras
bring (:data:`TRAIN_ONLY`), directly or through the project's own modules. conftest.py keeps a file
marked as a whole out of such a run (:func:`marked_as_a_whole`); tests/test_markers.py holds every test
file, in every folder, to the rule (:func:`unmarked_needs`). What only fails when it runs (the synthetic
generator's scikit-image photographs) is the serve-only run's to find.
"""

from __future__ import annotations

import ast
import functools
from collections.abc import Iterator
from pathlib import Path

from tests.helpers import ROOT, TESTS

PACKAGES = ("service", "training", "export", "bench")
MARKER = "torch"
LOADERS = ("require_module", "importlib.import_module")  # calls that import the module they name

# Import name of each distribution that the train or bench extra brings and the serve and test extras do
# not (tests/test_markers.py checks this against pyproject.toml and the installed metadata).
TRAIN_ONLY = {"torch": "torch", "onnxscript": "onnxscript", "tqdm": "tqdm", "scikit-image": "skimage",
              "psutil": "psutil", "libsgm": "c_libsgm"}


def _is_marker(node: ast.expr) -> bool:
    """``pytest.mark.torch``, bare or called, or a list/tuple holding one (``pytestmark = [...]``)."""
    if isinstance(node, ast.Call):
        return _is_marker(node.func)
    if isinstance(node, ast.List | ast.Tuple):
        return any(_is_marker(element) for element in node.elts)
    return ast.unparse(node) == f"pytest.mark.{MARKER}"


def whole_mark(tree: ast.Module) -> bool:
    """True when the module's ``pytestmark`` carries the marker."""
    return any(isinstance(node, ast.Assign) and any(ast.unparse(t) == "pytestmark" for t in node.targets)
               and _is_marker(node.value) for node in tree.body)


def marked_as_a_whole(path: Path) -> bool:
    """True when the test file at ``path`` is marked ``torch`` as a whole (read, never imported)."""
    try:
        return whole_mark(ast.parse(path.read_text(encoding="utf-8")))
    except (OSError, SyntaxError, UnicodeDecodeError):
        return False  # let pytest import it and report what is wrong


def _imported(node: ast.AST, module: str) -> Iterator[str]:
    """Dotted names an import statement (or a ``require_module("name")`` call) loads."""
    if isinstance(node, ast.Import):
        yield from (alias.name for alias in node.names)
    elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
        yield node.module
        yield from (f"{node.module}.{alias.name}" for alias in node.names)
    elif isinstance(node, ast.ImportFrom) and node.level:  # relative: from the module's own package
        package = module.split(".") if _is_package(module) else module.split(".")[:-1]
        base = ".".join([*package[: len(package) - node.level + 1], *([node.module] if node.module else [])])
        yield base
        yield from (f"{base}.{alias.name}" for alias in node.names)
    elif (isinstance(node, ast.Call) and ast.unparse(node.func) in LOADERS and node.args
          and isinstance(node.args[0], ast.Constant) and isinstance(node.args[0].value, str)):
        yield node.args[0].value


def _module_level(tree: ast.Module) -> Iterator[ast.AST]:
    """Statements run at import: the body, into ``if``/``try``/``with`` but not ``if TYPE_CHECKING``."""
    pending = list(tree.body)
    while pending:
        node = pending.pop()
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            pending.extend(node.orelse)
        elif isinstance(node, ast.If | ast.Try | ast.With):
            pending.extend(child for child in ast.iter_child_nodes(node) if isinstance(child, ast.stmt))
        elif not isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
            yield from ast.walk(node)


@functools.cache
def _source(module: str) -> Path | None:
    """The file of a project module (a package's ``__init__.py``), the test suite's (``tests.helpers``)
    included."""
    parts = module.split(".")
    if parts[0] not in (*PACKAGES, TESTS.name):
        return None
    for path in (ROOT.joinpath(*parts).with_suffix(".py"), ROOT.joinpath(*parts, "__init__.py")):
        if path.is_file():
            return path
    return None


def _is_package(module: str) -> bool:
    path = _source(module)
    return path is not None and path.name == "__init__.py"


def _loaded(name: str) -> list[str]:
    """What importing the dotted ``name`` loads: each prefix that is a module of ours, or the third-party
    top-level package."""
    parts = name.split(".")
    ours = [".".join(parts[:depth]) for depth in range(1, len(parts) + 1) if _source(".".join(parts[:depth]))]
    return ours or ([parts[0]] if parts[0] not in PACKAGES else [])


@functools.cache
def _edges(module: str) -> frozenset[str]:
    """The modules a module of ours loads when it is imported (its module-level imports)."""
    path = _source(module)
    if path is None:
        return frozenset()
    return frozenset(loaded for node in _module_level(ast.parse(path.read_text(encoding="utf-8")))
                     for name in _imported(node, module) for loaded in _loaded(name))


def needs_at_import(name: str) -> str | None:
    """How importing the dotted ``name`` loads a train-only package ("torch through training.networks"),
    or None. ``name``: third-party, a module of ours, or one of the test suite (``tests.helpers``)."""
    start = _loaded(name)
    seen, pending = set(start), [(module, module) for module in start]
    while pending:
        module, through = pending.pop()
        if module in TRAIN_ONLY.values():
            return module if through == module else f"{module} through {through}"
        for loaded in _edges(module) - seen:
            seen.add(loaded)
            pending.append((loaded, through))
    return None


def _first_need(node: ast.AST, module: str) -> str | None:
    return next((found for name in _imported(node, module) if (found := needs_at_import(name))), None)


def _units(tree: ast.Module) -> Iterator[tuple[ast.FunctionDef | ast.AsyncFunctionDef, bool]]:
    """Each top-level function and each method of a top-level class, with whether a decorator (its own
    or its class's) marks it."""
    for top in tree.body:
        if isinstance(top, ast.FunctionDef | ast.AsyncFunctionDef):
            yield top, any(_is_marker(decorator) for decorator in top.decorator_list)
        elif isinstance(top, ast.ClassDef):
            whole = any(_is_marker(decorator) for decorator in top.decorator_list)
            for node in top.body:
                if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                    yield node, whole or any(_is_marker(decorator) for decorator in node.decorator_list)


def unmarked_needs(path: Path) -> list[str]:
    """'file:line what' for each import of the train extra that the marker does not cover. At module level
    the file must be marked as a whole; inside a test, the test (or its class); inside a fixture or a
    helper, every test that names it."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    if whole_mark(tree):
        return []
    inside = path.resolve().is_relative_to(ROOT)
    shown = path.resolve().relative_to(ROOT) if inside else path.name
    module = ".".join(shown.with_suffix("").parts) if inside else path.stem  # relative imports start here
    problems = [f"{shown}:{node.lineno} imports {found} at module level: mark the file"
                for node in _module_level(tree) if (found := _first_need(node, module))]
    units = list(_units(tree))
    tests = [(unit, marked) for unit, marked in units if unit.name.startswith("test")]
    for unit, marked in units:
        if not unit.name.startswith("test"):  # a fixture (by parameter) or a helper (by call): its users
            users = [marked_user for test, marked_user in tests
                     if unit.name in {arg.arg for arg in test.args.args}
                     or any(isinstance(node, ast.Name) and node.id == unit.name for node in ast.walk(test))]
            marked = bool(users) and all(users)
        problems += [f"{shown}:{node.lineno} {unit.name} loads {found}: mark it"
                     for node in ast.walk(unit) if not marked and (found := _first_need(node, module))]
    return problems
