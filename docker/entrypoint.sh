#!/bin/sh
# Image entry point: copy the Numba cache compiled at build time into a writable directory (the image's
# own copy stays read-only, and the root filesystem may be read-only too), then run the command.
# A CPU different from the build machine's makes Numba recompile into the writable copy; nothing breaks.
set -eu
seed="${ADSM_NUMBA_CACHE_SEED:-/opt/adsm/numba-cache}"
cache="${ADSM_NUMBA_CACHE_DIR:-/tmp/adsm-numba}"
if [ -d "$seed" ] && [ ! -e "$cache/.seeded" ]; then
    mkdir -p "$cache"
    cp -R "$seed/." "$cache/"
    touch "$cache/.seeded"
fi
export ADSM_NUMBA_CACHE_DIR="$cache"
exec "$@"
