#!/usr/bin/env bash
# One device call of issue 11's GPU list (docs/training.md, "The next GPU session"): the default model's
# 17-px tower from scratch with the depth-edge loss weight 4 beside its weight-0 control, the same seed
# and steps, side by side on one GPU, sized to finish its schedule inside one call: a session is lent
# 15 minutes of device time at most, start-up included, so a plan that needs a second call waits for a
# second lent session. Each run stops after BUDGET seconds at the latest (validated and checkpointed),
# so a call that falls short is continued by the next one (--resume auto).
#
#   run (device tool): bash training/edge_weight_chunk.sh    timeout_s 600; carry [".gpu"] only to resume
#
# Synthetic batches are the bottleneck there (~53 ms per 128 x 256 pair on one core), so the runs share
# the machine's cores as batch workers: two runs of 7 workers each make ~15 steps/s of batch 8 apiece, and
# 5000 steps (40,000 crops, 1.3x what adsm-fast saw) fit 480 s with room for start-up and validations.
# What comes back under $OUT: RUN/last.pt (weights and optimizer, to resume), RUN/best.pt (by the
# trainer's 8-pair validation) where at most two runs share the call, and RUN/validation.jsonl; copy them
# to .gpu/runs/RUN/ here, then export, tune and measure (docs/training.md).
# Environment: PLAN the runs, each TOWER-wWEIGHT with TOWER k11 (11-5conv) or k17 (13-1deconv3-4conv)
# ("k17-w4 k17-w0"; "k11-w4 k11-w0 k17-w4 k17-w0" was the four-run plan of three calls), BUDGET seconds
# (480: the call's 600-s limit holds start-up and the last validation), DEVICE (cuda), WORKERS batch
# processes per run (the cores left after one per run, shared), ITERATIONS (5000: the cosine schedule's
# length, the same in every call), RUNS folder of the runs (.gpu/runs), EXTRA more trainer flags (a CPU
# smoke test: DEVICE=cpu BUDGET=1 ITERATIONS=2 EXTRA="--crop 48 96 --max-disparity 24 --val-pairs 1"),
# DRY_RUN=1 prints the trainer command lines instead of running them.
set -euo pipefail

PLAN=${PLAN:-k17-w4 k17-w0}
BUDGET=${BUDGET:-480}
DEVICE=${DEVICE:-cuda}
ITERATIONS=${ITERATIONS:-5000}
RUNS=${RUNS:-.gpu/runs}
EXTRA=${EXTRA:-}
OUT=${OUT:?OUT must name the folder whose files come back}
PYTHON=${PYTHON:-python}

read -r -a plan <<<"$PLAN"
cores=$(nproc 2>/dev/null || echo 4)
WORKERS=${WORKERS:-$(( (cores - ${#plan[@]}) / ${#plan[@]} > 0 ? (cores - ${#plan[@]}) / ${#plan[@]} : 1 ))}
# At most 8 files come back: best.pt too only where it fits.
files=(last.pt validation.jsonl)
(( ${#plan[@]} <= 2 )) && files+=(best.pt)

declare -A CONFIG=([k11]=11-5conv [k17]=13-1deconv3-4conv)
pids=()
for run in "${plan[@]}"; do
    tower=${run%-w*} weight=${run##*-w}
    if [[ -z ${CONFIG[$tower]:-} || ! $weight =~ ^[0-9]+$ || $run != "$tower-w$weight" ]]; then
        echo "PLAN: '$run' is not TOWER-wWEIGHT with TOWER k11 or k17" >&2
        exit 2
    fi
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
[[ -n ${DRY_RUN:-} ]] && exit 0
status=0
for pid in "${pids[@]}"; do
    wait "$pid" || status=1
done
for run in "${plan[@]}"; do
    mkdir -p "$OUT/$run"
    for file in "${files[@]}"; do
        cp "$RUNS/$run/$file" "$OUT/$run/" 2>/dev/null || status=1
    done
    echo "== $run"; tail -n 3 "$RUNS/$run/chunk.log"
done
exit "$status"
