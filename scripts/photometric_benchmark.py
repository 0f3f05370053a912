"""What the photometric camera buys: train one model with it off or on, relight every view, score against the truth.

    spotless reproduce --preset quick --out out/quick --jobs 2              # the bedroom's renders
    spotless-sim add-noise --robot-camera --data out/quick/datasets/bedroom-uneven --out data/bedroom-robot
    python3 scripts/photometric_benchmark.py data/bedroom-robot runs/robot-off off
    python3 scripts/photometric_benchmark.py data/bedroom-robot runs/robot-on on
    python3 scripts/photometric_benchmark.py out/quick/datasets/bedroom-uneven runs/ideal off

Prints one JSON line: relit PSNR / SSIM (raw and exposure-aligned) of the test views, training time and ms per step,
the frame-to-frame change of the relit and true sequences' mean brightness (mean |Δ log|), and with the camera on and
a ``camera_effects.json`` truth, how well the learned exposures match (correlation and RMS of the centred log-gains
over the fitted frames) and the learned vignetting. The numbers of docs/results.md ("Real robot cameras") came from
these commands (spotless model, quick preset, 2 threads).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from spotlessgs.io.colorspace import srgb_to_linear
from spotlessgs.io.images import read_image
from spotlessgs.run import RunSpec, train
from spotlessgs.training.data import load_training_views


def _flicker(folder: Path, names: list[str]) -> float:
    levels = np.array([srgb_to_linear(read_image(folder / n)).mean() for n in names])
    return float(np.mean(np.abs(np.diff(np.log(levels)))))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data", type=Path)
    parser.add_argument("out", type=Path)
    parser.add_argument("photometric", choices=["auto", "on", "off"])
    parser.add_argument("--model", default="spotless")
    parser.add_argument("--preset", default="quick")
    parser.add_argument("--threads", type=int, default=2)
    args = parser.parse_args()
    start = time.perf_counter()
    spec = RunSpec(data=args.data, model=args.model, preset=args.preset,
                   overrides=(("num_threads", args.threads), ("photometric", args.photometric)))
    run = train(spec, args.out, resume=True, progress=False)
    seconds = time.perf_counter() - start
    scores = run.score_views(args.out / "relit_all", "all", args.threads)
    names = sorted(p.name for p in (args.data / "gt").iterdir())
    result = {"photometric": args.photometric, "train_seconds": seconds, "ms_per_step": run.summary["ms_per_step"],
              "gaussians": run.summary["num_gaussians"], **{k: v for k, v in scores.items() if k != "relight"},
              "flicker_relit": _flicker(args.out / "relit_all", names), "flicker_truth": _flicker(args.data / "gt", names)}
    report_path, truth_path = args.out / "photometric.json", args.data / "camera_effects.json"
    if report_path.is_file():
        report = json.loads(report_path.read_text())
        if report["exposure"] and truth_path.is_file():
            truth = json.loads(truth_path.read_text())["gains"]
            views = load_training_views(args.data)
            true_log = np.log([truth[views.names[i]] for i in views.train])
            learned_log = np.log([report["exposure"]["gains"][views.names[i]] for i in views.train])
            true_log, learned_log = true_log - true_log.mean(), learned_log - learned_log.mean()
            result["exposure_correlation"] = float(np.corrcoef(true_log, learned_log)[0, 1])
            result["exposure_rms_log_error"] = float(np.sqrt(np.mean((true_log - learned_log) ** 2)))
        if report["vignetting"]:
            result["vignetting"] = report["vignetting"]["falloff"]
    print(json.dumps(result))


if __name__ == "__main__":
    main()
