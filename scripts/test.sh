#!/usr/bin/env bash
# Set up (if needed) and run the test suite. Extra arguments go to pytest, e.g. `bash scripts/test.sh -m slow`.
# Without arguments: the fast suite; under CI (CI=true) also the slow end-to-end tests (about 5 more minutes).
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
bash scripts/bootstrap.sh
export PYVISTA_OFF_SCREEN=true
if [ "$#" -eq 0 ] && [ "${CI:-}" = "true" ]; then
  set -- -m "slow or not slow"
fi
exec .venv/bin/python -m pytest "$@"
