#!/usr/bin/env bash
# Issue #12 measurements on a GPU (the lead runs this unattended on the H200, ~2-5 min):
#   bench/volume.py at 1920x1080: empty-space skipping on/off, the marcher's
#     multiple-scattering octaves (3, 4, 8) against single scattering, and the path
#     estimator at 16 spp, on the five real files -> bench/results/volume_gpu-clouds-1080p.*
#   bench/error.py, multiple-scattering section at 320x240: path time to 5/2/1% and the
#     octaves' error against the path-traced reference -> bench/results/error_gpu-ms.*
# Inputs: .npz conversions in bench/data/ (git-ignored; made where OpenVDB is installed):
#   for f in smoke wdas_cloud_sixteenth dragon_with_xform fluid_data_0190 fluid_data_0056; do
#     volrender convert ../shared/data/vdb/$f.vdb bench/data/$f.npz; done
#   volrender convert scenes/demo_cloud.vdb bench/data/demo_cloud.npz
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
DEVICE=${DEVICE:-nvidia}
# smaller runs for a check elsewhere: SIZE=96x54 MS_SIZE=32x24 MS_REF=16 TAG=test-
SIZE=${SIZE:-1920x1080}; MS_SIZE=${MS_SIZE:-320x240}; MS_REF=${MS_REF:-2048}; TAG=${TAG:-}
FILES=""
for f in smoke wdas_cloud_sixteenth dragon_with_xform fluid_data_0190 fluid_data_0056; do
  FILES="$FILES bench/data/$f.npz"
done
$PY bench/volume.py --device "$DEVICE" --size "$SIZE" --repeat 3 --no-dispatch \
  --octaves 3,4,8 --path-spp 16 --tag "${TAG}clouds-1080p" $FILES
$PY bench/error.py --device "$DEVICE" --no-glass --no-volume --ms-size "$MS_SIZE" \
  --ms-ref-spp "$MS_REF" --repeat 3 --tag "${TAG}ms"
