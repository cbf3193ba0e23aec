#!/usr/bin/env bash
# Run commands on the lent NVIDIA GPU machine (../shared/GPU.md): Python wheels from
# .whl/ (carried), NVIDIA's OpenCL ICD registered at run time, the GPU picked by name
# ($VOLRENDER_DEVICE=nvidia), the .npz conversions and scans from bench/data/ (carried).
# Each argument is one command, run in turn with its own time limit; bench/results is
# tarred into $OUT/results.tgz at the end, logs into $OUT/log.txt.
#   bash bench/gpu.sh "python3 -m volrender bench volume --size 1920x1080" ...
set -uo pipefail
OUT=${OUT:-/tmp/out}
mkdir -p "$OUT"
exec > >(tee "$OUT/log.txt") 2>&1
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl \
  || { echo "gpu.sh: wheel install failed"; exit 1; }
export PYTHONPATH=/tmp/site:$PWD PYTHONUNBUFFERED=1
mkdir -p /tmp/icd && echo /usr/local/nvidia/lib64/libnvidia-opencl.so.1 > /tmp/icd/nvidia.icd \
  && cp /etc/OpenCL/vendors/*.icd /tmp/icd/ 2>/dev/null
export OCL_ICD_VENDORS=/tmp/icd VOLRENDER_DEVICE=${VOLRENDER_DEVICE:-nvidia}
export VOLRENDER_SHARED_DATA=/nonexistent        # the .npz conversions in bench/data instead
# the commit measured (the copy's git metadata is not the checkout's): GPU_COMMIT=...
export VOLRENDER_COMMIT=${GPU_COMMIT:-${VOLRENDER_COMMIT:-}}
nvidia-smi --query-gpu=name,driver_version,clocks.sm,clocks.mem --format=csv,noheader || true
python3 -m volrender info
limit=${GPU_CMD_LIMIT:-540}
for cmd in "$@"; do
  echo "== $(date +%T) $cmd"
  start=$SECONDS
  timeout "$limit" bash -c "$cmd"
  echo "== rc $? in $((SECONDS - start)) s"
done
tar czf "$OUT/results.tgz" bench/results
