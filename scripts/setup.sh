#!/usr/bin/env bash
# Set up everything evaaa needs on a fresh Debian/Ubuntu machine, and check it works:
#   1. the system libraries for headless OpenGL (EGL through Mesa) and Debian's Chromium with its driver for the
#      browser test of scripts/play.py (installed with apt-get when run as root),
#   2. a virtual environment in .venv with the pinned packages of constraints.txt (torch 2.13.0 CPU build; the
#      extras train, dev, cluster (Ray, submitit: tests/test_cluster.py and test_launchers.py run them), `warp`
#      (the tests of the MuJoCo Warp backend: tests/test_warp.py) and sb3 (Stable-Baselines3: tests/test_score.py)),
#   3. one off-screen render.
# Safe to run again: each step is skipped when already done. Called by `make setup`, `make train`, `make demo` and
# `make test`.
set -euo pipefail

usage() {
  cat <<'TEXT'
usage: bash scripts/setup.sh [-h | --help]

Sets up evaaa on a Debian/Ubuntu machine and checks that it works:
  1. the system libraries for headless OpenGL (EGL through Mesa; MUJOCO_GL=osmesa: OSMesa) and Chromium for the
     browser test, installed with apt-get when run as root (otherwise the command to run is printed),
  2. .venv with the pinned packages of constraints.txt (PyTorch CPU build; the extras train, cluster, dev, warp
     and sb3),
  3. one off-screen render.
Each step already done is skipped, so it is safe to run again. It takes no other arguments.
TEXT
}
case "${1:-}" in
  -h|--help) usage; exit 0 ;;
  "") ;;
  *) printf 'setup.sh: error: unknown argument %s (see --help)\n' "$1" >&2; exit 2 ;;
esac
cd "$(dirname "$0")/.."

say() { printf '[setup] %s\n' "$*"; }
fail() { printf '[setup] ERROR: %s\n' "$*" >&2; exit 1; }

# ------------------------------------------------------------------------------------------ system libraries
GL_PACKAGES=(libegl1 libegl-mesa0 libgl1-mesa-dri libglib2.0-0)
if [ "${MUJOCO_GL:-egl}" = "osmesa" ]; then GL_PACKAGES=(libosmesa6 libglib2.0-0); fi
# tests/test_play_browser.py drives the human-play page in this browser (it is skipped where chromium is missing)
BROWSER_PACKAGES=(chromium chromium-driver)
not_installed() {  # prints those of the named Debian packages that are not installed
  for pkg in "$@"; do
    dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q "install ok installed" || printf '%s\n' "$pkg"
  done
}
if command -v dpkg-query >/dev/null 2>&1; then
  mapfile -t missing_gl < <(not_installed "${GL_PACKAGES[@]}")
  mapfile -t missing_browser < <(not_installed "${BROWSER_PACKAGES[@]}")
  missing=("${missing_gl[@]}" "${missing_browser[@]}")
  if [ ${#missing[@]} -gt 0 ]; then
    if [ "$(id -u)" = "0" ] && command -v apt-get >/dev/null 2>&1; then
      say "installing system packages for headless rendering and the browser test: ${missing[*]}"
      DEBIAN_FRONTEND=noninteractive apt-get update -qq
      DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
    elif [ ${#missing_gl[@]} -gt 0 ]; then
      fail "missing system packages for headless rendering: ${missing_gl[*]}
        install them with: sudo apt-get install ${missing_gl[*]}   (or set MUJOCO_GL=osmesa and install libosmesa6)"
    else
      say "missing system packages for the browser test (it will be skipped): ${missing_browser[*]}
        install them with: sudo apt-get install ${missing_browser[*]}"
    fi
  fi
else
  say "not a Debian-like system: make sure EGL (or OSMesa with MUJOCO_GL=osmesa) is available"
fi

# ------------------------------------------------------------------------------------------ python environment
PYTHON=${PYTHON:-}
if [ -z "$PYTHON" ]; then
  for candidate in python3.11 python3.12 python3.10 python3; do
    if command -v "$candidate" >/dev/null 2>&1; then PYTHON=$candidate; break; fi
  done
fi
[ -n "$PYTHON" ] || fail "no python3 found (Python 3.10-3.12 is needed)"
"$PYTHON" -c 'import sys; assert (3, 10) <= sys.version_info[:2] <= (3, 12), sys.version' 2>/dev/null \
  || fail "$PYTHON is $("$PYTHON" --version 2>&1); Python 3.10-3.12 is needed (set PYTHON=...)"

if [ ! -x .venv/bin/python ]; then
  say "creating .venv with $("$PYTHON" --version)"
  "$PYTHON" -m venv .venv
fi
stamp=.venv/.evaaa-installed
if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ] || [ constraints.txt -nt "$stamp" ]; then
  say "installing packages (pinned by constraints.txt; first time takes a few minutes)"
  .venv/bin/python -m pip install --quiet --upgrade pip
  .venv/bin/python -m pip install --quiet -c constraints.txt -e ".[train,cluster,dev,warp,sb3]"
  touch "$stamp"
fi

# ------------------------------------------------------------------------------------------ check rendering
if ! .venv/bin/python - <<'PY'
import evaaa
env = evaaa.make_env("1-1", seed=0)
frame = env.reset()["pixels"]
assert frame.shape == (1, 64, 64, 3) and frame.float().std() > 0, "the rendered frame is blank"
env.close()
PY
then
  fail "evaaa could not render off-screen; see the message above (MUJOCO_GL=${MUJOCO_GL:-egl})"
fi
say "ready: .venv has evaaa $(.venv/bin/python -c 'import evaaa; print(evaaa.__version__)') and renders headless"
