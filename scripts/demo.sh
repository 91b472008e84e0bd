#!/usr/bin/env bash
# Set up (if needed) and run the main job on embedded data: plant floaters around a generated object, prune them,
# and write the clouds and a picture to demo-out/ (or the folder given as the first argument).
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
bash scripts/bootstrap.sh
export PYVISTA_OFF_SCREEN=true
exec .venv/bin/roodi-toolkit demo "${1:-demo-out}" --overwrite
