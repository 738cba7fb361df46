"""Numba set-up shared by every kernel: a writable cache directory, thread count and warm-up.

Kernel modules import :data:`njit` from here rather than from numba, so the cache directory is fixed
before the first ``@njit(cache=True)`` decorator runs: numba reads ``config.CACHE_DIR`` when a cached
function is decorated, and its default (``__pycache__`` next to the source) is read-only in an installed
package or a container image.

Cache directory, first that is writable: ``$ADSM_NUMBA_CACHE_DIR``, ``$NUMBA_CACHE_DIR``,
``$XDG_CACHE_HOME/adsm/numba`` (``~/.cache/adsm/numba``), a fresh temporary directory.
"""

from __future__ import annotations

import functools
import os
import tempfile
from pathlib import Path

import numba
import numpy as np


def _writable(folder: Path) -> bool:
    try:
        folder.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=folder):
            pass
    except OSError:
        return False
    return True


def _choose_cache_dir() -> Path:
    candidates = [os.environ.get("ADSM_NUMBA_CACHE_DIR"), os.environ.get("NUMBA_CACHE_DIR")]
    cache_home = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    candidates.append(os.path.join(cache_home, "adsm", "numba"))
    for candidate in candidates:
        if candidate and _writable(Path(candidate)):
            return Path(candidate).resolve()
    return Path(tempfile.mkdtemp(prefix="adsm-numba-"))


CACHE_DIR: Path = _choose_cache_dir()
# Both: numba re-reads the environment when its config is reloaded.
os.environ["NUMBA_CACHE_DIR"] = str(CACHE_DIR)
numba.config.CACHE_DIR = str(CACHE_DIR)

# The one decorator of the runtime's kernels. fastmath lets LLVM vectorise the min/sum reductions over
# disparities; kernels never see NaN or inf (out-of-range cells hold a finite maximum cost).
njit = functools.partial(numba.njit, cache=True, nogil=True, fastmath=True)


def set_threads(threads: int | None) -> int:
    """Use ``threads`` Numba threads in the calling thread (None: all); returns the number in use."""
    if threads is not None:
        if threads < 1:
            raise ValueError(f"threads must be >= 1, got {threads}")
        numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
    return numba.get_num_threads()


def warmup() -> None:
    """Compile, or load from the cache, every kernel of the runtime by running it on tiny inputs."""
    from service.cost.volume import cost_volume
    from service.disparity.wta import left_right_winners, winner_takes_all
    from service.filling.rays import fill_invalid
    from service.optimization.sgm import aggregate
    from service.refinement.subpixel import refine_subpixel
    from service.validation.inner_check import inner_check

    rng = np.random.default_rng(0)
    features = rng.standard_normal((2, 3, 4, 5)).astype(np.float32)
    cost = cost_volume(features[0], features[1], 3, scale=128.0)
    volume = aggregate(cost, p1=30.0, p2=160.0)
    winner_takes_all(volume)
    left, right = left_right_winners(volume)
    disparity = refine_subpixel(volume, left)
    validity = inner_check(disparity, right, volume.shape[2])
    validity[0, :2] = (0, 2)  # at least one valid and one invalid pixel, so the ray kernel runs
    fill_invalid(disparity, validity)
