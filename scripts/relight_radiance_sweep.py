"""How the relighting radiance L0 trades the two ground truths: a run's test views relit at several fixed L0.

    python3 scripts/relight_radiance_sweep.py RUN [RUN ...] [--l0 0.05 0.1 ...] [--lamp] [--plot FILE.png
        [--labels NAME ...]] [--threads N]

A relit view is R·L0 + R·L_lf (docs/method.md §8): the reflectance under an even light L0 plus the learned
low-frequency (SH, room) light. Exposure alignment removes one overall gain, not the share of the room's light in the
image, and L0 sets that share. ``spotless relight`` chooses L0 for exposure only (about 1 % of pixels at 1). For each
run and each L0 (white, linear), the run's test views are relit into a temporary folder (``Run.score_views``: what
``spotless relight RUN --views test --l0 L L L`` writes) and scored as the reproduction scores them
(``evaluation.runner.score_test_views``: exposure-aligned PSNR, mean over the test views) against the dataset's
lamps-on ground truth and, where the dataset has one, its uniform one. Prints a line per run and L0, and the L0 that
``spotless relight`` chose for the run (``RUN/relit.json``, when it was relit); ``--plot`` draws the lamps-on score
against the uniform one, a curve per run (named by ``--labels``, else by its path), L0 written along it. A model
whose low-frequency light is a constant (DarkGS) relights to the same image at every L0 up to a gain.
``--lamp`` adds, per run, the relighting of ``spotless relight --lamp-l0``: L0 as the paper's "replace L_spot by a
constant" reads most literally, the lamp's own mean irradiance Ψ Φ max(0, n̂·l̂) on the surfaces the training views see
(:func:`spotlessgs.rendering.lamp_irradiance`), beside the room light as learned, the view then scaled as a whole for
exposure as the automatic L0 is (so that its clipping matches).
docs/results.md ("The relighting radiance L0 and the residual-light room's targets", "A lamp-matched L0") quotes it.
"""

from __future__ import annotations

import argparse
import math
import tempfile
from pathlib import Path

from evaluation.runner import score_test_views
from spotlessgs.io.dataset import available_ground_truths, read_dataset
from spotlessgs.io.errors import FolderLockedError, InputError
from spotlessgs.io.json_files import read_json
from spotlessgs.run import Run

#: The L0 values of the sweep by default (white, linear; ``spotless relight`` chose 0.72–0.88 on the
#: residual-light room).
DEFAULT_L0 = (0.05, 0.1, 0.2, 0.3, 0.4, 0.6, 0.8, 1.2)


def sweep(run_dir: str | Path, l0_values: list[float], work: Path, threads: int = 1, lamp: bool = False) -> list[dict]:
    """Rows ``{"l0", "lamps", "uniform"}`` (aligned PSNR, dB; ``uniform`` None without that ground truth) of the run's
    test views relit at each L0, the relit views kept under ``work`` (``work/l0-<L0>``); with ``lamp`` last a row
    relit as ``spotless relight --lamp-l0`` does (``work/l0-lamp``), its ``l0`` "lamp", with ``lamp_irradiance`` and
    the view's ``gain`` (None for a model without a spotlight, which relights as at any L0).

    Raises:
        InputError: the run's dataset has no lamps-on ground truth (names it), or is damaged or gone.
    """
    run = Run.load(run_dir)
    data = run.data_dir
    truths = available_ground_truths(read_dataset(data))
    if "lamps" not in truths:
        raise InputError(f"{data}: the dataset has no ground truth to score against")

    def relit_row(out: Path, l0: list[float] | str) -> tuple[dict, dict]:
        """The row of the test views relit at ``l0`` into ``out``, and the lamps-on scores (with the relighting)."""
        scores = run.score_views(out, "test", threads, l0=l0, device="cpu")
        uniform = score_test_views(data, out, threads, "uniform")["psnr_aligned"] if "uniform" in truths else None
        return {"lamps": scores["psnr_aligned"], "uniform": uniform}, scores

    rows = [{"l0": level, **relit_row(work / f"l0-{level:g}", [level] * 3)[0]} for level in l0_values]
    if lamp:
        row, scores = relit_row(work / "l0-lamp", "lamp")
        rows.append({"l0": "lamp", **row, "lamp_irradiance": scores["relight"].get("lamp_irradiance"),
                     "gain": scores["relight"].get("low_frequency_gain")})
    return rows


def chosen_l0(run_dir: str | Path) -> float | None:
    """The white L0 that ``spotless relight`` chose for the run's own ``RUN/relit`` with the low-frequency light, or
    None (not relit there, relit at a given L0 or without that light, or a 3DGS run, which has none).

    Raises:
        InputError: ``RUN/relit.json`` is damaged or its automatic L0 is not three numbers (names the file).
    """
    path = Path(run_dir) / "relit.json"
    if not path.is_file():
        return None
    summary = read_json(path, "relit summary", required=("l0",))
    l0 = summary["l0"]
    if summary.get("l0_mode") != "auto" or summary.get("low_frequency") is False or l0 is None:
        return None
    if not (isinstance(l0, list) and len(l0) == 3
            and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in l0)):
        raise InputError(f"{path}: l0 must be three numbers, got {l0!r}")
    return float(l0[0])


def plot(curves: dict[str, list[dict]], path: Path) -> None:
    """Lamps-on against uniform PSNR, one curve per run with its L0 values written at the points."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.8))
    for name, rows in curves.items():
        rows = [r for r in rows if r["uniform"] is not None]
        lamp = [r for r in rows if r["l0"] == "lamp"]
        rows = [r for r in rows if r["l0"] != "lamp"]
        line = ax.plot([r["uniform"] for r in rows], [r["lamps"] for r in rows], marker="o", label=name)[0]
        for r in lamp:  # --lamp-l0's relighting: a star in the curve's colour
            ax.plot([r["uniform"]], [r["lamps"]], marker="*", markersize=12, color=line.get_color())
            ax.annotate("lamp", (r["uniform"], r["lamps"]), fontsize=7, xytext=(3, -9), textcoords="offset points")
        last = None
        for r in rows:  # points within 0.05 dB of the last one written (a constant ambient's) are left unwritten
            if last is None or max(abs(r["uniform"] - last[0]), abs(r["lamps"] - last[1])) > 0.05:
                ax.annotate(f"{r['l0']:g}", (r["uniform"], r["lamps"]), fontsize=7, xytext=(3, 3),
                            textcoords="offset points")
                last = (r["uniform"], r["lamps"])
    ax.set_xlabel("aligned PSNR against the uniform ground truth (dB)")
    ax.set_ylabel("aligned PSNR against the lamps-on ground truth (dB)")
    ax.set_title("relit test views at fixed L0 (written at the points)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("runs", nargs="+", help="trained run folders")
    parser.add_argument("--l0", type=float, nargs="+", default=list(DEFAULT_L0), help="white L0 values (linear)")
    parser.add_argument("--lamp", action="store_true",
                        help="also relight each run as `spotless relight --lamp-l0` does (L0: the lamp's mean "
                             "irradiance)")
    parser.add_argument("--plot", type=Path, help="write the trade-off figure here (PNG)")
    parser.add_argument("--labels", nargs="+", help="the runs' names in the figure, one per run (default: folders)")
    parser.add_argument("--threads", type=int, default=1, help="threads for scoring")
    args = parser.parse_args()
    if any(not (math.isfinite(level) and level >= 0) for level in args.l0):
        parser.error(f"--l0 values must be finite and non-negative, got {args.l0}")
    labels = args.labels or list(args.runs)
    if len(labels) != len(args.runs):
        parser.error(f"--labels gives {len(labels)} names for {len(args.runs)} runs")
    if len(set(labels)) != len(labels):
        parser.error(f"the runs' names must differ (one curve each), got {labels}")
    curves = {}
    for run_dir, label in zip(args.runs, labels):
        with tempfile.TemporaryDirectory() as tmp:
            try:
                chosen = chosen_l0(run_dir)
                rows = sweep(run_dir, args.l0, Path(tmp), args.threads, lamp=args.lamp)
            except (FileNotFoundError, InputError, FolderLockedError) as err:  # not a run, a damaged one, its
                raise SystemExit(f"error: {err}") from None                     # dataset moved, or in use
        curves[label] = rows
        print(f"{run_dir}: spotless relight chose L0 = {chosen:.3f}" if chosen is not None else f"{run_dir}:")
        for r in rows:
            uniform = f"{r['uniform']:.2f}" if r["uniform"] is not None else "-"
            if r["l0"] != "lamp":
                print(f"  L0 {r['l0']:<5g} lamps-on {r['lamps']:.2f} dB  uniform {uniform} dB")
            elif r["lamp_irradiance"] is None:
                print(f"  --lamp-l0 (no lamp)  lamps-on {r['lamps']:.2f} dB  uniform {uniform} dB")
            else:
                print(f"  --lamp-l0 (L0 {r['lamp_irradiance']:.3f}, the view x {r['gain']:.2f})  lamps-on "
                      f"{r['lamps']:.2f} dB  uniform {uniform} dB")
    if args.plot:
        plot(curves, args.plot)
        print(f"wrote {args.plot}")


if __name__ == "__main__":
    main()
