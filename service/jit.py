"""Numba set-up shared by every kernel: the ``njit`` decorator, the compiled-kernel cache and threads.

A leaf module: it imports numba only, so every kernel module imports :data:`njit` from here without a
cycle, and importing it changes nothing in the host process (neither ``os.environ`` nor numba's config).
Warm-up is not here: :meth:`service.matcher.Matcher.warmup` runs the real pipeline on a tiny pair.

The cache directory is chosen by :func:`configure_cache`, which ``adsm`` (every subcommand) and the HTTP
service call when they start; until then a kernel caches where numba puts it by default (``__pycache__``
beside the source, else numba's user-wide folder). Candidates, the first that passes wins:
``$ADSM_NUMBA_CACHE_DIR``, ``$NUMBA_CACHE_DIR``, ``$XDG_CACHE_HOME/adsm/numba`` (``~/.cache/adsm/numba``),
then ``<tmp>/adsm-numba-<uid>`` (one fixed folder per user, reused by every start: no ``mkdtemp`` left
behind per start). A candidate must be a directory owned by this user, not group- or world-writable,
writable, and so must be every file and folder in it: numba reads its ``.nbi`` index files with
``pickle``, so a folder someone else can write is a way to run code in the service. A refused candidate
is logged with the reason; when none passes, kernels compile in memory at every start (logged too).
"""

from __future__ import annotations

import logging
import os
import stat
import tempfile
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numba
from numba.core.caching import NullCache

logger = logging.getLogger("adsm")

# The options of every runtime kernel. fastmath lets LLVM vectorise the min/sum reductions over
# disparities; kernels never see NaN or inf (out-of-range cells hold a finite maximum cost).
_OPTIONS = {"cache": True, "nogil": True, "fastmath": True}

_dispatchers: list[Any] = []  # every kernel decorated by njit, so configure_cache can re-point them
_state: dict[str, Path | None] = {}  # "dir": the configured cache (None: no cache); absent: not configured


def njit(function: Callable | None = None, **options: Any) -> Any:
    """``numba.njit`` with the runtime's options (cache, nogil, fastmath); ``@njit`` or ``@njit(...)``."""

    def decorate(py_function: Callable) -> Any:
        dispatcher = numba.njit(**{**_OPTIONS, **options})(py_function)
        _dispatchers.append(dispatcher)
        if "dir" in _state:
            _point_cache(dispatcher, _state["dir"])
        return dispatcher

    return decorate if function is None else decorate(function)


def _point_cache(dispatcher: Any, folder: Path | None) -> None:
    """Make one kernel cache in ``folder`` (None: in memory only)."""
    if folder is None:
        dispatcher._cache = NullCache()
        return
    # numba picks a function's cache locator from config.CACHE_DIR when caching is enabled; the compiler
    # reloads the config from the environment later, so the value is set around this call only.
    config: Any = numba.config  # its settings are attributes made at run time: no static types
    previous = config.CACHE_DIR
    config.CACHE_DIR = str(folder)
    try:
        dispatcher.enable_caching()
    finally:
        config.CACHE_DIR = previous


def untrusted_reason(folder: Path) -> str | None:
    """Why ``folder`` must not hold compiled kernels (None: it may). Everything in it is checked too."""
    uid = os.geteuid()

    def problem(path: Path, info: os.stat_result) -> str | None:
        if stat.S_ISLNK(info.st_mode):
            return f"{path} is a symbolic link"
        if info.st_uid != uid:
            return f"{path} is owned by uid {info.st_uid}, not by this user (uid {uid})"
        if info.st_mode & (stat.S_IWGRP | stat.S_IWOTH):
            return f"{path} is group- or world-writable (mode {stat.S_IMODE(info.st_mode):o})"
        return None

    try:
        info = folder.lstat()
        if not stat.S_ISDIR(info.st_mode):
            return f"{folder} is not a directory"
        if reason := problem(folder, info):
            return reason
        if not os.access(folder, os.W_OK | os.X_OK):
            return f"{folder} is not writable"
        for root, folders, files in os.walk(folder):
            for name in (*folders, *files):
                path = Path(root, name)
                if reason := problem(path, path.lstat()):
                    return reason
    except OSError as error:
        return f"{folder}: {error.strerror or error}"
    return None


def _candidates(env: Mapping[str, str]) -> list[tuple[str, Path]]:
    found = [(name, Path(env[name])) for name in ("ADSM_NUMBA_CACHE_DIR", "NUMBA_CACHE_DIR") if env.get(name)]
    cache_home = env.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    found.append(("the user cache", Path(cache_home, "adsm", "numba")))
    found.append(("the temporary folder", Path(tempfile.gettempdir(), f"adsm-numba-{os.geteuid()}")))
    return found


def configure_cache(environ: Mapping[str, str] | None = None) -> Path | None:
    """Choose the kernel cache folder (module docstring) and point every kernel at it; returns it, or
    None when no candidate is usable (kernels then compile in memory). Sets numba's config only for the
    kernels, never ``os.environ``."""
    env = os.environ if environ is None else environ
    chosen: Path | None = None
    for source, candidate in _candidates(env):
        try:
            # 0o700: a folder this creates is private from the start (mkdir leaves existing ones alone).
            candidate.mkdir(mode=0o700, parents=True, exist_ok=True)
        except OSError as error:
            logger.warning("numba cache folder %s (%s) cannot be created: %s; trying the next",
                           candidate, source, error.strerror or error)
            continue
        if reason := untrusted_reason(candidate):
            logger.warning("numba cache folder %s (%s) refused: %s; trying the next",
                           candidate, source, reason)
            continue
        chosen = candidate.resolve()
        break
    else:
        logger.warning("no usable numba cache folder: the kernels compile in memory at every start")
    _state["dir"] = chosen
    for dispatcher in _dispatchers:
        _point_cache(dispatcher, chosen)
    return chosen


def is_configured() -> bool:
    """Whether :func:`configure_cache` has run in this process."""
    return "dir" in _state


def cache_dir() -> Path | None:
    """The configured cache folder; None when none is configured or usable."""
    return _state.get("dir")


def clear_cache() -> int:
    """Delete the compiled kernels (``*.nbi``, ``*.nbc``) of the configured folder; returns how many."""
    folder = cache_dir()
    removed = 0
    if folder is not None:
        for path in [*folder.rglob("*.nbi"), *folder.rglob("*.nbc")]:
            path.unlink(missing_ok=True)
            removed += 1
    return removed


def raised_by_cache(error: BaseException) -> bool:
    """Whether ``error`` came from reading numba's cache files (a corrupt or truncated index)."""
    traceback = error.__traceback__
    while traceback is not None:
        if traceback.tb_frame.f_code.co_filename.endswith(os.path.join("numba", "core", "caching.py")):
            return True
        traceback = traceback.tb_next
    return False


def set_threads(threads: int | None) -> int:
    """Use ``threads`` Numba threads in the calling thread (None: all); returns the number in use."""
    if threads is not None:
        if threads < 1:
            raise ValueError(f"threads must be >= 1, got {threads}")
        config: Any = numba.config
        numba.set_num_threads(min(threads, config.NUMBA_NUM_THREADS))
    return numba.get_num_threads()
