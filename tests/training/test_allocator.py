"""training.allocator: glibc's thresholds raised where they can be, a no-op elsewhere."""

from __future__ import annotations

import ctypes
import sys

from tests.helpers import require
from training import allocator


def test_keep_freed_memory_sets_glibc_thresholds_on_linux():
    require(sys.platform.startswith("linux") and hasattr(ctypes.CDLL(None), "mallopt"),
            "glibc's mallopt (Linux with glibc)")
    assert allocator.keep_freed_memory() is True
    assert allocator.keep_freed_memory() is True  # idempotent: the trainer may call it per run


def test_keep_freed_memory_is_a_no_op_off_linux(monkeypatch):
    monkeypatch.setattr(allocator.sys, "platform", "darwin")
    assert allocator.keep_freed_memory() is False


def test_keep_freed_memory_is_a_no_op_without_mallopt(monkeypatch):
    class Musl:  # a C library with no mallopt
        pass

    monkeypatch.setattr(allocator.ctypes, "CDLL", lambda name: Musl())
    assert allocator.keep_freed_memory() is False
