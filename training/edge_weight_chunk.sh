#!/usr/bin/env bash
# One device call of issue 11's GPU list (docs/training.md, "The next GPU session"): the 11-px and 17-px
# towers from scratch with the depth-edge loss weight 4 beside a weight-0 control, the same seed and
# steps, four trainings side by side on one GPU, each stopping after BUDGET seconds (validated and
# checkpointed) so that the next call continues it (--resume auto). Prepared so that a session lent a
# GPU spends its device time training, not writing commands:
#
#   run (device tool): bash training/edge_weight_chunk.sh        carry: [".gpu"] from the second chunk on
#
# What comes back under $OUT (at most 8 files): RUN/last.pt (weights and optimizer, to resume) and
# RUN/validation.jsonl for each of the four runs; copy them to .gpu/runs/RUN/ here before the next call.
# Environment: BUDGET seconds per chunk (480: the call's 600-s limit holds start-up and the last
# validation), DEVICE (cuda), WORKERS batch processes per run (3), ITERATIONS (9000: the cosine schedule's
# length, the same in every chunk), RUNS folder of the runs (.gpu/runs), EXTRA more trainer flags (a CPU
# smoke test: DEVICE=cpu BUDGET=1 ITERATIONS=2 EXTRA="--crop 48 96 --max-disparity 24 --val-pairs 1"),
# DRY_RUN=1 prints the four trainer command lines instead of running them.
set -euo pipefail

BUDGET=${BUDGET:-480}
DEVICE=${DEVICE:-cuda}
WORKERS=${WORKERS:-3}
ITERATIONS=${ITERATIONS:-9000}
RUNS=${RUNS:-.gpu/runs}
EXTRA=${EXTRA:-}
OUT=${OUT:?OUT must name the folder whose files come back}
PYTHON=${PYTHON:-python}

declare -A CONFIG=([k11]=11-5conv [k17]=13-1deconv3-4conv)
pids=()
for tower in k11 k17; do
    for weight in 4 0; do
        run="$tower-w$weight"
        # shellcheck disable=SC2206  # EXTRA is a list of flags
        command=("$PYTHON" -m training.train --config "${CONFIG[$tower]}" --channels 32 --shared
                 --edge-weight "$weight" --device "$DEVICE" --workers "$WORKERS" --batch-size 8
                 --iterations "$ITERATIONS" --schedule cosine --lr 1e-3 --seed 0 --val-every 1000
                 --val-pairs 8 --cones '' --time-budget "$BUDGET" --resume auto --out "$RUNS/$run" $EXTRA)
        if [[ -n ${DRY_RUN:-} ]]; then
            printf '%q ' "${command[@]}"; echo
            continue
        fi
        mkdir -p "$RUNS/$run"
        PYTHONUNBUFFERED=1 "${command[@]}" >"$RUNS/$run/chunk.log" 2>&1 &
        pids+=("$!")
    done
done
[[ -n ${DRY_RUN:-} ]] && exit 0
status=0
for pid in "${pids[@]}"; do
    wait "$pid" || status=1
done
for run in k11-w4 k11-w0 k17-w4 k17-w0; do
    mkdir -p "$OUT/$run"
    cp "$RUNS/$run/last.pt" "$RUNS/$run/validation.jsonl" "$OUT/$run/" 2>/dev/null || status=1
    echo "== $run"; tail -n 3 "$RUNS/$run/chunk.log"
done
exit "$status"
