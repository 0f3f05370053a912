"""Render speed against error: one view at several sample counts vs a high-sample reference.

    spotless-sim benchmark --scene scenes/bedroom/house.json --out bench/render

renders the first pose of the room's camera loop at each sample count (with and without OpenImageDenoise) and a
reference at ``--reference-samples`` (denoised), then reports seconds per paired frame (both renders) against the
PSNR of each render relative to the reference, as ``render_benchmark.json``, a Markdown table and a plot. Timings are
wall-clock on whatever machine runs it: compare rows of one run, not runs of different machines.
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import numpy as np
import torch

from simulator.front3d import LoadOptions
from simulator.render_pipeline import RenderConfig, plan_poses
from spotlessgs.io.atomic import write_json, write_text
from spotlessgs.io.colorspace import linear_to_srgb
from spotlessgs.io.errors import InputError
from spotlessgs.io.figures import pyplot, save_figure
from spotlessgs.io.provenance import provenance
from spotlessgs.metrics import psnr


def psnr_srgb(image_linear: np.ndarray, reference_linear: np.ndarray) -> float:
    """PSNR (dB) between two linear renders after sRGB encoding (clipped to [0, 1]), as images are compared."""
    a, b = (torch.from_numpy(linear_to_srgb(x)).permute(2, 0, 1) for x in (image_linear, reference_linear))
    return float(psnr(a, b)[0])


def run_benchmark(scene_path: Path, out_dir: Path, samples: list[int], reference_samples: int, width: int,
                  height: int, threads: int, frame: int = 0) -> list[dict]:
    """Render one pose at each setting; returns one row per (samples, denoise) with seconds and PSNRs."""
    if sorted(set(samples)) != sorted(samples) or any(n >= reference_samples for n in samples):
        raise InputError(f"--samples {','.join(map(str, samples))}: each count once and below --reference-samples "
                         f"({reference_samples}), which the others are scored against")
    try:  # before minutes of rendering: a --out that cannot be a folder fails now
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"{out_dir}: --out cannot be made a folder ({exc.strerror or exc})") from None
    from simulator.blender import renderer, scene_builder  # deferred: bpy is imported only when rendering

    config = RenderConfig(width=width, height=height, frames=max(frame + 1, 8))
    scene, _room, objects, poses = plan_poses(scene_path, config, LoadOptions())
    scene_builder.reset_blender()
    base = renderer.CyclesSettings(width=width, height=height, threads=threads, device="cpu")
    renderer.configure(base)
    built = scene_builder.build_scene(dataclasses.replace(scene, objects=objects), config.spotlight,
                                      config.ground_truth.ceiling_glow, config.intrinsics())

    def render(n: int, denoise: bool):
        settings = dataclasses.replace(base, samples=n, denoise=denoise)
        renderer.configure(settings)
        start = time.perf_counter()
        pair = renderer.render_pair(built, poses[frame], settings, seed=1234)
        return pair, time.perf_counter() - start

    from tqdm import tqdm

    reference, ref_seconds = render(reference_samples, True)
    rows = [{"samples": reference_samples, "denoise": True, "seconds_per_pair": ref_seconds, "psnr_uneven": None,
             "psnr_gt": None, "reference": True}]
    for n, denoise in tqdm([(n, d) for n in samples for d in (False, True)], desc="render benchmark"):
        pair, seconds = render(n, denoise)
        rows.append({"samples": n, "denoise": denoise, "seconds_per_pair": seconds,
                     "psnr_uneven": psnr_srgb(pair.uneven, reference.uneven),
                     "psnr_gt": psnr_srgb(pair.gt, reference.gt), "reference": False})
    write_json(out_dir / "render_benchmark.json",
               {"scene": str(scene_path), "width": width, "height": height, "threads": threads, "rows": rows,
                "provenance": provenance(extra_packages=("bpy",))})
    write_text(out_dir / "render_benchmark.md", markdown_table(rows, width, height))
    plot(rows, out_dir / "render_benchmark.png", width, height)
    return rows


def markdown_table(rows: list[dict], width: int, height: int) -> str:
    """The benchmark as a Markdown table."""
    lines = [f"Render cost vs error at {width}x{height} (PSNR vs the reference, both renders of one pose)", "",
             "| samples | denoise | s / pair | PSNR uneven (dB) | PSNR ground truth (dB) |", "|---|---|---|---|---|"]
    for r in rows:
        if r["reference"]:
            lines.append(f"| {r['samples']} (reference) | yes | {r['seconds_per_pair']:.1f} | – | – |")
        else:
            lines.append(f"| {r['samples']} | {'yes' if r['denoise'] else 'no'} | {r['seconds_per_pair']:.1f} | "
                         f"{r['psnr_uneven']:.2f} | {r['psnr_gt']:.2f} |")
    return "\n".join(lines) + "\n"


def plot(rows: list[dict], path: Path, width: int, height: int) -> None:
    """Seconds per pair (x) against PSNR (y), one curve per render and denoise setting."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(6, 4))
    for denoise, style in ((False, "--"), (True, "-")):
        sel = [r for r in rows if not r["reference"] and r["denoise"] == denoise]
        for key, label in (("psnr_uneven", "spotlight"), ("psnr_gt", "ground truth")):
            ax.plot([r["seconds_per_pair"] for r in sel], [r[key] for r in sel], style, marker="o",
                    label=f"{label}{' + OIDN' if denoise else ''}")
            for r in sel:
                ax.annotate(str(r["samples"]), (r["seconds_per_pair"], r[key]), fontsize=7)
    ax.set_xscale("log")
    ax.set_xlabel("seconds per paired frame (wall clock)")
    ax.set_ylabel("PSNR vs reference (dB)")
    ax.set_title(f"Cycles CPU, {width}x{height}")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    save_figure(fig, path)
