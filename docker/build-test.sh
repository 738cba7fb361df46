#!/usr/bin/env bash
# Build the adsm-service image with podman and check that it serves, on a machine with no container
# registry: no registry is reachable here, so the python:3.11-slim base is a stand-in made by debootstrap
# (Debian bookworm + its python3 3.11, pip and venv), imported under the official name so that
# docker/Dockerfile builds unchanged. On a machine with Docker Hub, `docker build` uses the real base.
#
#   bash docker/build-test.sh            (root; installs podman, buildah, debootstrap if missing)
#
# Steps: stand-in base -> `podman build --isolation=chroot` (pip reaches the package index through the
# host's network and CA certificates) -> `buildah run --isolation chroot` of the image's entry point and
# command -> GET /readyz -> a real POST /disparity of the Cones pair -> checks on the answer.
# Not part of pytest (minutes); tests/e2e/test_serve_venv.py runs the same command from a fresh venv.
set -euo pipefail
cd "$(dirname "$0")/.."

IMAGE=localhost/adsm-service:latest
BASE=docker.io/library/python:3.11-slim
PORT="${ADSM_TEST_PORT:-18765}"
CONES="${CONES:-../shared/data/middlebury2003-cones}"
export STORAGE_DRIVER="${STORAGE_DRIVER:-vfs}"   # overlay is not available inside most containers
WORK="$(mktemp -d /tmp/adsm-build-test.XXXXXX)"
CONTAINER=""
SERVER_PID=""
PYTHON="${PYTHON:-$( [ -x .venv/bin/python ] && echo .venv/bin/python || echo python3 )}"  # host side: numpy, Pillow

log() { printf '\n== %s\n' "$*"; }
cleanup() {
    if [ -n "$SERVER_PID" ]; then kill "$SERVER_PID" 2>/dev/null || true; wait "$SERVER_PID" 2>/dev/null || true; fi
    if [ -n "$CONTAINER" ]; then buildah rm "$CONTAINER" >/dev/null 2>&1 || true; fi
    rm -rf "$WORK"
}
trap cleanup EXIT

if ! command -v podman >/dev/null || ! command -v buildah >/dev/null || ! command -v debootstrap >/dev/null; then
    log "installing podman, buildah, debootstrap"
    apt-get update -qq
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq podman buildah debootstrap >/dev/null
fi

if podman image exists "$BASE"; then
    log "stand-in base $BASE already present"
else
    log "building the stand-in base $BASE with debootstrap (no registry is reachable)"
    ROOTFS="$WORK/rootfs"
    debootstrap --variant=minbase --include=python3,python3-pip,python3-venv,ca-certificates \
        bookworm "$ROOTFS" http://deb.debian.org/debian >"$WORK/debootstrap.log" 2>&1 \
        || { tail -20 "$WORK/debootstrap.log"; exit 1; }
    # Like the official image: `python` and `pip` on PATH, and pip may install into the system Python.
    ln -sf python3 "$ROOTFS/usr/bin/python"
    ln -sf pip3 "$ROOTFS/usr/bin/pip"
    rm -f "$ROOTFS"/usr/lib/python3*/EXTERNALLY-MANAGED
    rm -rf "$ROOTFS"/var/lib/apt/lists/* "$ROOTFS"/var/cache/apt/*
    tar -C "$ROOTFS" -c . | podman import --change 'CMD ["python3"]' - "$BASE" >/dev/null
fi

log "podman build -> $IMAGE"
started=$(date +%s)
podman build --isolation=chroot --pull=never --format docker \
    -v /etc/ssl/certs:/etc/ssl/certs:ro \
    -f docker/Dockerfile -t "$IMAGE" . 2>&1 | tee "$WORK/build.log" | grep -E '^(STEP|COMMIT|Successfully)' || true
[ "${PIPESTATUS[0]}" -eq 0 ] || { tail -40 "$WORK/build.log"; exit 1; }
echo "built in $(( $(date +%s) - started )) s; size $(podman image inspect "$IMAGE" --format '{{.Size}}' | awk '{printf "%.0f MB", $1/1e6}')"
podman image inspect "$IMAGE" --format 'user={{.Config.User}} entrypoint={{.Config.Entrypoint}} cmd={{.Config.Cmd}}'
podman image inspect "$IMAGE" --format '{{json .Config.Healthcheck}}' | grep -q readyz \
    || { echo "FAIL: no HEALTHCHECK on /readyz in the image"; exit 1; }

log "image contents: no torch, non-root user, seeded Numba cache"
CONTAINER=$(buildah from --pull-never "$IMAGE")
if buildah run --isolation chroot "$CONTAINER" -- python -c "import torch" 2>/dev/null; then
    echo "FAIL: torch is importable in the image"; exit 1
fi
echo "ok: import torch fails"
user=$(buildah run --isolation chroot "$CONTAINER" -- id -u)
[ "$user" != 0 ] || { echo "FAIL: the image runs as root"; exit 1; }
echo "ok: runs as uid $user"
seeded=$(buildah run --isolation chroot "$CONTAINER" -- sh -c 'find "$ADSM_NUMBA_CACHE_SEED" -name "*.nbi" | wc -l')
[ "$seeded" -gt 0 ] || { echo "FAIL: no Numba cache seeded at build time"; exit 1; }
echo "ok: $seeded Numba cache index files seeded at build time"

log "buildah run: the image's entry point and command, on port $PORT"
# buildah run does not apply ENTRYPOINT/CMD, so they are read from the image and run as they are.
read -r -a COMMAND < <(podman image inspect "$IMAGE" \
    --format '{{range .Config.Entrypoint}}{{.}} {{end}}{{range .Config.Cmd}}{{.}} {{end}}')
echo "command: ${COMMAND[*]} (user $(podman image inspect "$IMAGE" --format '{{.Config.User}}'))"
buildah run --isolation chroot --env ADSM_PORT="$PORT" "$CONTAINER" -- "${COMMAND[@]}" >"$WORK/server.log" 2>&1 &
SERVER_PID=$!
started=$(date +%s)
until curl -fsS "http://127.0.0.1:$PORT/readyz" >"$WORK/readyz.json" 2>/dev/null; do
    if ! kill -0 "$SERVER_PID" 2>/dev/null || [ $(( $(date +%s) - started )) -gt 300 ]; then
        echo "FAIL: not ready"; cat "$WORK/server.log"; exit 1
    fi
    sleep 0.5
done
echo "ready after $(( $(date +%s) - started )) s: $(cat "$WORK/readyz.json")"

log "POST /disparity (Cones, max_disparity=64)"
curl -fsS -D "$WORK/headers.txt" -o "$WORK/disparity.png" -w 'HTTP %{http_code} in %{time_total} s\n' \
    -F "left=@$CONES/left.png" -F "right=@$CONES/right.png" \
    "http://127.0.0.1:$PORT/disparity?max_disparity=64"
grep -i -E '^(content-type|server-timing|x-request-id):' "$WORK/headers.txt"
"$PYTHON" - "$WORK/disparity.png" <<'EOF'
import sys
from PIL import Image
import numpy as np
disparity = np.asarray(Image.open(sys.argv[1]))
assert disparity.dtype == np.uint16 and disparity.shape == (375, 450), (disparity.dtype, disparity.shape)
valid = disparity > 0
assert valid.mean() > 0.5, valid.mean()
print(f"ok: uint16 {disparity.shape[1]} x {disparity.shape[0]}, {valid.mean():.0%} valid, "
      f"median disparity {np.median(disparity[valid]) / 256:.1f} px")
EOF
curl -fsS "http://127.0.0.1:$PORT/metrics" | grep -E '^adsm_http_requests_total\{method="POST"'

log "PASS: adsm-service built, started as a non-root user, ready, and served a real disparity map"
