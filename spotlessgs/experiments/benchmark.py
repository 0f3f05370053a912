"""What each model component costs and buys: per variant, training ms/step, relit-render FPS, peak memory, and
test-view PSNR after a fixed iteration budget.

    spotless benchmark models --data data/bedroom --out bench/train --iterations 1500

Each variant trains in its own subprocess (so its peak resident memory, ``ru_maxrss``, is its own), then relights its
test views and scores them: PSNR of the relit test views against the ground truth after one exposure gain
(``psnr_aligned``, the meaningful figure, see the evaluation package) and the spotlight-lit reconstruction PSNR of the
held-out views. Timings are wall clock on the machine that runs it: compare rows of one run.

Two relit frame rates are reported: ``relit_fps`` is ``spotless relight``'s (each view rendered, copied to the host,
resampled into its input camera and written as a PNG), ``render_fps`` is the relit image alone, kept on the model's
device (:func:`time_relit_render`): the figure a real-time relighting, and the paper's FPS, measure. On a CUDA device
the peak device memory is reported too: of training and the scored relighting after it (``peak_gpu_train_mb``), and
of the timed relit render (``peak_gpu_render_mb``).
"""

from __future__ import annotations

import json
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from spotlessgs.io.atomic import write_json, write_text
from spotlessgs.io.json_files import read_json
from spotlessgs.io.provenance import provenance

if TYPE_CHECKING:
    import torch

VARIANTS = ("3dgs", "darkgs", "darkgs-calibrated", "darkgs+sh", "darkgs+brdf", "spotless")


def child(data: str, run: str, variant: str, preset: str, iterations: int, threads: int, seed: int,
          settings: tuple[tuple[str, Any], ...] = ()) -> None:
    """Train (with the trainer ``settings``: (TrainConfig field, value) pairs), relight the test views and score
    them, in this (sub)process; prints one JSON line."""
    import torch  # not needed by ``spotless --help``

    from spotlessgs.run import train

    spec = _run_spec(data, variant, preset, iterations, threads, seed, settings)
    trained = train(spec, run, progress=False, resume=(Path(run) / "run.json").is_file())  # an interrupted one goes on
    summary = trained.summary
    # a resumed run's training time is its last session's alone: not the variant's cost, so not reported as one
    resumed = summary.get("session_started_at_step", 0) > 0
    row = {"variant": variant, "iterations": iterations, "ms_per_step": summary["ms_per_step"],
           "train_seconds": None if resumed else summary["seconds_this_session"], "resumed": resumed,
           "gaussians": summary["num_gaussians"], "test_psnr_reconstruction": summary["test_psnr_reconstruction"]}
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
    if torch.cuda.is_available():
        row["peak_gpu_train_mb"] = torch.cuda.max_memory_allocated() / 2**20
        torch.cuda.reset_peak_memory_stats()
    row.update(time_relit_render(Path(run), Path(data), "all"))
    if torch.cuda.is_available():
        row["peak_gpu_render_mb"] = torch.cuda.max_memory_allocated() / 2**20
    row["peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    print(json.dumps(row))


def relit_frame_renderer(scene, cameras, config, first_view: int):
    """A function view index -> relit image (H, W, 3) on the model's device, lit with L0 = 1 and the learned
    low-frequency light (3DGS: its ordinary render): the image ``spotless relight --l0 1,1,1`` writes, before it is
    resampled into the input camera and encoded. The relit colours are made once, from view ``first_view``'s camera
    (as ``spotless relight`` makes them). ``cameras``: the views' batch on the model's device."""
    from spotlessgs.rendering import RelitColours  # torch: not needed by ``spotless --help``

    relit = RelitColours(scene, cameras.c2w[first_view]) if scene.config.light_model != "none" else None

    def frame(k: int) -> torch.Tensor:
        view = cameras[k]
        if relit is None:
            return scene.render(view, relight_l0=[1.0, 1.0, 1.0], backend=config.raster_backend,
                                num_threads=config.num_threads).image
        both = relit.render(view, config)
        return both[..., :3] + both[..., 3:]

    return frame


def time_relit_render(run: Path, data: Path, views: str = "test", repeats: int = 2) -> dict[str, Any]:
    """Frames per second of the relit ``views`` (:func:`relit_frame_renderer`) rendered on the model's device and kept
    there: ``repeats`` passes over the views after one warm-up pass, the device synchronized before the clock is read.
    Nothing is copied to the host, resampled or written.

    Returns:
        {"render_fps": frames per second (median pass), "render_device": the device's name, "render_views": count}.
    """
    import torch

    from spotlessgs.rendering import select_views
    from spotlessgs.training.trainer import load_run

    scene, training_views, config, _ = load_run(run, data_dir=data)
    device = scene.gaussians.means.device
    indices = select_views(training_views, views)

    def synchronize() -> None:
        if device.type == "cuda":
            torch.cuda.synchronize(device)

    seconds = []
    with torch.no_grad():
        frame = relit_frame_renderer(scene, training_views.cameras.to(device), config, indices[0])
        for repeat in range(repeats + 1):
            synchronize()
            start = time.perf_counter()
            for k in indices:
                frame(k)
            synchronize()
            if repeat:  # the first pass warms up (kernel loading, the allocator)
                seconds.append(time.perf_counter() - start)
    name = torch.cuda.get_device_name(device) if device.type == "cuda" else "cpu"
    return {"render_fps": len(indices) / statistics.median(seconds), "render_device": name,
            "render_views": len(indices)}


def _run_spec(data: str | Path, variant: str, preset: str, iterations: int, threads: int, seed: int,
              settings: tuple[tuple[str, Any], ...]):
    """The RunSpec of one variant's row (the child trains it; a finished row is checked against it)."""
    from spotlessgs.run import RunSpec, given_overrides

    return RunSpec(data=Path(data), model=variant, preset=preset, seed=seed,
                   overrides=given_overrides(iterations=iterations, num_threads=threads) + tuple(settings))


#: What a finished row (``benchmark_row.json``) holds at least.
ROW_KEYS = ("variant", "iterations", "ms_per_step", "train_seconds", "gaussians")


def run_benchmark(data: Path, out: Path, variants: tuple[str, ...], preset: str, iterations: int, threads: int,
                  seed: int = 0, settings: tuple[tuple[str, Any], ...] = ()) -> list[dict]:
    """Benchmark each variant in a subprocess (``settings``: (TrainConfig field, value) pairs for every variant);
    writes ``train_benchmark.json`` and ``.md`` to ``out``."""
    from spotlessgs.experiments.run_settings import refuse_other_settings  # loads torch: not for `spotless --help`

    rows = []
    for variant in variants:
        run = out / variant.replace("+", "_")
        if (run / "benchmark_row.json").is_file():  # a finished row: reused when its run had these settings
            if (run / "config.json").is_file():
                refuse_other_settings(run, _run_spec(data, variant, preset, iterations, threads, seed, settings),
                                      f"the {variant} row's run")
            rows.append(read_json(run / "benchmark_row.json", "a benchmark row", ROW_KEYS))
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

    def gpu_memory(r):
        train, render = r.get("peak_gpu_train_mb"), r.get("peak_gpu_render_mb")
        return "–" if train is None else f"{train:.0f} / {render:.0f}"

    given = "; settings: " + ", ".join(f"{k}={v}" for k, v in settings) if settings else ""
    resumed = any(r.get("resumed") for r in rows)
    note = ("; a (resumed) row was interrupted and finished in a later session: its train s is unknown, its ms / "
            "step and peak RSS are that session's" if resumed else "")
    lines = [f"{iterations} iterations per variant, {threads} thread(s){given}{note}", "",
             "| model | ms / step | train s | Gaussians | relit FPS (files) | relit FPS (render) | peak RSS (MB) | "
             "peak GPU MB (train / render) | test PSNR recon. | relit PSNR | relit PSNR aligned | relit SSIM aligned | "
             "PSNR aligned, uniform GT | SSIM aligned, uniform GT |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(
            f"| {r['variant']}{' (resumed)' if r.get('resumed') else ''} | {r['ms_per_step']:.1f} | "
            f"{fmt(r['train_seconds'], '.1f')} | {r['gaussians']} | "
            f"{r['relit_fps']:.1f} | {fmt(r.get('render_fps'), '.1f')} | {r['peak_rss_mb']:.0f} | "
            f"{gpu_memory(r)} | {fmt(r.get('test_psnr_reconstruction'), '.2f')} | "
            f"{fmt(r.get('psnr'), '.2f')} | {fmt(r.get('psnr_aligned'), '.2f')} | {fmt(r.get('ssim_aligned'), '.3f')} | "
            f"{fmt(r.get('psnr_aligned_uniform'), '.2f')} | {fmt(r.get('ssim_aligned_uniform'), '.3f')} |")
    return "\n".join(lines) + "\n"
