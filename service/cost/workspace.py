"""Reusable memory for the two volume-sized arrays of a match: the raw and the aggregated cost volume.

Why: each fresh volume is hundreds of MB of new pages, and the kernel's first touch of them is not cheap
here. At 375x1242, D=192 a fresh 358 MB ``np.empty`` + fill took 0.03 s in most runs and 0.7-1.1 s in
others (transparent huge pages being compacted on demand), which made the same predict take 0.94 s or
1.66 s. Keeping the buffers between calls, as ONNX Runtime keeps its arena, makes every call after the
first one touch memory that is already mapped.

The buffers grow to the largest volume asked for and keep that size until :meth:`release`; the
service's cost-volume cell limit bounds them (two int16 volumes, ``4 * cells`` bytes).
"""

from __future__ import annotations

import numpy as np

from service.cost.volume import COST_DTYPE


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

    def volumes(self, shape: tuple[int, int, int]) -> tuple[np.ndarray, np.ndarray]:
        """C-contiguous views of ``shape`` into the two buffers (contents undefined)."""
        cells = int(np.prod(shape))
        if cells > self._buffers[0].size:
            # Drop the old buffers first so the peak is never old + new.
            self._buffers = ()
            self._buffers = (np.empty(cells, COST_DTYPE), np.empty(cells, COST_DTYPE))
        raw, aggregated = (buffer[:cells].reshape(shape) for buffer in self._buffers)
        return raw, aggregated

    def release(self) -> None:
        """Give the memory back (the next call allocates again)."""
        self._buffers = (np.empty(0, COST_DTYPE), np.empty(0, COST_DTYPE))
