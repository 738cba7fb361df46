#!/bin/sh
# Image entry point: copy the Numba cache compiled at build time into a private, writable folder (the
# image's own copy stays read-only, and the root filesystem may be read-only too), then run the command.
# A CPU different from the build machine's makes Numba recompile into the writable copy; nothing breaks.
#
# The copy is made afresh at every start: numba reads the cache's index files with pickle, so a copy left
# by an earlier start (an emptyDir survives container restarts) that is corrupt, or that someone else
# wrote to, must not be trusted. The folder is created with mode 700; one that already exists and is not
# this user's own folder is left alone (service/jit.py then refuses it with a log line and falls back).
set -eu
seed="${ADSM_NUMBA_CACHE_SEED:-/opt/adsm/numba-cache}"
cache="${ADSM_NUMBA_CACHE_DIR:-${TMPDIR:-/tmp}/adsm-numba-$(id -u)}"
if [ -d "$seed" ]; then
    if [ -d "$cache" ] && [ ! -L "$cache" ] && [ -O "$cache" ]; then
        rm -rf "$cache"
    fi
    if mkdir -m 700 "$cache" 2>/dev/null; then
        cp -R "$seed/." "$cache/"
        chmod -R go-w "$cache"
    else
        echo "adsm-entrypoint: $cache exists and is not this user's folder; not seeding it" >&2
    fi
fi
export ADSM_NUMBA_CACHE_DIR="$cache"
exec "$@"
