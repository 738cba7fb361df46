"""``python -m bench``: list the benchmarks; ``python -m bench NAME [options]``: run one."""

from __future__ import annotations

import ast
import importlib
import pkgutil
import statistics
import sys
from pathlib import Path

import bench


def _benchmarks() -> dict[str, str]:
    """Benchmark name -> first line of its docstring, read without importing (imports can be heavy)."""
    found = {}
    for module in pkgutil.iter_modules(bench.__path__):
        if module.name.startswith("_"):
            continue
        source = (Path(bench.__path__[0]) / f"{module.name}.py").read_text(encoding="utf-8")
        tree = ast.parse(source)
        # Helper modules (bench/peers.py) have no main(): they are not benchmarks.
        if not any(isinstance(node, ast.FunctionDef) and node.name == "main" for node in tree.body):
            continue
        docstring = ast.get_docstring(tree) or ""
        found[module.name] = docstring.strip().splitlines()[0] if docstring.strip() else ""
    return found


def main(argv: list[str]) -> int:
    benchmarks = _benchmarks()
    if not argv or argv[0] in ("-h", "--help", "list"):
        print("usage: python -m bench NAME [options]   (python -m bench NAME --help for its options)\n")
        for name, summary in sorted(benchmarks.items()):
            print(f"  {name:<16} {summary}")
        return 0
    name = argv[0]
    if name not in benchmarks:
        known = ", ".join(sorted(benchmarks))
        print(f"bench: error: unknown benchmark {name!r}; have {known}", file=sys.stderr)
        return 2
    from service import jit
    from service.features.manifest import ModelError

    jit.configure_cache()  # as `adsm` does when it starts
    try:
        return int(importlib.import_module(f"bench.{name}").main(argv[1:]) or 0)
    except (OSError, ValueError, RuntimeError, ModelError, statistics.StatisticsError) as error:
        # A bad argument or file (a missing model folder, synthetic:0, an unreadable pair, --repeats 0):
        # one line, as every tool of the project, not a traceback.
        print(f"bench {name}: error: {type(error).__name__}: {error}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
