#!/usr/bin/env bash
# Install everything roodi-toolkit needs on a fresh Debian machine; safe to run again (skips what is done).
#   - Debian libraries that Open3D and VTK load (EGL/OSMesa for off-screen rendering);
#   - a virtual environment (.venv, or $ROODI_VENV) with the pinned CPU PyTorch installed first, so no
#     dependency pulls a multi-GB CUDA build;
#   - the package in editable mode with its dev extra, and the bundled plugins.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."

VENV="${ROODI_VENV:-.venv}"
PYTHON="${PYTHON:-python3}"
TORCH_PIN="torch==2.13.0"
APT_PACKAGES=(libusb-1.0-0 libgl1 libegl1 libgomp1 libosmesa6)

missing=()
for pkg in "${APT_PACKAGES[@]}"; do
  dpkg -s "$pkg" >/dev/null 2>&1 || missing+=("$pkg")
done
if [ "${#missing[@]}" -gt 0 ]; then
  echo "bootstrap: installing Debian packages: ${missing[*]}" >&2
  SUDO=""
  if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi

if [ ! -x "$VENV/bin/python" ]; then
  echo "bootstrap: creating virtual environment $VENV" >&2
  "$PYTHON" -m venv "$VENV"
fi
PIP=("$VENV/bin/python" -m pip --disable-pip-version-check -q)

if ! "$VENV/bin/python" -c "import torch" >/dev/null 2>&1; then
  echo "bootstrap: installing $TORCH_PIN (CPU build)" >&2
  "${PIP[@]}" install "$TORCH_PIN"
fi

# Re-install when the packaging files change; otherwise the editable install is already current.
stamp="$VENV/.roodi-toolkit-installed"
sources=(setup.cfg pyproject.toml plugins/*/setup.cfg)
if [ ! -f "$stamp" ] || [ -n "$(find "${sources[@]}" -newer "$stamp" 2>/dev/null)" ]; then
  echo "bootstrap: installing roodi-toolkit (editable) and its plugins" >&2
  "${PIP[@]}" install -e ".[dev]"
  for plugin in plugins/*/; do
    if [ -f "$plugin/setup.cfg" ]; then
      "${PIP[@]}" install --no-deps -e "$plugin"
    fi
  done
  touch "$stamp"
fi
