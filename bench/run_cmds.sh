#!/usr/bin/env bash
# The bench/h200_*.sh scripts' last step: their commands (one an argument) on the lent
# GPU through bench/gpu.sh where DEVICE is nvidia (the default), else here in turn (the
# scripts' tiny test runs on PoCL).
set -euo pipefail
if [ "${DEVICE:-nvidia}" = nvidia ]; then
    exec bash "$(dirname "$0")/gpu.sh" "$@"
fi
export PYTHONPATH=$PWD
for cmd in "$@"; do
    echo "== $(date +%T) $cmd"
    (bash -c "$cmd")
done
