#!/usr/bin/env bash
# The project's checks, in the order CI runs them: lint (ruff), the layer contracts (import-linter: layers only
# import downward, bpy only under simulator/blender/), then the default test suite. Extra arguments go to pytest.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
"$PY" -m ruff check spotlessgs simulator evaluation scripts tests
# import-linter's `lint-imports`, run through the same Python (a venv need not be activated)
"$PY" -c "import sys; from importlinter.cli import lint_imports_command; sys.argv = ['lint-imports', '--no-cache']; lint_imports_command()"
"$PY" -m pytest -q "$@"
