#!/usr/bin/env bash
# Set up (if needed) and run the test suite. Extra arguments go to pytest, e.g. `bash scripts/test.sh -m slow`.
# Without arguments: the fast suite; under CI (CI=true) also the slow end-to-end tests (about 5 more minutes).
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
bash scripts/bootstrap.sh
# The reference reader and writer of the splat formats, PlayCanvas's splat-transform, as an oracle for the format
# tests (tests/io/test_formats.py); never a runtime dependency. Without npm those tests skip and say why.
if command -v npm >/dev/null 2>&1 && [ ! -x .oracle/node_modules/.bin/splat-transform ]; then
  echo "test: installing @playcanvas/splat-transform 2.7.1 into .oracle/ (the format tests' oracle)" >&2
  npm install --silent --no-audit --no-fund --prefix .oracle @playcanvas/splat-transform@2.7.1 >/dev/null 2>&1 \
    || echo "test: could not install splat-transform; the oracle tests will be skipped" >&2
fi
export PYVISTA_OFF_SCREEN=true
if [ "$#" -eq 0 ] && [ "${CI:-}" = "true" ]; then
  set -- -m "slow or not slow"
fi
exec .venv/bin/python -m pytest "$@"
