"""Load the runtime's Numba kernels without running them, so a first call does not wait for them.

A one-off ``adsm predict`` used to spend its first match loading every kernel's machine code from the
cache (numba's start-up, then one index and object file per kernel: 0.4-1 s on 2 shared cores, half of
it before the first kernel runs). :func:`load_kernels` asks each dispatcher for the exact specialisation
the pipeline calls (``Dispatcher.compile(signature)``: loaded from the cache, compiled only when the cache
has none), which executes nothing, so it can run in a background thread while the towers' model loads and
the images decode (:meth:`service.matcher.Matcher.prepare`): no parallel region is launched, and numba's
threading layers (workqueue among them) never see two callers at once.

Where SciPy is installed (the train and dev extras, not ``serve``), numba's first kernel load imports
``scipy.linalg`` to look for a BLAS: 0.4-1 s more here, paid by any first kernel call in such a process.

The argument types below are those the public wrappers pass (C-contiguous arrays of these dtypes, Python
ints, float32 scalars); ``tests/service/test_first_call.py`` runs the matcher after :func:`load_kernels` and
fails if any runtime kernel gained a specialisation, so a kernel added to the pipeline must be listed here.
"""

from __future__ import annotations

import contextlib
import threading
from typing import Any

import numba
import numpy as np

from service.aggregation.shiftable_windows import _shift_rows
from service.cost.right_view import _right_view_rows
from service.cost.volume import _cost_rows
from service.disparity.wta import _left_right_winners, _winners
from service.filling.border import _band_rows
from service.filling.rays import _DIRECTIONS, _fill_rows
from service.filtering.weighted_median import _filter_rows
from service.optimization.sgm import _horizontal_paths, _vertical_paths
from service.refinement.subpixel import _refine_rows
from service.validation.confidence import _confidence_rows
from service.validation.inner_check import _check_rows


def _signatures(*, confidence: bool) -> list[tuple[Any, tuple[Any, ...]]]:
    """(kernel, example arguments of the types the pipeline passes), in pipeline order."""
    volume = np.zeros((1, 1, 1), np.int16)
    features = np.zeros((1, 1, 1), np.float32)
    grey = np.zeros((1, 1), np.float32)
    winners = np.zeros((1, 1), np.int32)
    codes = np.zeros((1, 1), np.uint8)
    real = np.float32(0)
    calls: list[tuple[Any, tuple[Any, ...]]] = [
        (_cost_rows, (features, features, real, 0, volume)),
        (_shift_rows, (volume, 0)),
        (_horizontal_paths, (volume, real, real, grey, real, volume)),
        (_vertical_paths, (volume, real, real, grey, real, volume)),
        (_left_right_winners, (volume, 0, winners, winners)),
        (_winners, (volume, winners)),
        (_refine_rows, (volume, winners, grey)),
        (_right_view_rows, (volume, 0, real, volume)),
        (_check_rows, (grey, winners, 0, 0, real, codes)),
        (_fill_rows, (grey, codes, _DIRECTIONS, 0, 0, 0, grey, codes)),
        (_band_rows, (grey, codes, 0, real)),
        (_filter_rows, (grey, np.zeros((1, 1, 3), np.uint8), 0, np.zeros(1, np.float32), grey, real, grey)),
    ]
    if confidence:
        calls.append((_confidence_rows, (volume, winners, np.int32(0), grey)))
    return calls


def load_kernels(*, confidence: bool = False) -> int:
    """Load (or compile) every kernel a match calls, running none; returns how many were loaded."""
    calls = _signatures(confidence=confidence)
    for kernel, arguments in calls:
        kernel.compile(tuple(numba.typeof(argument) for argument in arguments))
    return len(calls)


def load_kernels_in_background(*, confidence: bool = False) -> threading.Thread:
    """:func:`load_kernels` in a daemon thread, started. A kernel called while the thread still loads it
    waits on numba's compiler lock and then finds it loaded, so nothing is loaded twice."""
    thread = threading.Thread(target=_quietly_load, kwargs={"confidence": confidence}, name="adsm-kernels",
                              daemon=True)
    thread.start()
    return thread


def _quietly_load(*, confidence: bool) -> None:
    # An optimisation only: a call loads (or compiles, and reports a failure of) the kernel itself.
    with contextlib.suppress(Exception):
        load_kernels(confidence=confidence)
