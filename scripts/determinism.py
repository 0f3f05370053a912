"""What changes a training run's numbers: the same tiny run trained under one change at a time.

    python3 scripts/determinism.py [--out DIR] [--iterations 300]

Trains SpotlessGS on the synthetic ray-cast box room (14 views, 40x30) with seed 0 and one CPU thread ("reference"),
then once more for each variation: the same again; 2 threads; torch's CPU kernels limited to AVX2
(``ATEN_CPU_CAPABILITY=avx2``); the C++ rasterizer built without ``-march=native``; both C++ builds with
``-ffp-contract=off``; seed 1. Each run is a separate process (environment variables act at import). Prints, per
run, the test PSNR, the Gaussian count and a digest of every trained tensor; equal digests mean bit-identical models.
The results are in docs/results.md, "Determinism".
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import stat
import subprocess
import sys
import tempfile
from pathlib import Path

from evaluation.synthetic import render_room_sequence, write_dataset_folder

ROOT = Path(__file__).resolve().parents[1]

TRAIN_ONE = r"""
import hashlib, json, sys
from pathlib import Path
import torch
from spotlessgs.training.checkpoint import load_checkpoint
from spotlessgs.training.config import preset
from spotlessgs.training.trainer import train

data, out, threads, seed, iterations = Path(sys.argv[1]), Path(sys.argv[2]), *map(int, sys.argv[3:6])
result = train(data, out, "spotless", preset("tiny", iterations=iterations, image_width=40, num_threads=threads),
               seed=seed, progress=False)
digest = hashlib.sha256()
def walk(node, key):
    if isinstance(node, torch.Tensor):
        digest.update(key.encode()); digest.update(node.detach().cpu().contiguous().numpy().tobytes())
    elif isinstance(node, dict):
        for k in sorted(node, key=str): walk(node[k], f"{key}/{k}")
    elif isinstance(node, (list, tuple)):
        for i, v in enumerate(node): walk(v, f"{key}/{i}")
state = load_checkpoint(out)
for part in ("gaussians", "appearance"):
    walk(state[part], part)
print(json.dumps({"test_psnr": result.test_psnr, "gaussians": result.num_gaussians,
                  "digest": digest.hexdigest()[:16]}))
"""


def _compiler_wrapper(folder: Path, name: str, drop_native: bool, no_contract: bool) -> Path:
    """A `$CXX` that calls g++ without -march=native and/or with -ffp-contract=off."""
    path = folder / name
    extra = "-ffp-contract=off " if no_contract else ""
    filter_native = 'for a in "$@"; do [ "$a" = "-march=native" ] || args+=("$a"); done' if drop_native else \
        'args=("$@")'
    path.write_text(f'#!/bin/bash\nargs=()\n{filter_native}\nexec g++ {extra}"${{args[@]}}"\n')
    path.chmod(path.stat().st_mode | stat.S_IXUSR)
    return path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=None, help="work folder (default: a temporary one)")
    parser.add_argument("--iterations", type=int, default=300)
    args = parser.parse_args()
    work = args.out or Path(tempfile.mkdtemp(prefix="spotless-determinism-"))
    work.mkdir(parents=True, exist_ok=True)
    data = work / "box"
    if not (data / "transforms.json").is_file():
        write_dataset_folder(render_room_sequence(num_frames=14, width=40, height=30, seed=0), data, with_depth=False)
    plain = {"CXX": str(_compiler_wrapper(work, "cxx-native", False, False)),
             "TORCH_EXTENSIONS_DIR": str(work / "ext-native")}
    variants = [
        ("reference (1 thread, seed 0)", 1, 0, plain),
        ("the same again", 1, 0, plain),
        ("2 threads", 2, 0, plain),
        ("torch CPU kernels AVX2", 1, 0, {**plain, "ATEN_CPU_CAPABILITY": "avx2"}),
        ("C++ kernel without -march=native", 1, 0,
         {"CXX": str(_compiler_wrapper(work, "cxx-portable", True, False)),
          "TORCH_EXTENSIONS_DIR": str(work / "ext-portable")}),
        ("-march=native, -ffp-contract=off", 1, 0,
         {"CXX": str(_compiler_wrapper(work, "cxx-native-nc", False, True)),
          "TORCH_EXTENSIONS_DIR": str(work / "ext-native-nc")}),
        ("no -march=native, -ffp-contract=off", 1, 0,
         {"CXX": str(_compiler_wrapper(work, "cxx-portable-nc", True, True)),
          "TORCH_EXTENSIONS_DIR": str(work / "ext-portable-nc")}),
        ("seed 1", 1, 1, plain),
    ]
    print(f"{'variation':40s} {'test PSNR':>10s} {'Gaussians':>10s}  digest")
    for index, (name, threads, seed, env) in enumerate(variants):
        run = work / f"run{index}"
        shutil.rmtree(run, ignore_errors=True)
        proc = subprocess.run([sys.executable, "-c", TRAIN_ONE, str(data), str(run), str(threads), str(seed),
                               str(args.iterations)], env={**os.environ, **env, "PYTHONPATH": str(ROOT)},
                              capture_output=True, text=True, check=False)
        if proc.returncode != 0:
            raise SystemExit(f"{name}: training failed:\n{proc.stderr[-2000:]}")
        row = json.loads(proc.stdout.strip().splitlines()[-1])
        print(f"{name:40s} {row['test_psnr']:10.3f} {row['gaussians']:10d}  {row['digest']}", flush=True)


if __name__ == "__main__":
    main()
