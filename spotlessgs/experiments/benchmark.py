"""What each model component costs and buys: per variant, training ms/step, relit-render FPS, peak memory, and
test-view PSNR after a fixed iteration budget.

    spotless benchmark models --data data/bedroom --out bench/train --iterations 1500

Each variant trains in its own subprocess (so its peak resident memory, ``ru_maxrss``, is its own), then relights its
test views and scores them: PSNR of the relit test views against the ground truth after one exposure gain
(``psnr_aligned``, the meaningful figure, see the evaluation package) and the spotlight-lit reconstruction PSNR of the
held-out views. Timings are wall clock on the machine that runs it: compare rows of one run.
"""

from __future__ import annotations

import json
import resource
import subprocess
import sys
from pathlib import Path
from typing import Any

from spotlessgs.io.atomic import write_json, write_text
from spotlessgs.io.provenance import provenance

VARIANTS = ("3dgs", "darkgs", "darkgs-calibrated", "darkgs+sh", "darkgs+brdf", "spotless")


def child(data: str, run: str, variant: str, preset: str, iterations: int, threads: int, seed: int,
          settings: tuple[tuple[str, Any], ...] = ()) -> None:
    """Train (with the trainer ``settings``: (TrainConfig field, value) pairs), relight the test views and score
    them, in this (sub)process; prints one JSON line."""
    from spotlessgs.run import RunSpec, given_overrides, train  # torch: not needed by ``spotless --help``

    spec = RunSpec(data=Path(data), model=variant, preset=preset, seed=seed,
                   overrides=given_overrides(iterations=iterations, num_threads=threads) + tuple(settings))
    trained = train(spec, run, progress=False)
    summary = trained.summary
    row = {"variant": variant, "iterations": iterations, "ms_per_step": summary["ms_per_step"],
           "train_seconds": summary["seconds_this_session"], "gaussians": summary["num_gaussians"],
           "test_psnr_reconstruction": summary["test_psnr_reconstruction"]}
    if (Path(data) / "gt").is_dir():
        scores = trained.score_views(Path(run) / "relit_test", "test", threads)
        row.update({"psnr": scores["psnr"], "psnr_aligned": scores["psnr_aligned"],
                    "ssim_aligned": scores["ssim_aligned"]})
        from evaluation.runner import score_test_views
        from spotlessgs.io.dataset import available_ground_truths, read_dataset

        if "uniform" in available_ground_truths(read_dataset(data)):  # the same views against the uniform one
            uniform = score_test_views(data, Path(run) / "relit_test", threads, ground_truth="uniform")
            row.update({"psnr_aligned_uniform": uniform["psnr_aligned"],
                        "ssim_aligned_uniform": uniform["ssim_aligned"]})
        relit = scores["relight"]
    else:
        relit = trained.relight("test", Path(run) / "relit_test", progress=False)
    row["relit_fps"] = relit["fps"]
    row["peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    print(json.dumps(row))


def run_benchmark(data: Path, out: Path, variants: tuple[str, ...], preset: str, iterations: int, threads: int,
                  seed: int = 0, settings: tuple[tuple[str, Any], ...] = ()) -> list[dict]:
    """Benchmark each variant in a subprocess (``settings``: (TrainConfig field, value) pairs for every variant);
    writes ``train_benchmark.json`` and ``.md`` to ``out``."""
    rows = []
    for variant in variants:
        run = out / variant.replace("+", "_")
        if (run / "benchmark_row.json").is_file():
            rows.append(json.loads((run / "benchmark_row.json").read_text()))
            continue
        cmd = [sys.executable, "-m", "spotlessgs.cli", "benchmark", "models", "--child", "--data", str(data), "--out",
               str(run), "--variants", variant, "--preset", preset, "--iterations", str(iterations), "--threads",
               str(threads), "--seed", str(seed)] + [arg for key, value in settings
                                                     for arg in ("--set", f"{key}={value}")]
        proc = subprocess.run(cmd, capture_output=True, text=True)
        if proc.returncode != 0:
            raise RuntimeError(f"benchmark of {variant} failed:\n{proc.stderr[-3000:]}")
        row = json.loads(proc.stdout.strip().splitlines()[-1])
        write_json(run / "benchmark_row.json", row)
        rows.append(row)
    write_json(out / "train_benchmark.json", {"data": str(data), "preset": preset, "iterations": iterations,
                                              "threads": threads, "settings": dict(settings),
                                              "rows": rows, "provenance": provenance(seed=seed)})
    write_text(out / "train_benchmark.md", markdown_table(rows, iterations, threads, settings))
    return rows


def markdown_table(rows: list[dict], iterations: int, threads: int,
                   settings: tuple[tuple[str, Any], ...] = ()) -> str:
    """The benchmark as a Markdown table (``settings``: the trainer settings every variant had, named above it)."""
    def fmt(value, spec):
        return "–" if value is None else format(value, spec)

    given = "; settings: " + ", ".join(f"{k}={v}" for k, v in settings) if settings else ""
    lines = [f"{iterations} iterations per variant, {threads} thread(s){given}", "",
             "| model | ms / step | train s | Gaussians | relit FPS | peak RSS (MB) | test PSNR recon. | "
             "relit PSNR | relit PSNR aligned | relit SSIM aligned | PSNR aligned, uniform GT | "
             "SSIM aligned, uniform GT |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(
            f"| {r['variant']} | {r['ms_per_step']:.1f} | {r['train_seconds']:.1f} | {r['gaussians']} | "
            f"{r['relit_fps']:.1f} | {r['peak_rss_mb']:.0f} | {fmt(r.get('test_psnr_reconstruction'), '.2f')} | "
            f"{fmt(r.get('psnr'), '.2f')} | {fmt(r.get('psnr_aligned'), '.2f')} | {fmt(r.get('ssim_aligned'), '.3f')} | "
            f"{fmt(r.get('psnr_aligned_uniform'), '.2f')} | {fmt(r.get('ssim_aligned_uniform'), '.3f')} |")
    return "\n".join(lines) + "\n"
