"""Under Numba's CUDA simulator (``NUMBA_ENABLE_CUDASIM=1``, test_simulated.py), make its shared arrays
race-free, and give SGM lines the smallest block that covers their disparities.

The simulator runs a block's threads as Python threads and hands each ``cuda.shared.array`` call the array
its source line allocated first, but it checks and records that allocation without a lock: two threads
that reach the line together can each create one, and the kernel's threads then hold different "shared"
arrays. With the fast thread switching test_simulated.py asks for, that happened in CI (the SGM kernel's
first rows differed; the same kernels are bit-equal on an H100). This wraps the same lookup in a lock;
nothing changes outside the simulator.

The simulator runs every thread of a block as a Python thread and wakes each one at every barrier, so an
SGM line's time grows with its block, and the one-warp floor of ``sgm.threads_for`` (32 threads for the
tests' 5 or 6 disparities) made the SGM kernel ~85 % of the simulated pipeline tests. Here the default block
is the power of two from 8 that covers the disparities (8 for those tests, the same as on a GPU from 128
disparities); the same kernel, barriers and min-reduction tree run, three levels deep instead of five.
test_kernels.py still runs 32- and 128-thread lines over 260 disparities.
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

    from service.cuda import sgm

    _gpu_threads_for = sgm.threads_for

    def _simulated_threads_for(disparities: int) -> int:
        return 8 if disparities <= 8 else 16 if disparities <= 16 else _gpu_threads_for(disparities)

    sgm.threads_for = _simulated_threads_for
