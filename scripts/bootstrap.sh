#!/usr/bin/env bash
# Install everything roodi-toolkit needs on a fresh Debian machine; safe to run again (skips what is done).
#   - Debian libraries that Open3D and VTK load (EGL/OSMesa for off-screen rendering);
#   - a virtual environment (.venv, or $ROODI_VENV) with the pinned PyTorch installed first, so no dependency pulls
#     another build: on a machine without an NVIDIA GPU the CPU build, from PyTorch's CPU index where it can be
#     reached ($ROODI_TORCH_INDEX), else from what the machine's pip offers (scripts/torch_source.py decides and
#     says which; afterwards this script says which build came);
#   - the package in editable mode with its dev extra, and the bundled plugins.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."

VENV="${ROODI_VENV:-.venv}"
PYTHON="${PYTHON:-python3}"
TORCH_VERSION="2.13.0"
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
  mapfile -t torch_source < <("$VENV/bin/python" scripts/torch_source.py "$TORCH_VERSION")
  echo "bootstrap: ${torch_source[0]}" >&2
  "${PIP[@]}" install "${torch_source[@]:1}"
  "$VENV/bin/python" - >&2 <<'PY'
import warnings

warnings.filterwarnings("ignore")  # torch warns that NumPy is not installed yet
import torch
if torch.version.cuda is None:
    print(f"bootstrap: installed torch {torch.__version__}, the CPU build")
else:
    print(f"bootstrap: installed torch {torch.__version__}, the CUDA {torch.version.cuda} build"
          + ("" if torch.cuda.is_available() else " (no GPU sees it here: the CPU build is smaller, pip install "
             "torch --index-url https://download.pytorch.org/whl/cpu)"))
PY
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
