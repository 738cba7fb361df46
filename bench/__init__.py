"""Benchmarks (not tests): speed, memory and accuracy figures. List them with ``python -m bench``.

Each benchmark is a module ``bench/<name>.py`` whose docstring's first line describes it and whose
``main(argv) -> int`` runs it; ``python -m bench <name> [options]`` calls it.
"""

from __future__ import annotations

import argparse
import math


def positive_int(text: str) -> int:
    """argparse type of a count (repeats, pairs, threads, channels, sizes): an integer >= 1.

    >>> positive_int("3")
    3
    """
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number >= 1, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a whole number >= 1, got {value}")
    return value


def positive_float(text: str) -> float:
    """argparse type of a duration or a bound: a finite number > 0.

    >>> positive_float("2.5")
    2.5
    """
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number > 0, got {text!r}") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"expected a finite number > 0, got {value}")
    return value
