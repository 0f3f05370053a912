"""Where a training step's time goes: the torch profiler over a run's first steps, one thread.

    python3 scripts/step_profile.py DATA OUT [--variant spotless] [--preset quick] [--steps 300] [--rows 25]

Trains ``--variant`` on DATA into OUT (a new run folder) for the first ``--steps`` steps of ``--preset``
(``stop_after``: the run stops as if interrupted, with a checkpoint, and resumes with ``spotless train --resume``)
under ``torch.profiler``, on one thread (the run's ``num_threads``), and prints a Markdown table of the ``--rows``
operators with the most self CPU time: ms per step, share of all profiled self time, and calls per step. The rasterizer's C++ compositing shows as
``_CompositeFunction`` and ``_CompositeFunctionBackward``, its projection as ``_ProjectFunction`` and
``_ProjectFunctionBackward``; an ``aten::`` row sums every call of that operator, wherever it comes from. The profiler
slows the run, so the shares are the figure, not the times. The first steps are those before densification, with the
start's Gaussians: scripts/step_cost_ab.py times whole runs. docs/results.md ("Where a SpotlessGS step's time goes")
quotes it.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from torch.profiler import ProfilerActivity, profile

from spotlessgs.training.config import TrainConfig, preset
from spotlessgs.training.trainer import train


def profile_steps(data: str | Path, out: str | Path, variant: str, config: TrainConfig,
                  steps: int) -> tuple[float, float, list[tuple[str, float, int]]]:
    """Train ``steps`` steps of ``variant`` (``config``) on ``data`` into ``out`` under the profiler, seed 0. Returns
    (the trainer's ms per step, all operators' self CPU time in ms, [(operator, self CPU ms, calls)] by descending
    self time)."""
    with profile(activities=[ProfilerActivity.CPU]) as prof:
        result = train(data, out, variant, config, seed=0, progress=False, stop_after=steps)
    rows = sorted(((event.key, event.self_cpu_time_total / 1000.0, event.count) for event in prof.key_averages()),
                  key=lambda row: -row[1])
    return result.ms_per_step, sum(ms for _, ms, _ in rows), rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data", type=Path)
    parser.add_argument("out", type=Path)
    parser.add_argument("--variant", default="spotless")
    parser.add_argument("--preset", default="quick")
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--rows", type=int, default=25)
    args = parser.parse_args()
    ms_per_step, total, rows = profile_steps(args.data, args.out, args.variant, preset(args.preset, num_threads=1),
                                             args.steps)
    print(f"{args.variant}, {args.steps} steps of {args.preset}: {ms_per_step:.1f} ms per step under the profiler, "
          f"{total / args.steps:.1f} ms of operator self time per step")
    print("| operator | ms per step | share | calls per step |\n|---|---|---|---|")
    for name, ms, calls in rows[:args.rows]:
        print(f"| {name} | {ms / args.steps:.2f} | {100.0 * ms / total:.1f} % | {calls / args.steps:.1f} |")


if __name__ == "__main__":
    main()
