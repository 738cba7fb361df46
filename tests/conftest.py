"""Fixtures and hooks only (what tests share otherwise is in helpers.py): a throw-away Numba cache for the
whole run, the Cones pair's folder, a seeded random generator. Without torch, ``-m "not torch"`` does not
import the files marked ``torch`` as a whole (tests/train_extra.py)."""

from __future__ import annotations

import importlib.util
import os
import tempfile
from pathlib import Path

import numpy as np
import pytest

# Keep test runs off the user's cache: kernels cache here, as `adsm` would with this variable set (child
# processes inherit it).
os.environ.setdefault("ADSM_NUMBA_CACHE_DIR", os.path.join(tempfile.gettempdir(), "adsm-test-numba-cache"))
from service import jit
from tests.helpers import cones_folder
from tests.train_extra import MARKER, marked_as_a_whole

jit.configure_cache()

TORCH_INSTALLED = importlib.util.find_spec("torch") is not None


def _deselects_the_marker(config: pytest.Config) -> bool:
    """True when ``-m`` leaves out every test marked ``torch``, whatever its other markers."""
    from _pytest.mark.expression import Expression  # pytest's own -m parser; no public name for it

    if not config.option.markexpr:
        return False
    try:
        expression = Expression.compile(config.option.markexpr)
    except SyntaxError:
        return False  # pytest reports the bad expression itself
    return not any(expression.evaluate(lambda name, others=others, **_: name == MARKER or others)
                   for others in (False, True))


def pytest_ignore_collect(collection_path: Path, config: pytest.Config) -> bool | None:
    """Without torch, a test file marked ``torch`` as a whole is not imported by a run that deselects the
    marker (``pytest -m "not torch"`` on a serve-only install): its imports would fail, and ``-m`` drops
    each of its tests anyway. Any other run imports it and fails loudly, as does an unmarked file."""
    if TORCH_INSTALLED or collection_path.suffix != ".py" or not collection_path.name.startswith("test_"):
        return None
    return True if _deselects_the_marker(config) and marked_as_a_whole(collection_path) else None


@pytest.fixture
def cones_dir() -> Path:
    """:func:`cones_folder` as a fixture (``pytest.mark.usefixtures("cones_dir")`` on tests that read it)."""
    return cones_folder()


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(1234)
