"""Metric throughput (images per second) on CPU, for the README: `python3 -m evaluation.benchmark`.

Times PSNR, SSIM and LPIPS (AlexNet) on random image pairs at a few resolutions, after one warm-up call, and prints a
Markdown table. Images are generated with a fixed seed; nothing is downloaded.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass

import torch

from evaluation.lpips import lpips
from spotlessgs.metrics import psnr, ssim
from spotlessgs.io.seeding import torch_generator


@dataclass(frozen=True)
class BenchmarkConfig:
    """What to time."""

    sizes: tuple[tuple[int, int], ...] = ((320, 240), (640, 480))  # (width, height) of the images
    batch: int = 8  # image pairs per call
    repeats: int = 3  # timed calls per metric and size (the median is reported)
    threads: int = 1  # torch CPU threads
    seed: int = 0  # seed of the random images


def measure(config: BenchmarkConfig = BenchmarkConfig()) -> list[dict]:
    """Time each metric; returns rows {metric, width, height, threads, images_per_s, ms_per_image}."""
    torch.set_num_threads(config.threads)
    gen = torch_generator(config.seed, "benchmark-images")
    metrics = {"psnr": psnr, "ssim": ssim, "lpips": lambda a, b: lpips(a, b, batch_size=config.batch)}
    rows = []
    for w, h in config.sizes:
        a = torch.rand(config.batch, 3, h, w, generator=gen)
        b = (a + 0.05 * torch.randn(a.shape, generator=gen)).clamp(0, 1)
        for name, fn in metrics.items():
            with torch.no_grad():
                fn(a, b)  # warm-up (LPIPS loads its weights here)
                times = []
                for _ in range(config.repeats):
                    t0 = time.perf_counter()
                    fn(a, b)
                    times.append(time.perf_counter() - t0)
            sec = sorted(times)[len(times) // 2] / config.batch
            rows.append({"metric": name, "width": w, "height": h, "threads": config.threads,
                         "images_per_s": 1.0 / sec, "ms_per_image": 1000.0 * sec})
    return rows


def markdown(rows: list[dict]) -> str:
    """The rows as a Markdown table."""
    lines = ["| metric | size | threads | images/s | ms/image |", "|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['metric']} | {r['width']}×{r['height']} | {r['threads']} | {r['images_per_s']:.1f} | "
                     f"{r['ms_per_image']:.2f} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    """Command-line entry: --threads N --batch N --repeats N."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--batch", type=int, default=8)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args(argv)
    print(markdown(measure(BenchmarkConfig(batch=args.batch, repeats=args.repeats, threads=args.threads))))


if __name__ == "__main__":
    main()
