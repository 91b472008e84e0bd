#!/usr/bin/env bash
# Set up (if needed) and run the main job on generated data (no GPU, no downloads): generate a cluttered scene, train
# it, extract one partly hidden object (distil, select, prune, inpaint, fine-tune) and score it against the object's
# true views: 1.8 minutes on a fresh clone on 2 idle cores, most of it training (README.md; longer on a busy machine).
# Writes demo-out/ (or the folder given as the first argument; its files are replaced) and ends by printing where
# the object PLY and the pictures are (docs/demo.md). The earlier pruning demo:
# .venv/bin/roodi-toolkit demo prune-out --prune-only
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
bash scripts/bootstrap.sh
export PYVISTA_OFF_SCREEN=true
exec .venv/bin/roodi-toolkit demo "${1:-demo-out}" --overwrite
