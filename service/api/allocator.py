"""The C allocator of a serving process: freed answers and work buffers go back to the system.

glibc's malloc serves blocks of at least ``M_MMAP_THRESHOLD`` bytes with their own ``mmap`` and returns
them with ``munmap`` on free. The threshold starts at 128 KiB but, by default, rises to the size of every
mmapped block freed (up to 32 MiB): after the first 15 MB point cloud was released, later answers and
the matches' mid-size buffers came from the heap, whose freed pages the process kept. 16 clients that
never read their answers left the server +110-186 MiB larger after every answer was dropped, and
``malloc_trim`` got little of it back; with the threshold fixed, +3 MiB (the slow test in
tests/service/api/middleware/test_http_hardening.py). Setting the threshold explicitly turns the rise
off (mallopt(3)). Elsewhere than glibc these are no-ops: other allocators have their own policies.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools

# Blocks from 1 MiB up get their own mapping: the answers, images and volumes, never the small objects.
MMAP_THRESHOLD_BYTES = 1 << 20
_M_MMAP_THRESHOLD = -3  # glibc's malloc.h


@functools.cache
def _libc() -> ctypes.CDLL | None:
    name = ctypes.util.find_library("c")
    return ctypes.CDLL(name) if name else None


def pin_mmap_threshold(threshold_bytes: int = MMAP_THRESHOLD_BYTES) -> bool:
    """Fix glibc's mmap threshold at ``threshold_bytes`` (which stops it from rising); True if it was set.

    >>> pin_mmap_threshold() in (True, False)   # False where the C library is not glibc
    True
    """
    mallopt = getattr(_libc(), "mallopt", None)
    return bool(mallopt is not None and mallopt(_M_MMAP_THRESHOLD, threshold_bytes) == 1)


def malloc_trim() -> None:
    """Give freed heap memory at the top of each arena back to the system (glibc only)."""
    trim = getattr(_libc(), "malloc_trim", None)
    if trim is not None:
        trim(0)
