"""Reusable memory for the two volume-sized arrays of a match: the raw and the aggregated cost volume.

Why: each fresh volume is hundreds of MB of new pages, and the kernel's first touch of them is not cheap
here. At 375x1242, D=192 a fresh 358 MB ``np.empty`` + fill took 0.03 s in most runs and 0.7-1.1 s in
others (transparent huge pages being compacted on demand), which made the same predict take 0.94 s or
1.66 s. Keeping the buffers between calls, as ONNX Runtime keeps its arena, makes every call after the
first one touch memory that is already mapped.

The buffers grow to the largest volume asked for and keep that size until :meth:`release`; the
service's cost-volume cell limit bounds them (two int16 volumes, ``4 * cells`` bytes).

:meth:`reserve` lets a caller that knows the next shape early (``adsm predict`` reads it from the image
headers) pay for the pages in a background thread while the model loads and the images decode
(:meth:`service.matcher.Matcher.prepare`): the buffers are mapped with their 4 KiB pages present
(``MAP_POPULATE``, inside the ``mmap`` call, which releases the GIL). Growth inside :meth:`volumes` keeps
``np.empty``, whose pages NumPy advises as transparent huge pages: a long-running service touches them
once and then runs its kernels ~8 % faster on them (375x1242x192: cost volume + SGM + winners 0.72-0.77 vs
0.78-0.88 CPU s), while getting those huge pages cost 1.9-2.1 s of compaction against 0.4 s for 4 KiB
pages on this machine: the one-off run takes the cheap pages, the service the fast ones.
"""

from __future__ import annotations

import mmap
from collections.abc import Callable

import numpy as np

from service.cost.volume import COST_DTYPE

# Linux: map anonymous memory with its pages present. Elsewhere np.empty (pages fault in on first touch).
_POPULATE = getattr(mmap, "MAP_POPULATE", None)


def _populated(cells: int) -> np.ndarray:
    """A 1-D int16 buffer of ``cells`` whose pages are present (contents undefined)."""
    if _POPULATE is None or cells == 0:
        buffer = np.empty(cells, COST_DTYPE)
        buffer[::2048] = 0  # one write per 4 KiB page
        return buffer
    mapping = mmap.mmap(-1, cells * np.dtype(COST_DTYPE).itemsize,
                        flags=mmap.MAP_PRIVATE | mmap.MAP_ANONYMOUS | _POPULATE)
    return np.frombuffer(mapping, COST_DTYPE)  # keeps the mapping alive; unmapped with the last view


class VolumeWorkspace:
    """Two grow-only int16 buffers handed out as ``(H, W, D)`` views. Not thread-safe (like the Matcher).

    >>> workspace = VolumeWorkspace()
    >>> raw, aggregated = workspace.volumes((2, 3, 4))
    >>> raw.shape, aggregated.dtype.name, workspace.nbytes
    ((2, 3, 4), 'int16', 96)
    """

    def __init__(self) -> None:
        # Two buffers, or none while they are replaced (tuple[np.ndarray, ...] takes both states).
        self._buffers: tuple[np.ndarray, ...] = (np.empty(0, COST_DTYPE), np.empty(0, COST_DTYPE))

    @property
    def nbytes(self) -> int:
        return sum(buffer.nbytes for buffer in self._buffers)

    def reserve(self, shape: tuple[int, int, int]) -> None:
        """Grow the buffers to hold two volumes of ``shape`` with their pages present; nothing if they
        hold it already."""
        self._grow(int(np.prod(shape)), _populated)

    def volumes(self, shape: tuple[int, int, int]) -> tuple[np.ndarray, np.ndarray]:
        """C-contiguous views of ``shape`` into the two buffers (contents undefined)."""
        cells = int(np.prod(shape))
        self._grow(cells, lambda size: np.empty(size, COST_DTYPE))
        raw, aggregated = (buffer[:cells].reshape(shape) for buffer in self._buffers)
        return raw, aggregated

    def _grow(self, cells: int, allocate: Callable[[int], np.ndarray]) -> None:
        if cells > self._buffers[0].size:
            # Drop the old buffers first so the peak is never old + new.
            self._buffers = ()
            self._buffers = (allocate(cells), allocate(cells))

    def release(self) -> None:
        """Give the memory back (the next call allocates again)."""
        self._buffers = (np.empty(0, COST_DTYPE), np.empty(0, COST_DTYPE))
