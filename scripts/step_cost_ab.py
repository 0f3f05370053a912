"""What a training setting costs per step: whole runs with and without it, alternated, one at a time.

    python3 scripts/step_cost_ab.py DATA OUT --set depth_spread=on [--set depth_spread_weight=0.1] [--variant spotless]
        [--base depth_spread_every=4] [--preset quick] [--repeats 4] [--seed 0]

Trains ``--repeats`` pairs of runs of ``--variant`` on DATA into OUT/a-rR and OUT/b-rR (OUT new or empty): A with the
preset's settings and the ``--base`` ones, B with those and the ``--set`` changes, in the order A B, B A, A B, B A,
...: with an even number of repeats a machine whose speed drifts steadily during the measurement favours neither.
(On a real camera's data `depth_spread=auto` already trains the term: compare `--set depth_spread=off` there.) A
setting that changes densification changes the number of Gaussians too, so whole runs are the unit, not a block of
steps on one model (scripts/pose_step_cost.py). Run it on an otherwise idle machine. Prints, and writes to
OUT/step_cost.json, each run's ms per step (the trainer's training loop), the means and each pair's ratio B / A
(with the settings of both arms, ``settings_both``, and of B, ``settings_b``). docs/results.md ("The depth-spread
term: on for real cameras", "The depth-spread term on every 4th step") quotes it.
"""

from __future__ import annotations

import argparse
import json
import statistics
from pathlib import Path

from spotlessgs.io.atomic import write_json
from spotlessgs.training.config import parse_setting, preset
from spotlessgs.training.trainer import train


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data")
    parser.add_argument("out", type=Path)
    parser.add_argument("--set", dest="settings", action="append", required=True, metavar="KEY=VALUE",
                        help="a TrainConfig setting of run B (repeatable)")
    parser.add_argument("--base", dest="base", action="append", default=[], metavar="KEY=VALUE",
                        help="a TrainConfig setting of both runs (repeatable)")
    parser.add_argument("--variant", default="spotless")
    parser.add_argument("--preset", default="quick")
    parser.add_argument("--repeats", type=int, default=4)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    base = dict(parse_setting(s) for s in args.base)
    configs = {"a": preset(args.preset, **base),
               "b": preset(args.preset, **{**base, **dict(parse_setting(s) for s in args.settings)})}
    rows = []
    for repeat in range(args.repeats):
        for arm in ("a", "b") if repeat % 2 == 0 else ("b", "a"):
            result = train(args.data, args.out / f"{arm}-r{repeat}", args.variant, configs[arm], seed=args.seed,
                           progress=False)
            rows.append({"arm": arm, "repeat": repeat, "ms_per_step": result.ms_per_step})
            print(json.dumps(rows[-1]), flush=True)
    ms = {arm: [r["ms_per_step"] for r in sorted(rows, key=lambda r: r["repeat"]) if r["arm"] == arm]
          for arm in ("a", "b")}
    summary = {"settings_both": args.base, "settings_b": args.settings, "variant": args.variant,
               "preset": args.preset, "runs": rows,
               "mean_ms_per_step": {arm: statistics.fmean(v) for arm, v in ms.items()},
               "pair_ratios_b_over_a": [b / a for a, b in zip(ms["a"], ms["b"])]}
    summary["ratio_of_means"] = summary["mean_ms_per_step"]["b"] / summary["mean_ms_per_step"]["a"]
    write_json(args.out / "step_cost.json", summary)
    print(f"A {summary['mean_ms_per_step']['a']:.1f} ms, B {summary['mean_ms_per_step']['b']:.1f} ms per step: "
          f"B / A = {summary['ratio_of_means']:.3f} (pairs: "
          + ", ".join(f"{r:.3f}" for r in summary["pair_ratios_b_over_a"]) + ")")


if __name__ == "__main__":
    main()
