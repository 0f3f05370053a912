"""Rasterizer timings: forward + backward (L1 loss) per backend, in milliseconds.

    python -m spotlessgs.rasterizer.benchmark [--threads 2] [--repeats 7] [--backends cpp,torch] [--quick]

Cases: 160×120 with 20k Gaussians and 3 / 12 channels, 320×240 with 50k Gaussians and 3 channels (``--quick``: only
the first). Reported per case and backend: the median and the minimum wall-clock time over the repeats and the
minimum CPU time (all threads of the process). The load average is printed first: on a busy machine the wall-clock
figures grow with the load, and the minimum is the better estimate of the cost.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from dataclasses import dataclass

import torch

from spotlessgs.io.seeding import torch_generator

from .api import rasterize
from .cpp_kernel import load_kernel


@dataclass(frozen=True)
class BenchCase:
    """One benchmark configuration."""

    width: int  # image width in pixels
    height: int  # image height in pixels
    gaussians: int  # number of Gaussians
    channels: int  # feature channels


CASES = (BenchCase(160, 120, 20_000, 3), BenchCase(160, 120, 20_000, 12), BenchCase(320, 240, 50_000, 3))


def make_scene(case: BenchCase, seed: int = 0) -> tuple[list[torch.Tensor], torch.Tensor, torch.Tensor]:
    """A room-like test scene: Gaussians on the walls of a box around the camera, sized like a trained model's.

    Returns:
        params [means (N, 3), quats (N, 4), scales (N, 3), opacities (N,), features (N, C)] (leaf tensors that
        require grad), viewmat (4, 4), K (3, 3).
    """
    gen = torch_generator(seed, "rasterizer-benchmark")
    n = case.gaussians
    # Points on five walls of a 4 m × 3 m × 5 m box seen from inside (the camera looks down +z).
    u = torch.rand(n, 2, generator=gen) * 2 - 1
    wall = torch.randint(0, 5, (n,), generator=gen)
    half = torch.tensor([2.0, 1.5, 2.5])
    means = torch.zeros(n, 3)
    axes = [(0, 1, 2, 1.0), (0, 1, 2, -1.0), (1, 2, 0, 1.0), (1, 2, 0, -1.0), (0, 2, 1, 1.0)]
    for w, (a, b, fixed, sign) in enumerate(axes):
        m = wall == w
        means[m, a] = u[m, 0] * half[a]
        means[m, b] = u[m, 1] * half[b]
        means[m, fixed] = sign * half[fixed]
    means[:, 2] += 2.0
    means += 0.02 * torch.randn(n, 3, generator=gen)
    quats = torch.randn(n, 4, generator=gen)
    # Mean spacing on ~50 m² of wall: sqrt(50 / n); scales of that order so the surfaces close up.
    spacing = (50.0 / n) ** 0.5
    scales = spacing * torch.exp(0.3 * torch.randn(n, 3, generator=gen))
    opacities = torch.sigmoid(torch.randn(n, generator=gen) + 1.0)
    features = torch.rand(n, case.channels, generator=gen)
    fx = 0.9 * case.width
    K = torch.tensor([[fx, 0.0, case.width / 2], [0.0, fx, case.height / 2], [0.0, 0.0, 1.0]])
    params = [t.requires_grad_() for t in (means, quats, scales, opacities, features)]
    return params, torch.eye(4), K


def time_backend(case: BenchCase, backend: str, threads: int, repeats: int) -> tuple[list[float], list[float]]:
    """Wall-clock and process-CPU milliseconds of forward + L1 backward per run, one warm-up run excluded."""
    params, view, K = make_scene(case)
    target = torch.zeros(case.height, case.width, case.channels)
    wall, cpu = [], []
    for i in range(repeats + 1):
        for p in params:
            p.grad = None
        start, start_cpu = time.perf_counter(), time.process_time()
        out = rasterize(*params, view, K, case.width, case.height, backend=backend, num_threads=threads)
        (out.image - target).abs().mean().backward()
        if i:
            wall.append((time.perf_counter() - start) * 1e3)
            cpu.append((time.process_time() - start_cpu) * 1e3)
    return wall, cpu


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--threads", type=int, default=2, help="threads for the CPU backends and torch ops")
    parser.add_argument("--repeats", type=int, default=7, help="timed runs per case and backend")
    parser.add_argument("--backends", default="cpp,torch", help="comma-separated backends to time")
    parser.add_argument("--quick", action="store_true", help="only the first case")
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    backends = [b.strip() for b in args.backends.split(",") if b.strip()]
    if "cpp" in backends and load_kernel() is None:
        print("C++ kernel unavailable; timing the torch backend only")
        backends = [b for b in backends if b != "cpp"]
    load = ", ".join(f"{x:.1f}" for x in os.getloadavg())
    print(f"torch {torch.__version__}, threads {args.threads}, repeats {args.repeats}, "
          f"{os.cpu_count()} CPUs, load average {load}")
    print(f"{'case':<26}{'backend':<9}{'median ms':>10}{'min ms':>9}{'min cpu ms':>12}")
    for case in CASES[:1] if args.quick else CASES:
        label = f"{case.width}x{case.height} / {case.gaussians // 1000}k / {case.channels}ch"
        for backend in backends:
            wall, cpu = time_backend(case, backend, args.threads, args.repeats)
            print(f"{label:<26}{backend:<9}{statistics.median(wall):>10.1f}{min(wall):>9.1f}{min(cpu):>12.1f}",
                  flush=True)


if __name__ == "__main__":
    main()
