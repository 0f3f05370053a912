#!/usr/bin/env bash
# The project's checks, in the order CI runs them: lint (ruff), the layer contracts (import-linter: layers only
# import downward, bpy only under simulator/blender/), then the default test suite. Extra arguments go to pytest.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
"$PY" -m ruff check spotlessgs simulator evaluation scripts tests
lint-imports --no-cache
"$PY" -m pytest -q "$@"
