#!/usr/bin/env bash
# The CUDA checks of docs/gpu.md in one run, on a machine with a CUDA GPU, PyTorch and nvcc (no network needed):
#   1. gsplat 1.5.3 JIT-compiled for this GPU's architecture (from a wheel in $WHEELS, or an installed gsplat);
#   2. the `gpu`-marked tests (gsplat's forward and backward against the CPU rasterizer);
#   3. `spotless benchmark models` of 3DGS, DarkGS and SpotlessGS on a 640x480 dataset: ms per training step,
#      Gaussians, relit FPS (on the device, no files), peak GPU memory of training and of the relit render.
#
#   DATA=path/to/dataset ITERATIONS=1500 OUT=results/ bash scripts/gpu_check.sh
#
# The compiled extension is saved gzipped in $OUT (gsplat_cuda.so.gz.part-*); PREBUILT=<folder holding those parts>
# loads it instead of compiling again (same GPU architecture, torch and gsplat only).
#
# Each step's log, and each model's benchmark row, is written to $OUT as soon as it is done, so a run stopped at a
# time limit keeps what it finished. The repository is used from its folder (PYTHONPATH), not installed: the GPU
# machine may have another Python than the one pyproject.toml names.
set -u
OUT=${OUT:-gpu-results}
DATA=${DATA:?DATA must name a dataset folder rendered at 640x480}
ITERATIONS=${ITERATIONS:-1500}
VARIANTS=${VARIANTS:-3dgs darkgs spotless}
WHEELS=${WHEELS:-.whl}
BENCH_DIR=$(mktemp -d /tmp/gpu-bench.XXXX)
mkdir -p "$OUT"
export PYTHONUNBUFFERED=1
{
  nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv
  python3 -c "import sys, torch, numpy; print(sys.version.split()[0], torch.__version__, torch.version.cuda, numpy.__version__)"
  nvcc --version | tail -2
  nproc
} > "$OUT/environment.log" 2>&1
cat "$OUT/environment.log"

if ls "$WHEELS"/*.whl > /dev/null 2>&1; then
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site "$WHEELS"/*.whl
  export PYTHONPATH=/tmp/site:$PWD
else
  export PYTHONPATH=$PWD
fi
# gsplat compiles its CUDA kernels at first import: only for this GPU's architecture, on every core.
TORCH_CUDA_ARCH_LIST=$(python3 -c "import torch; print('%d.%d' % torch.cuda.get_device_capability())")
export TORCH_CUDA_ARCH_LIST MAX_JOBS=$(nproc)
start=$(date +%s)
if [ -n "${PREBUILT:-}" ] && [ -d /tmp/site/gsplat ]; then  # gsplat imports gsplat.csrc before it tries to compile
  cat "$PREBUILT"/gsplat_cuda.so.gz.part-* | gunzip > /tmp/site/gsplat/gsplat_cuda.so
  cat > /tmp/site/gsplat/csrc.py <<'PY'
"""gsplat's compiled extension from an earlier run of scripts/gpu_check.sh (its module is named gsplat_cuda)."""
import importlib.util
import pathlib

import torch  # noqa: F401  (the extension links against libtorch)

_spec = importlib.util.spec_from_file_location("gsplat_cuda", pathlib.Path(__file__).with_name("gsplat_cuda.so"))
_module = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_module)
globals().update({k: v for k, v in vars(_module).items() if not k.startswith("__")})
PY
fi
if python3 -c "from gsplat.cuda._backend import _C; assert _C is not None, 'gsplat did not compile'" \
    > "$OUT/gsplat_compile.log" 2>&1; then
  echo "gsplat compiled in $(( $(date +%s) - start )) s" | tee -a "$OUT/gsplat_compile.log"
  if [ -z "${PREBUILT:-}" ]; then
    built=$(python3 -c "from torch.utils.cpp_extension import _get_build_directory as d; print(d('gsplat_cuda', False))")
    gzip -c "$built/gsplat_cuda.so" | split -b 15M - "$OUT/gsplat_cuda.so.gz.part-"
    ls -la "$OUT"/gsplat_cuda.so.gz.part-*
  fi
else
  echo "gsplat FAILED to compile after $(( $(date +%s) - start )) s: the benchmark uses the torch rasterizer" \
    | tee -a "$OUT/gsplat_compile.log"
  tail -40 "$OUT/gsplat_compile.log"
  rm -rf /tmp/site/gsplat  # `auto` then picks the torch backend on CUDA
fi

python3 -m pytest -q -o addopts="" -p no:cacheprovider -m gpu tests/test_rasterizer_gpu.py 2>&1 \
  | tee "$OUT/gpu_tests.log" | tail -25
nvidia-smi --query-gpu=name,clocks.sm,clocks.mem,temperature.gpu,utilization.gpu --format=csv >> "$OUT/environment.log"

for variant in $VARIANTS; do
  python3 -m spotlessgs.cli benchmark models --data "$DATA" --out "$BENCH_DIR" --variants "$variant" \
    --preset paper --iterations "$ITERATIONS" --threads "$(nproc)" > "/tmp/bench-$variant.log" 2>&1 \
    || tail -30 "/tmp/bench-$variant.log"
  cp "$BENCH_DIR/${variant//+/_}/benchmark_row.json" "$OUT/row-${variant//+/_}.json" 2>/dev/null \
    && cat "$OUT/row-${variant//+/_}.json" && echo
done
