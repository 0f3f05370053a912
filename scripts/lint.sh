#!/usr/bin/env bash
# The project's static checks, run by CI before the tests: ruff, then the import-linter contracts (layers only import
# downward, bpy only under simulator/blender/, click only in the command-line modules).
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
"$PY" -m ruff check spotlessgs simulator evaluation scripts tests
# import-linter's `lint-imports`, run through the same Python (a venv need not be activated)
"$PY" -c "import sys; from importlinter.cli import lint_imports_command; sys.argv = ['lint-imports', '--no-cache']; lint_imports_command()"
