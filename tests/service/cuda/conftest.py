"""Under Numba's CUDA simulator (``NUMBA_ENABLE_CUDASIM=1``, test_simulated.py), make its shared arrays
race-free.

The simulator runs a block's threads as Python threads and hands each ``cuda.shared.array`` call the array
its source line allocated first, but it checks and records that allocation without a lock: two threads
that reach the line together can each create one, and the kernel's threads then hold different "shared"
arrays. With the fast thread switching test_simulated.py asks for, that happened in CI (the SGM kernel's
first rows differed; the same kernels are bit-equal on an H100). This wraps the same lookup in a lock;
nothing changes outside the simulator.
"""

from __future__ import annotations

import os
import sys
import threading
import traceback

import numpy as np

if os.environ.get("NUMBA_ENABLE_CUDASIM") == "1":
    from numba.core import types
    from numba.cuda.simulator import kernelapi
    from numba.np import numpy_support

    _allocation = threading.Lock()
    _unlocked_array = kernelapi.FakeCUDAShared.array

    def _shared_array(self, shape, dtype):  # type: ignore[no-untyped-def]
        if shape == 0:  # dynamic shared memory: one buffer, no per-line allocation to race on
            return _unlocked_array(self, shape, dtype)
        caller = traceback.extract_stack(sys._getframe(1), limit=1)[-1][0:2]  # the kernel's source line
        with _allocation:
            array = self._allocations.get(caller)
            if array is None:
                kind = numpy_support.as_dtype(dtype) if isinstance(dtype, types.Type) else dtype
                array = self._allocations[caller] = np.empty(shape, kind)
        return array

    kernelapi.FakeCUDAShared.array = _shared_array
