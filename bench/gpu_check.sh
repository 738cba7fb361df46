#!/usr/bin/env bash
# One device call of issue 16 (docs/gpu.md): the GPU tests on the GPU, the SGM's threads-per-line sweep,
# then `python -m bench gpu` on the models.
#
#   run (device tool): bash bench/gpu_check.sh    timeout_s 270; carry [".gpu/cones"]
#
# The device's checkout has no ../shared beside it: the Cones pair (the suite's Cones size) travels in an
# ignored folder (CONES, .gpu/cones: `mkdir -p .gpu/cones && cp ../shared/data/middlebury2003-cones/*
# .gpu/cones/`) and is put where the code looks for it. Each step runs under its own time limit
# (TEST_S, SWEEP_S, BENCH_S seconds) so that one that overruns leaves the other its share; every output lands in
# $OUT as it is written. TOWERS: torch (the folder's architecture in PyTorch on the GPU, untrained: the
# device has no onnxruntime-gpu) or onnx (the folder's towers on ONNX Runtime's CPU provider).
set -uo pipefail
OUT=${OUT:?OUT must name the folder whose files come back}
PYTHON=${PYTHON:-python3}
CONES=${CONES:-.gpu/cones}
TOWERS=${TOWERS:-torch}
export PYTHONUNBUFFERED=1 ADSM_NUMBA_CACHE_DIR=${ADSM_NUMBA_CACHE_DIR:-/tmp/adsm-numba}  # one CPU-kernel cache for both
# The lent machine's numba-cuda overloads np.row_stack, which its NumPy (2.5) no longer has (pyproject's gpu
# extra caps NumPy for this); the alias comes back in a sitecustomize for this call only.
if ! "$PYTHON" -c "import numpy; numpy.row_stack" 2>/dev/null; then
    mkdir -p /tmp/adsm-numpy-shim
    printf 'import numpy\nnumpy.row_stack = numpy.vstack\n' >/tmp/adsm-numpy-shim/sitecustomize.py
    export PYTHONPATH=/tmp/adsm-numpy-shim${PYTHONPATH:+:$PYTHONPATH}
fi
shared="$(cd .. && pwd)/shared/data/middlebury2003-cones"
if [[ ! -f $shared/left.png && -d $CONES ]]; then
    mkdir -p "$shared" && cp "$CONES"/* "$shared"/
fi
{ nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv
  "$PYTHON" -c "import numba, numba.cuda as c; print('numba', numba.__version__, 'cuda', c.is_available())"
} >"$OUT/gpu.txt" 2>&1
cat "$OUT/gpu.txt"
timeout "${TEST_S:-90}" "$PYTHON" -m pytest -q -p no:cacheprovider tests/service/cuda/test_kernels.py \
    tests/service/cuda/test_pipeline.py 2>&1 | tee "$OUT/pytest.log" | tail -n 15
timeout "${SWEEP_S:-30}" "$PYTHON" -m bench gpu --sgm-threads 32 64 128 256 --sizes kitti \
    --json "$OUT/sgm-threads.json" 2>&1 | tee "$OUT/sgm-threads.log"
timeout "${BENCH_S:-125}" "$PYTHON" -m bench gpu --towers "$TOWERS" --models adsm-rf17 adsm-fast adsm-paper \
    --sizes kitti cones --json "$OUT/gpu-$TOWERS.json" 2>&1 | tee "$OUT/bench-$TOWERS.log"
