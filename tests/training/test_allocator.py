"""training.allocator: glibc's thresholds raised where they can be, a no-op elsewhere."""

from __future__ import annotations

import ctypes
import sys

import pytest

from training import allocator


def test_keep_freed_memory_sets_glibc_thresholds_on_linux():
    if not sys.platform.startswith("linux") or not hasattr(ctypes.CDLL(None), "mallopt"):
        pytest.skip("glibc's mallopt is not in this process")
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
