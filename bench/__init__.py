"""Benchmarks (not tests): speed, memory and accuracy figures. List them with ``python -m bench``.

Each benchmark is a module ``bench/<name>.py`` whose docstring's first line describes it and whose
``main(argv) -> int`` runs it; ``python -m bench <name> [options]`` calls it.
"""
