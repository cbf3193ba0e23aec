#!/usr/bin/env bash
# Set-up and entry points for volrender on Debian (run as root, or with sudo).
#   bash run.sh demo    install what is missing, then render the bundled demo to demo.png
#   bash run.sh test    install what is missing, then run the test suite
#   bash run.sh setup   install only (add --inspect for `volrender tree`: pyvista and VTK)
#   bash run.sh test-pip  the tests that depend on the environment, in a pip user's one
#                       (.venv-pip: `pip install .[test]`, numpy 2, no OpenVDB); .ci/run runs both
#   bash run.sh peers   optional: install vdb_render and Mitsuba 3.5, then compare (bench/peers.py)
# Idempotent: a second run installs nothing new.
set -euo pipefail
cd "$(dirname "$0")"

VENV=.venv
SYS_PY=/usr/bin/python3          # Debian's python3-openvdb is built for this interpreter

as_root() { if [ "$(id -u)" = 0 ]; then "$@"; elif command -v sudo >/dev/null; then sudo "$@"; else
  echo "run.sh: need root (or sudo) to install Debian packages: $*" >&2; exit 1; fi; }

apt_deps() {
  local missing=()
  [ -f /usr/lib/python3/dist-packages/pyopenvdb.cpython-311-x86_64-linux-gnu.so ] \
    || ls /usr/lib/python3/dist-packages/*openvdb*.so >/dev/null 2>&1 || missing+=(python3-openvdb)
  "$SYS_PY" -c 'import ensurepip, venv' 2>/dev/null || missing+=(python3-venv)
  # PoCL from Debian (3.1, LLVM 15): the pip wheel's LLVM 14 cannot name newer CPUs
  # ("unknown target CPU 'generic'") and then builds no kernel at all.
  [ -f /etc/OpenCL/vendors/pocl.icd ] || missing+=(pocl-opencl-icd)
  if [ ${#missing[@]} -gt 0 ]; then
    echo "run.sh: installing Debian packages: ${missing[*]}" >&2
    as_root apt-get update -q
    DEBIAN_FRONTEND=noninteractive as_root apt-get install -y -q "${missing[@]}"
  fi
}

# covers HAVE WANT: every comma-separated extra of WANT is in HAVE
covers() { local e; for e in ${2//,/ }; do [[ ",$1," == *",$e,"* ]] || return 1; done; }
merge_extras() { echo "$1,$2" | tr , '\n' | awk 'NF && !seen[$0]++' | paste -sd, -; }

# The default install renders (denoises: pyoidn; views in the browser: viser) everything but `volrender tree` (whose pyvista and VTK are
# over half the venv); `--inspect` adds it, and the tests install it to test it.
EXTRAS=vdb,bench,denoise,view
for a in "$@"; do [ "$a" = --inspect ] && EXTRAS=$EXTRAS,inspect; done

venv() {
  if [ ! -x "$VENV/bin/python" ]; then
    echo "run.sh: creating $VENV on $SYS_PY" >&2
    "$SYS_PY" -m venv "$VENV"
  fi
  # Expose only the OpenVDB binding from Debian's site-packages (not the whole directory,
  # whose numpy and other modules would shadow or mix with the venv's).
  local site; site=$("$VENV/bin/python" -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')
  for so in /usr/lib/python3/dist-packages/pyopenvdb*.so /usr/lib/python3/dist-packages/openvdb*.so; do
    [ -e "$so" ] && ln -sf "$so" "$site/"
  done
  # $1: the extras to install; a venv that already has them (same pyproject.toml) is kept.
  local extras=$1 stamp="$VENV/.installed" hash have
  hash=$(sha256sum pyproject.toml | cut -c1-16)
  have=$(cat "$stamp" 2>/dev/null || true)
  if [ "${have%% *}" != "$hash" ] || ! covers "${have#* }" "$extras"; then
    [ "${have%% *}" = "$hash" ] && extras=$(merge_extras "${have#* }" "$extras")
    echo "run.sh: installing Python packages into $VENV (extras: $extras)" >&2
    "$VENV/bin/pip" install -q --upgrade pip >/dev/null
    if ! "$VENV/bin/pip" install -q -e ".[$extras]"; then
      # Open Image Denoise has wheels for x86-64 and arm64 only: without it renders are
      # written as rendered (volrender says so), so the rest still installs
      covers "$extras" denoise || exit 1
      extras=$(echo "$extras" | tr , '\n' | grep -vx denoise | paste -sd, -)
      echo "run.sh: pyoidn (Open Image Denoise) did not install; renders will not be denoised" >&2
      "$VENV/bin/pip" install -q -e ".[$extras]"
    fi
    echo "$hash $extras" > "$stamp"
  fi
  "$VENV/bin/python" -c 'import volrender.vdb as v; v.import_openvdb()' \
    || { echo "run.sh: OpenVDB's Python binding does not import in $VENV" >&2; exit 1; }
}

# The viewer's browser test (tests/test_viewer.py): Debian's headless Chromium and its
# WebDriver, where apt can install them; without them that test skips, saying so.
browser_deps() {
  command -v chromium >/dev/null && command -v chromedriver >/dev/null && return 0
  if [ "$(id -u)" != 0 ] && ! command -v sudo >/dev/null; then
    echo "run.sh: no root to install chromium; the viewer's browser test will skip" >&2; return 0
  fi
  echo "run.sh: installing Debian packages: chromium chromium-driver (the viewer's browser test)" >&2
  { as_root apt-get update -q && DEBIAN_FRONTEND=noninteractive as_root apt-get install -y -q \
      chromium chromium-driver; } >/dev/null \
    || echo "run.sh: chromium did not install; the viewer's browser test will skip" >&2
}

# Optional peers for bench/peers.py (docs/peers.md): OpenVDB's vdb_render (Debian's
# libopenvdb-tools) and Mitsuba 3.5.x in the venv. Mitsuba's LLVM variant dlopens
# libLLVM.so or libLLVM-16.so (Dr.Jit 0.4.6 does not look for Debian's libLLVM-14/15.so),
# so install libllvm16 and name it in DRJIT_LIBLLVM_PATH; scalar_rgb needs no LLVM.
MITSUBA_SPEC="mitsuba>=3.5,<3.6"
LIBLLVM16=/usr/lib/x86_64-linux-gnu/libLLVM-16.so.1
peers() {
  local missing=()
  command -v vdb_render >/dev/null || missing+=(libopenvdb-tools)
  [ -e "$LIBLLVM16" ] || missing+=(libllvm16)
  if [ ${#missing[@]} -gt 0 ]; then
    echo "run.sh: installing Debian packages: ${missing[*]}" >&2
    as_root apt-get update -q
    DEBIAN_FRONTEND=noninteractive as_root apt-get install -y -q "${missing[@]}"
  fi
  if ! "$VENV/bin/python" -c 'import importlib.metadata as m, sys; v = m.version("mitsuba"); sys.exit(not v.startswith("3.5."))' 2>/dev/null; then
    echo "run.sh: installing $MITSUBA_SPEC into $VENV" >&2
    "$VENV/bin/pip" install -q "$MITSUBA_SPEC"
  fi
  export DRJIT_LIBLLVM_PATH="${DRJIT_LIBLLVM_PATH:-$LIBLLVM16}"
  "$VENV/bin/python" bench/peers.py "$@"
}

# A pip user's environment (issue 39): a venv of its own with `pip install .[test]`, which
# resolves numpy 2 and has no OpenVDB (no vdb extra, no Debian binding). It runs the tests
# whose outcome depends on the environment (PIP_TESTS: file readers and writers, scene and
# option parsing, the API and CLI, the optional-dependency skips, the VDB tests that need
# no binding) and a closed-form render of each kernel family; the kernels' numerics do not
# depend on numpy's version and run in the main suite. About 4 minutes with the kernels
# cached by the main run (docs/testing.md).
PIP_VENV=.venv-pip
PIP_TESTS=(tests/test_points.py tests/test_point_formats.py tests/test_scene.py
           tests/test_properties.py tests/test_env.py tests/test_image.py tests/test_vdb.py
           tests/test_layout.py tests/test_fuzz_targets.py tests/test_api.py
           tests/test_python_api.py tests/test_octaves.py tests/test_imports.py
           tests/test_manual.py tests/test_generic_params.py
           "tests/test_render_volume.py::test_slab_transmittance_is_exp_of_optical_depth"
           "tests/test_optics.py::test_opaque_centre_pixel_by_hand")
pip_env() {
  [ -x "$PIP_VENV/bin/python" ] || { echo "run.sh: creating $PIP_VENV on $SYS_PY" >&2; "$SYS_PY" -m venv "$PIP_VENV"; }
  local stamp="$PIP_VENV/.installed" hash
  hash=$(sha256sum pyproject.toml | cut -c1-16)
  if [ "$(cat "$stamp" 2>/dev/null || true)" != "$hash" ]; then
    echo "run.sh: pip install .[test] into $PIP_VENV" >&2
    "$PIP_VENV/bin/pip" install -q --upgrade pip >/dev/null
    "$PIP_VENV/bin/pip" install -q ".[test]"
    echo "$hash" > "$stamp"
  fi
  "$PIP_VENV/bin/pip" install -q --no-deps --force-reinstall . >/dev/null   # this checkout's code
  "$PIP_VENV/bin/python" -c '
import numpy, importlib.util as u, sys
vdb = [m for m in ("pyopenvdb", "openvdb") if u.find_spec(m)]
print(f"run.sh: {sys.prefix}: numpy {numpy.__version__}, OpenVDB binding: {vdb or None}", file=sys.stderr)
sys.exit(int(numpy.__version__.split(".")[0]) < 2 or bool(vdb))' \
    || { echo "run.sh: $PIP_VENV is not a pip user's environment (numpy 2, no OpenVDB)" >&2; exit 1; }
  # the installed package (not the checkout: -P keeps the working directory off the path)
  # renders: its kernels shipped as package data
  local out; out=$(mktemp -d)
  (cd / && "$OLDPWD/$PIP_VENV/bin/python" -P -c '
import sys, volrender, volrender.cli as c
assert "site-packages" in volrender.__file__, volrender.__file__
sys.exit(c.main(["render", "blob:300", "-o", sys.argv[1], "--size", "16x12", "--spp", "1"]))' \
    "$out/blob.png") || { rm -rf "$out"; exit 1; }
  rm -rf "$out"
}

cmd=${1:-demo}
case "$cmd" in
  setup) apt_deps; venv "$EXTRAS"; du -sh "$VENV" | sed 's/^/run.sh: the venv takes /' >&2 ;;
  demo)  apt_deps; venv "$EXTRAS"
         # a white cloud: albedo 0.98, lit by the sun and a blue sky (--env), multiple
         # scattering by 3 octaves (docs/error_time.md: 16% from the path-traced image;
         # `--estimator path --spp 256` renders that image, grainier, in ~1 minute)
         "$VENV/bin/volrender" render scenes/demo_cloud.vdb -o demo.png --size 640x480 --spp 4 \
           --density-scale 6 --albedo 0.98 --sun=-0.6,-1,-0.5,10 --fov 28 --env 0.32,0.42,0.58 \
           --ms-octaves 3
         echo "run.sh: wrote demo.png" >&2 ;;
  test)  apt_deps; browser_deps; venv vdb,inspect,bench,denoise,view,test; shift || true
         "$VENV/bin/python" -m pytest -q "$@" ;;
  test-pip) apt_deps; pip_env; shift || true
         "$PIP_VENV/bin/python" -m pytest -q -p no:cacheprovider "${PIP_TESTS[@]}" "$@" ;;
  peers) apt_deps; venv "$EXTRAS"; shift || true
         peers "$@" ;;
  *) echo "usage: bash run.sh [demo|test|test-pip|setup|peers]" >&2; exit 2 ;;
esac
