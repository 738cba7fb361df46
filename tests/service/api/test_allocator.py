"""service.api.allocator: with the mmap threshold pinned, freed mid-size blocks go back to the system."""

from __future__ import annotations

import platform
import subprocess
import sys

from tests.helpers import ROOT, require

# A fresh process frees one 16 MiB block (glibc then raises its mmap threshold to 16 MiB unless it was
# pinned), then holds 40 MiB in 2 MiB blocks with live 200 KiB objects between them, frees the blocks
# and prints how much of the 40 MiB its RSS still holds.
_PROBE = """
import sys
from service.api.allocator import pin_mmap_threshold
if sys.argv[1] == "pinned":
    assert pin_mmap_threshold()

def rss_mib():
    line = next(l for l in open("/proc/self/status") if l.startswith("VmRSS:"))
    return int(line.split()[1]) / 1024

big = bytearray(16 << 20); del big
before = rss_mib()
blocks, pins = [], []
for _ in range(20):
    blocks.append(bytearray(2 << 20))
    pins.append(bytearray(200 << 10))  # live between the blocks: the heap cannot shrink past them
del blocks
print(rss_mib() - before)
"""


def _kept_mib(mode: str) -> float:
    result = subprocess.run([sys.executable, "-c", _PROBE, mode], capture_output=True, text=True, cwd=ROOT,
                            timeout=60, check=True)
    return float(result.stdout)


def test_freed_blocks_are_returned_once_the_threshold_is_pinned() -> None:
    require(platform.libc_ver()[0] == "glibc", "glibc (the rising mmap threshold is glibc's)")
    assert _kept_mib("default") > 30  # the probe does show the effect
    assert _kept_mib("pinned") < 10
