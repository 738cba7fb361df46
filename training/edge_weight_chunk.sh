#!/usr/bin/env bash
# One device call of issue 11's GPU list (docs/training.md, "The next GPU session"): by default the 17-px
# field built of eight 3x3 convs (17-8conv) with 48 feature channels, from scratch with the depth-edge loss
# weight 4, one camera draw per scene, 14000 steps (PLAN=k17dc48-w4 DRAWS=1 ITERATIONS=14000
# RUNS=.gpu/c48): the forty-first session's CPU A/B found 17-8conv 0.46 point lower than adsm-fast's
# 13-1deconv3-4conv on synthetic:200 at 32 channels and equal steps, and 0.85 lower at 48 (two seeds each;
# "Eight 3x3 convs at the 17-px field"), better on both real pairs, with its int8 twin at 0.92-0.95x the
# default's KITTI-size predict, so it is the likelier new default by the rule. Its other arm is the
# twenty-fourth session's 14000-step run of 13-1deconv3-4conv at 32 channels (docs/training.md, "The weight
# from scratch at 3x the budget"); PLAN=k17c48-w4 is that tower at 48 channels. The 11-px tower's own
# wider run is PLAN=k11c48-w4 (the thirty-fifth session's A/B: -0.32 point; its other arm the
# twenty-seventh session's PLAN=k11-w4 DRAWS=1 ITERATIONS=14000 RUNS=.gpu/long, 487 s of training,
# shipped as adsm-rf11). One run alone on the machine so that it gets every core's batches; a session is
# lent 15 minutes of device time at most, start-up included. Each run stops after BUDGET seconds at the
# latest (validated and checkpointed), so a call that falls short is continued by the next one (--resume
# auto): 420 s, then BUDGET=150 with carry [".gpu/c48/k17dc48-w4"] finishes the 14000 steps.
#
#   run (device tool): bash training/edge_weight_chunk.sh    timeout_s 530; carry [RUNS/RUN] to resume
#
# Synthetic batches are the bottleneck there (~53 ms per 128 x 256 pair on one core), not the towers' width.
# Measured on the H100 (twenty-third session): two runs of 7 batch workers each made 18.5 steps/s of batch 8
# apiece, one run of 15 workers 37 steps/s, validations included; the twenty-fourth session's run of 15
# workers made 27-30 steps/s, so its 14000 steps took the 420-s budget (11346 steps) and a second call
# (BUDGET=150, carry [".gpu/long"]) of 94 s. The camera-draws A/B at equal device time is the next call:
# PLAN=k11-w4 DRAWS=4 ITERATIONS=28000 RUNS=.gpu/draws4, then BUDGET=67 with carry [".gpu/draws4"]
# (DRAWS=4 makes ~2.4x the examples per core-second but trained worse per step on the CPU: docs/training.md,
# "Camera draws per scene"; the twenty-seventh session's 11-px run made 28-34 steps/s at DRAWS=1).
# The device's Python lacks this package's entry points (the synthetic data set is one), so the script
# installs the checkout there first (editable, no dependencies, offline) when they are missing.
# What comes back under $OUT: RUN/last.pt (weights and optimizer, to resume), RUN/best.pt (by the
# trainer's 8-pair validation) where at most two runs share the call, and RUN/validation.jsonl; copy them
# to RUNS/RUN/ here, then export, tune and measure (docs/training.md).
# Environment: PLAN the runs, each TOWER[cCHANNELS]-wWEIGHT with TOWER k11 (11-5conv), k17
# (13-1deconv3-4conv), k17d (17-8conv) or k21d (21-10conv), and CHANNELS the feature channels (32 when
# left out): "k17dc48-w4" the default, "k17c48-w4" adsm-fast's tower at 48 channels, "k11c48-w4" the 11-px
# tower's, "k11-w4" the twenty-seventh session's, "k17-w4" the twenty-fourth's, "k17-w4 k17-w0" the
# twenty-third's;
# BUDGET seconds (420: a 530-s call holds start-up, the install and the last validation), DEVICE (cuda),
# WORKERS batch processes per run (the cores left after one per run, shared), ITERATIONS (14000: the
# cosine schedule's length, the same in every call of a plan), DRAWS camera draws per rendered scene
# (--camera-draws; 1: every example its own scene), RUNS folder of the runs (.gpu/c48), EXTRA
# more trainer flags
# (a CPU smoke test: DEVICE=cpu BUDGET=1 ITERATIONS=2 EXTRA="--crop 48 96 --max-disparity 24
# --val-pairs 1"), DRY_RUN=1 prints the trainer command lines instead of running them.
set -euo pipefail

PLAN=${PLAN:-k17dc48-w4}
BUDGET=${BUDGET:-420}
DEVICE=${DEVICE:-cuda}
ITERATIONS=${ITERATIONS:-14000}
DRAWS=${DRAWS:-1}
RUNS=${RUNS:-.gpu/c48}
EXTRA=${EXTRA:-}
OUT=${OUT:?OUT must name the folder whose files come back}
PYTHON=${PYTHON:-python}

read -r -a plan <<<"$PLAN"
cores=$(nproc 2>/dev/null || echo 4)
WORKERS=${WORKERS:-$(( (cores - ${#plan[@]}) / ${#plan[@]} > 0 ? (cores - ${#plan[@]}) / ${#plan[@]} : 1 ))}
# At most 8 files come back: best.pt too only where it fits.
files=(last.pt validation.jsonl)
(( ${#plan[@]} <= 2 )) && files+=(best.pt)

declare -A CONFIG=([k11]=11-5conv [k17]=13-1deconv3-4conv [k17d]=17-8conv [k21d]=21-10conv)
if [[ -z ${DRY_RUN:-} ]] && ! "$PYTHON" -c "from importlib.metadata import entry_points as e; import sys
sys.exit('synthetic' not in {p.name for p in e(group='adsm.datasets')})"; then
    "$PYTHON" -m pip install -q --no-deps --no-build-isolation --no-index -e . >&2
fi
pids=()
for run in "${plan[@]}"; do
    if [[ ! $run =~ ^(k[0-9]+d?)(c([1-9][0-9]*))?-w([0-9]+)$ || -z ${CONFIG[${BASH_REMATCH[1]}]:-} ]]; then
        echo "PLAN: '$run' is not TOWER[cCHANNELS]-wWEIGHT with TOWER one of: ${!CONFIG[*]}" >&2
        exit 2
    fi
    tower=${BASH_REMATCH[1]} channels=${BASH_REMATCH[3]:-32} weight=${BASH_REMATCH[4]}
    # shellcheck disable=SC2206  # EXTRA is a list of flags
    command=("$PYTHON" -m training.train --config "${CONFIG[$tower]}" --channels "$channels" --shared
             --edge-weight "$weight" --device "$DEVICE" --workers "$WORKERS" --batch-size 8
             --iterations "$ITERATIONS" --camera-draws "$DRAWS" --schedule cosine --lr 1e-3 --seed 0
             --val-every 1000 --val-pairs 8 --cones '' --time-budget "$BUDGET" --resume auto
             --out "$RUNS/$run" $EXTRA)
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
