#!/usr/bin/env bash
# A fuzz campaign: scripts/fuzz.sh TARGET SECONDS [libFuzzer options]
#   TARGET: one of fuzz/targets.py's (python fuzz/targets.py lists them), or "all" (SECONDS each)
# Seeds are built at run time (fuzz/seeds.py: made here, scenes/, ../shared/data cut small);
# the corpus grows in fuzz/work/corpus/TARGET, the log is fuzz/work/logs/TARGET.log, and each
# finding is saved in fuzz/work/crashes/TARGET/ (crash-*, timeout-*, oom-*) and the campaign
# goes on from the corpus. Replay a finding: python -m fuzz.replay TARGET FILE. Copy a fixed
# finding to tests/data/fuzz/TARGET/ to keep it as a regression test.
set -uo pipefail
cd "$(dirname "$0")/.."
if [ $# -lt 2 ]; then
    sed -n '2,8p' "$0"; exit 2
fi
PY=${PYTHON:-.venv/bin/python}
target=$1 secs=$2
shift 2
work=fuzz/work
declare -A MAXLEN=([ply]=4096 [text]=4096 [npy]=1024 [vdb_header]=8192 [npz]=8192 [bricks]=8192
                   [scene]=4096 [camera]=2048 [pattern]=256 [frames]=256 [las]=8192)

campaign() {
    local t=$1 end=$((SECONDS + secs)) rc
    shift
    mkdir -p "$work/corpus/$t" "$work/crashes/$t" "$work/logs"
    "$PY" fuzz/seeds.py "$work/seeds" "$t" >/dev/null || return 2
    local log="$work/logs/$t.log"
    echo "== $(date -u +%FT%TZ) $t for $secs s" >>"$log"
    while [ $SECONDS -lt $end ]; do
        "$PY" fuzz/run.py "$t" "$work/corpus/$t" "$work/seeds/$t" \
            -max_total_time=$((end - SECONDS)) -timeout=30 -rss_limit_mb=4096 \
            -max_len="${MAXLEN[$t]:-4096}" -artifact_prefix="$work/crashes/$t/" \
            -print_final_stats=1 "$@" >>"$log" 2>&1
        rc=$?
        [ $rc -eq 0 ] && break
        echo "$t: a finding (libFuzzer exit $rc), saved in $work/crashes/$t/; going on" >&2
        sleep 1
    done
    echo "$t: $("$PY" fuzz/summary.py "$log" "$work/crashes/$t")"
}

if [ "$target" = all ]; then
    for t in $("$PY" -c 'import sys; sys.path.insert(0, "."); from fuzz import targets; print(*targets.names())'); do
        campaign "$t" "$@"
    done
else
    campaign "$target" "$@"
fi
