"""Keep the memory of freed tensors in the process, so the trainer's large tensors are not page-faulted in
again at every step.

glibc's malloc serves every block above its mmap threshold (at most 32 MiB when left to adapt) with a
fresh ``mmap`` and unmaps it when freed, so each of a dense step's volume-sized tensors (``[B, H, W, W]``
floats: 128 MiB for 4 crops of 128 x 256) is faulted in page by page on every step. On this project's
2-core machine that made half of a CPU step's time (``python -m bench training_step``). Raising both
thresholds makes such blocks come from the heap and stay there once freed: the process keeps its peak
memory instead of returning it, which is what a training process wants anyway. Intel's PyTorch CPU
guide reaches the same end by preloading jemalloc or tcmalloc; this needs nothing installed.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import sys

# mallopt parameters (malloc.h) and the largest value the int argument takes.
M_TRIM_THRESHOLD = -1
M_MMAP_THRESHOLD = -3
LARGEST = 2**31 - 1


def keep_freed_memory() -> bool:
    """Raise glibc's mmap and trim thresholds for this process; True where they were set.

    A no-op (False) off Linux and on a C library without ``mallopt`` (musl); call it before the first
    large allocation. Forked data-loader workers inherit the setting.

    >>> isinstance(keep_freed_memory(), bool)
    True
    """
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
    except OSError:
        return False
    mallopt = getattr(libc, "mallopt", None)
    if mallopt is None:
        return False
    mallopt.argtypes, mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
    return bool(mallopt(M_MMAP_THRESHOLD, LARGEST)) and bool(mallopt(M_TRIM_THRESHOLD, LARGEST))
