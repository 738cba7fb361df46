"""The GPU tests of this folder on Numba's CUDA simulator, in every test run, GPU or not (issue 16).

CI machines have no GPU, so test_kernels.py, test_pipeline.py and test_bench_gpu.py skip there
(tests.helpers.require_gpu); here they run in a child process with ``NUMBA_ENABLE_CUDASIM=1``, which
executes each GPU thread as a Python thread with the same shared memory, barriers and launch geometry
(but for SGM lines' default block: conftest.py). That checks every kernel's arithmetic and
synchronisation against its CPU twin, not its speed or the real compiler's code: those need the GPU run
(docs/gpu.md). The simulator's barriers poll, so the child switches threads every 0.1 ms instead of 5
(9x faster here).
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from tests.helpers import ROOT

HERE = Path(__file__).resolve().parent


@pytest.mark.slow
def test_the_gpu_tests_pass_on_the_cuda_simulator() -> None:
    script = ("import sys; sys.setswitchinterval(1e-4); import pytest; "
              "sys.exit(pytest.main(['-q', '-p', 'no:cacheprovider',"
              f"{str(HERE / 'test_kernels.py')!r}, {str(HERE / 'test_pipeline.py')!r}, "
              f"{str(HERE / 'test_bench_gpu.py')!r}]))")
    run = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=900,
                         cwd=ROOT, env={**os.environ, "NUMBA_ENABLE_CUDASIM": "1"})
    assert run.returncode == 0, run.stdout[-4000:] + run.stderr[-2000:]
    # Every test ran: a skip (require_gpu finding no simulator) would pass the run without checking anything.
    assert "skipped" not in run.stdout and " passed" in run.stdout, run.stdout[-2000:]
