"""Acceptance measurements of automatic model selection and the Gaussian budget, rerunnable with one command.

    spotless benchmark selection --data data/bedroom --data data/storage --out bench/selection

Per dataset folder (room = folder name), under ``OUT/<room>/``:

* ``auto/``: model selection (:func:`spotlessgs.training.selection.select_model`, its decision with every candidate
  and its wall time in ``auto/model_selection.json``), then the chosen model trained there with the default strategy
  (as ``spotless train --model auto`` does);
* ``spotless/``: the fixed SpotlessGS model, default strategy;
* ``spotless-budget/``: SpotlessGS with the Gaussian budget (the fields of ``spotless train --gaussian-budget``).

With several ``--seed`` values every seed is measured as above under ``OUT/seed-<s>/`` and ``OUT`` gets the summary
over seeds (:func:`aggregate_seeds`): per run the mean, minimum and maximum of each figure, every seed's choice, and
the verdicts on the means (single runs differ by ~0.15 dB, as much as the bounds' margins).

Each run is scored like :mod:`spotlessgs.experiments.benchmark`: every view relit in this process, the
test views scored against the ground truth raw and after one exposure gain (``psnr_aligned``, the figure the verdicts
use). Writes ``OUT/selection_benchmark.json`` (numbers + provenance), ``OUT/selection_benchmark.md`` (a table per
room and the verdicts) and ``OUT/budget.png``. Rerunning reuses finished runs (``train_summary.json`` present) and
their scores (``selection_benchmark_row.json``); an interrupted run continues from its last checkpoint. Timings are
wall clock on the machine that runs it: compare rows of one run. The relit FPS of a room's three runs is measured
again at the end, back to back (:func:`paired_relit_fps`), because runs reused from an earlier invocation were timed
under another load (measured: the same model at 31.3 and 24.8 FPS in two sessions); the FPS right after training is
kept as ``relit_fps_after_training``.
"""

from __future__ import annotations

import dataclasses
import logging
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from evaluation.runner import require_ground_truth
from spotlessgs.io.atomic import write_json, write_text
from spotlessgs.io.json_files import read_json
from spotlessgs.experiments.run_settings import refuse_other_settings
from spotlessgs.io.provenance import provenance
from spotlessgs.run import AUTO, Run, RunSpec, given_overrides, train
from spotlessgs.training.budget_plot import BudgetPoint, plot_budget
from spotlessgs.training.selection import SelectionConfig
from spotlessgs.training.budget import (
    BUDGET_MAX_LOSS_DB, BUDGET_MIN_REDUCTION_PCT, EPS, budget_verdict, check_finite,
)
from spotlessgs.training.light_need import light_note

log = logging.getLogger(__name__)

RESULTS_JSON = "selection_benchmark.json"
RESULTS_MD = "selection_benchmark.md"
PLOT = "budget.png"
ROW_FILE = "selection_benchmark_row.json"
# Run key -> folder under OUT/<room>/.
RUN_FOLDERS = {"spotless": "spotless", "chosen": "auto", "budget": "spotless-budget"}
# The bounds as recorded in the results JSON.
BOUNDS = {"budget_min_reduction_pct": BUDGET_MIN_REDUCTION_PCT, "budget_max_loss_db": BUDGET_MAX_LOSS_DB}


@dataclass(frozen=True)
class BenchmarkSettings:
    """What the measurements depend on besides the data."""

    # Trainer preset (spotlessgs.training.config.PRESETS).
    preset: str = "quick"
    # Override of the preset's iteration count (None = the preset's; the densification schedule scales with it).
    iterations: int | None = None
    # Override of the preset's training image width in pixels (None = the preset's).
    image_width: int | None = None
    # CPU threads for training, relighting and scoring.
    threads: int = 1
    # The command seed (training, selection holdout, view order).
    seed: int = 0
    # SelectionConfig.min_proxy_iterations override (None = the selection's default; small for tests).
    min_proxy_iterations: int | None = None

    def __post_init__(self) -> None:
        if self.threads < 1:
            raise ValueError(f"BenchmarkSettings: threads must be >= 1, got {self.threads}")
        for name in ("iterations", "image_width", "min_proxy_iterations"):
            value = getattr(self, name)
            if value is not None and value < 1:
                raise ValueError(f"BenchmarkSettings: {name} must be >= 1, got {value}")


def run_spec(data: Path, settings: BenchmarkSettings, model: str, strategy: str) -> RunSpec:
    """One benchmark run: ``model`` (a variant or ``auto``) with the preset, the settings' overrides and the
    densification ``strategy`` (``default``, or ``budget``: the fields of ``spotless train --gaussian-budget``); for
    ``auto`` the settings' ``min_proxy_iterations`` when given."""
    selection = None
    if model == AUTO and settings.min_proxy_iterations is not None:
        selection = SelectionConfig(min_proxy_iterations=settings.min_proxy_iterations)
    return RunSpec(data=data, model=model, preset=settings.preset, strategy=strategy, seed=settings.seed,
                   overrides=given_overrides(num_threads=settings.threads, iterations=settings.iterations,
                                             image_width=settings.image_width), selection=selection)


def selection_summary(decision: dict[str, Any]) -> dict[str, Any]:
    """What the benchmark reports of a model-selection decision: ``chosen``, ``chosen_model`` (ModelConfig fields),
    ``best``, ``tolerance_db``, ``candidates`` (every scored candidate), ``low_frequency_light`` (the light phase's
    measurements) and ``seconds``: wall time of the whole selection (None for a decision of an earlier version,
    which did not record it)."""
    return {**{k: decision[k] for k in ("chosen", "chosen_model", "best", "tolerance_db", "candidates")},
            "low_frequency_light": decision["low_frequency_light"], "seconds": decision.get("seconds")}


#: What a finished row (``selection_benchmark_row.json``) holds at least (what the report reads of it).
ROW_KEYS = ("model", "strategy", "steps", "gaussians", "train_seconds", "ms_per_step", "relit_fps", "psnr_aligned")


def measure_run(spec: RunSpec, run_dir: Path, threads: int) -> dict:
    """Train ``spec`` (unless ``train_summary.json`` exists), relight every view and score the test views of one run.

    Returns:
        the row: model, strategy, steps, gaussians, train_seconds (the training loop's wall time; None for a run
        resumed after an interruption, whose last session's time is not its cost), ms_per_step, relit_fps (every
        view, native resolution), relit_views, psnr / ssim / psnr_aligned / ssim_aligned (dB / SSIM of the relit
        test views against the ground truth); also stored as ``run_dir/selection_benchmark_row.json`` and reused
        from there.
    """
    summary_path, row_path = run_dir / "train_summary.json", run_dir / ROW_FILE
    if summary_path.is_file():
        refuse_other_settings(run_dir, spec)
        if row_path.is_file():
            return read_json(row_path, "a benchmark row", ROW_KEYS)
        run = Run.load(run_dir)
    else:
        log.info("training %s (%s, %s strategy)", run_dir, spec.model, spec.strategy)
        run = train(spec, run_dir, resume=True, progress=False)
    summary = run.summary
    log.info("relighting and scoring %s", run_dir)
    scores = run.score_views(run_dir / "relit", "all", threads, data_dir=spec.data)
    relit = scores.pop("relight")
    row = {"model": run.model, "strategy": spec.strategy,
           "steps": summary["steps"], "gaussians": summary["num_gaussians"],
           # a resumed run's time is its last session's alone: unknown as the run's cost
           "train_seconds": None if summary.get("session_started_at_step", 0) > 0 else summary["seconds_this_session"],
           "ms_per_step": summary["ms_per_step"],
           "relit_fps": relit["fps"], "relit_views": relit["count"], **scores}
    write_json(row_path, row)
    return row


def selection_verdict(chosen_psnr: float, spotless_psnr: float, tolerance_db: float) -> dict[str, Any]:
    """Is the chosen model's relit PSNR (dB) at most ``tolerance_db`` below SpotlessGS's?

    Returns ``delta_db`` (chosen − spotless), ``tolerance_db`` and ``within`` (delta ≥ −tolerance, at the bound
    included).
    """
    check_finite("selection_verdict", chosen_psnr=chosen_psnr, spotless_psnr=spotless_psnr, tolerance_db=tolerance_db)
    if tolerance_db < 0:
        raise ValueError(f"selection_verdict: tolerance_db must be >= 0, got {tolerance_db}")
    delta = chosen_psnr - spotless_psnr
    return {"delta_db": delta, "tolerance_db": tolerance_db, "within": delta >= -tolerance_db - EPS}


def _signed(value: float, spec: str) -> str:
    """``value`` formatted with an explicit sign, a true minus sign for negatives (−0.10, +0.10)."""
    text = format(value, "+" + spec)
    return "−" + text[1:] if text.startswith("-") else text


def verdict_lines(selection: dict[str, Any], budget: dict[str, Any]) -> list[str]:
    """The two verdict lines of a room, from :func:`selection_verdict` and :func:`budget_verdict`."""
    return [f"choice vs spotless: {_signed(selection['delta_db'], '.2f')} dB (tolerance {selection['tolerance_db']:g} "
            f"dB) — {'within' if selection['within'] else 'outside'}",
            f"budget: {_signed(-budget['reduction_pct'], '.1f')}% Gaussians, {_signed(budget['delta_db'], '.2f')} dB "
            f"(bound {budget['max_loss_db']:g} dB, at least {budget['min_reduction_pct']:g}% fewer) — "
            f"{'met' if budget['met'] else 'missed'}"]


def room_verdicts(room: dict[str, Any]) -> dict[str, Any]:
    """Both verdicts of one room's measurements (exposure-aligned relit PSNR)."""
    runs = room["runs"]
    return {"selection": selection_verdict(runs["chosen"]["psnr_aligned"], runs["spotless"]["psnr_aligned"],
                                           room["selection"]["tolerance_db"]),
            "budget": budget_verdict(runs["spotless"]["gaussians"], runs["budget"]["gaussians"],
                                     runs["spotless"]["psnr_aligned"], runs["budget"]["psnr_aligned"])}


# Rounds of the paired relit-FPS measurement; each run keeps its best round (the first also warms up).
FPS_ROUNDS = 2


def paired_relit_fps(run_dirs: dict[str, Path], rounds: int = FPS_ROUNDS) -> dict[str, float]:
    """Relit FPS (every view) of several runs measured back to back: the runs take turns for ``rounds`` rounds and
    each keeps its best round, so that all are timed under the same load. Renders into a temporary folder."""
    if rounds < 1:
        raise ValueError(f"paired_relit_fps: rounds must be >= 1, got {rounds}")
    best = {key: 0.0 for key in run_dirs}
    with tempfile.TemporaryDirectory(prefix="relit-fps-") as tmp:
        for r in range(rounds):
            for key, run_dir in run_dirs.items():
                relit = Run(Path(run_dir)).relight("all", Path(tmp) / f"{key}-{r}", progress=False)
                best[key] = max(best[key], float(relit["fps"]))
    return best


def measure_room(data: Path, room_dir: Path, settings: BenchmarkSettings) -> dict[str, Any]:
    """Selection and the three runs of one dataset; returns ``data``, ``selection``, ``runs`` and ``verdicts``."""
    specs = {"spotless": run_spec(data, settings, "spotless", "default"),
             "chosen": run_spec(data, settings, AUTO, "default"),  # model selection, then the chosen model
             "budget": run_spec(data, settings, "spotless", "budget")}
    runs = {key: measure_run(spec, room_dir / RUN_FOLDERS[key], settings.threads) for key, spec in specs.items()}
    selection = selection_summary(Run.load(room_dir / RUN_FOLDERS["chosen"]).decision)
    log.info("%s: model selection chose %s", room_dir.name, selection["chosen"])
    log.info("%s: relit FPS of the three runs, back to back", room_dir.name)
    fps = paired_relit_fps({key: room_dir / RUN_FOLDERS[key] for key in runs})
    runs = {key: {**row, "relit_fps_after_training": row["relit_fps"], "relit_fps": fps[key]}
            for key, row in runs.items()}
    room = {"data": str(data), "selection": selection, "runs": runs}
    room["verdicts"] = room_verdicts(room)
    return room


def markdown_report(rooms: dict[str, dict[str, Any]], settings: BenchmarkSettings) -> str:
    """Per room: the selection, a table of the three runs and the verdict lines."""
    def fmt(value, spec):
        return "–" if value is None else format(value, spec)

    lines = [f"Preset {settings.preset}, iterations {settings.iterations or 'of the preset'}, "
             f"{settings.threads} thread(s), seed {settings.seed}. Relit PSNR of the test views against the ground "
             "truth; aligned = after one exposure gain. Relit FPS over every view.", ""]
    for name, room in rooms.items():
        sel = room["selection"]
        lines += [f"## {name}", "",
                  f"Selection: chose {sel['chosen']} (best held-out PSNR: {sel['best']}, tolerance "
                  f"{sel['tolerance_db']:g} dB) in {fmt(sel['seconds'], '.1f')} s, {len(sel['candidates'])} "
                  f"candidates{light_note(sel['low_frequency_light'])}.", "",
                  "| run | model | strategy | Gaussians | train s | ms / step | relit PSNR | relit PSNR aligned | "
                  "relit FPS |",
                  "|---|---|---|---|---|---|---|---|---|"]
        for key, r in room["runs"].items():
            lines.append(f"| {key} | {r['model']} | {r['strategy']} | {r['gaussians']} | "
                         f"{fmt(r['train_seconds'], '.1f')} | "
                         f"{r['ms_per_step']:.1f} | {r['psnr']:.2f} | {r['psnr_aligned']:.2f} | "
                         f"{r['relit_fps']:.1f} |")
        lines += [""] + [f"- {v}" for v in verdict_lines(room["verdicts"]["selection"], room["verdicts"]["budget"])]
        lines.append("")
    return "\n".join(lines)


def budget_points(rooms: dict[str, dict[str, Any]]) -> list:
    """BudgetPoints of the default and the budget SpotlessGS run of every room."""
    return [BudgetPoint(name, strategy, int(r["gaussians"]), float(r["psnr_aligned"]), float(r["relit_fps"]))
            for name, room in rooms.items()
            for strategy, r in (("default", room["runs"]["spotless"]), ("budget", room["runs"]["budget"]))]


def run_selection_benchmark(data_dirs: list[Path], out: Path, settings: BenchmarkSettings = BenchmarkSettings()
                            ) -> dict[str, Any]:
    """Measure every dataset; writes ``selection_benchmark.json`` / ``.md`` and ``budget.png`` to ``out``.

    Returns the JSON's content: ``settings``, ``bounds``, ``rooms`` (room name -> :func:`measure_room`'s dict) and
    ``provenance``.
    """
    if not data_dirs:
        raise ValueError("run_selection_benchmark: no dataset folders given")
    names = [Path(d).name for d in data_dirs]
    duplicates = sorted({n for n in names if names.count(n) > 1})
    if duplicates:
        raise ValueError(f"run_selection_benchmark: dataset folders share the room name(s) {duplicates}; "
                         "rooms are named by folder name")
    for d in data_dirs:  # every room before the first trains
        require_ground_truth(d, "--data")
    rooms = {name: measure_room(Path(d).resolve(), out / name, settings) for name, d in zip(names, data_dirs)}
    results = {"settings": dataclasses.asdict(settings),
               "bounds": BOUNDS,
               "rooms": rooms, "provenance": provenance(seed=settings.seed)}
    write_json(out / RESULTS_JSON, results)
    write_text(out / RESULTS_MD, markdown_report(rooms, settings))
    plot_budget(budget_points(rooms), out / PLOT, title="Gaussian budget: default vs budget strategy")
    return results


# Figures of a run that the summary over seeds gives as mean / min / max.
SEED_FIGURES = ("gaussians", "train_seconds", "relit_fps", "psnr", "psnr_aligned")


def _spread(values: list[float | None]) -> dict[str, float | None]:
    """Mean, min and max over seeds; None for each when a seed's value is unknown (a resumed run's time)."""
    if any(v is None for v in values):
        return {"mean": None, "min": None, "max": None}
    return {"mean": sum(values) / len(values), "min": min(values), "max": max(values)}


def aggregate_seeds(per_seed: dict[int, dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """Summary of :func:`run_selection_benchmark`'s results over seeds, per room.

    Args:
        per_seed: seed -> that seed's results (the same rooms in each).
    Returns:
        room -> ``choices`` (seed -> chosen candidate), ``runs`` (run key -> figure -> mean / min / max over the
        seeds, figures of :data:`SEED_FIGURES`), ``deltas`` (``selection_db``, ``budget_db``, ``budget_reduction_pct``:
        one value per seed, in seed order) and ``verdicts`` (:func:`selection_verdict` / :func:`budget_verdict` on
        the means).
    """
    if not per_seed:
        raise ValueError("aggregate_seeds: no seeds")
    seeds = sorted(per_seed)
    room_sets = {s: set(per_seed[s]["rooms"]) for s in seeds}
    if len({frozenset(r) for r in room_sets.values()}) != 1:
        raise ValueError(f"aggregate_seeds: the seeds measured different rooms: {room_sets}")
    summary: dict[str, dict[str, Any]] = {}
    for name in per_seed[seeds[0]]["rooms"]:
        rooms = [per_seed[s]["rooms"][name] for s in seeds]
        runs = {key: {f: _spread([None if r["runs"][key][f] is None else float(r["runs"][key][f]) for r in rooms])
                      for f in SEED_FIGURES}
                for key in RUN_FOLDERS}
        tolerance = rooms[0]["selection"]["tolerance_db"]
        mean = {key: {f: runs[key][f]["mean"] for f in SEED_FIGURES} for key in runs}
        summary[name] = {
            "choices": {str(s): r["selection"]["chosen"] for s, r in zip(seeds, rooms)},
            "runs": runs,
            "deltas": {
                "selection_db": [r["verdicts"]["selection"]["delta_db"] for r in rooms],
                "budget_db": [r["verdicts"]["budget"]["delta_db"] for r in rooms],
                "budget_reduction_pct": [r["verdicts"]["budget"]["reduction_pct"] for r in rooms]},
            "verdicts": {
                "selection": selection_verdict(mean["chosen"]["psnr_aligned"], mean["spotless"]["psnr_aligned"],
                                               tolerance),
                "budget": budget_verdict(max(1, round(mean["spotless"]["gaussians"])),
                                         max(1, round(mean["budget"]["gaussians"])),
                                         mean["spotless"]["psnr_aligned"], mean["budget"]["psnr_aligned"])}}
    return summary


def seeds_markdown(summary: dict[str, dict[str, Any]], settings: BenchmarkSettings, seeds: list[int]) -> str:
    """Per room: every seed's choice, a table of mean [min, max] per run, the per-seed deltas and the verdicts on
    the means."""
    def cell(spread, spec):
        if spread["mean"] is None:  # a seed's value is unknown
            return "–"
        return f"{format(spread['mean'], spec)} [{format(spread['min'], spec)}, {format(spread['max'], spec)}]"

    lines = [f"Preset {settings.preset}, iterations {settings.iterations or 'of the preset'}, "
             f"{settings.threads} thread(s), seeds {', '.join(map(str, seeds))}: mean [min, max] over the seeds. "
             "Relit PSNR of the test views against the ground truth; aligned = after one exposure gain. Relit FPS "
             "over every view. Each seed's own report: seed-<s>/selection_benchmark.md.", ""]
    for name, room in summary.items():
        choices = ", ".join(f"seed {s}: {c}" for s, c in room["choices"].items())
        deltas = room["deltas"]
        lines += [f"## {name}", "", f"Chosen: {choices}.", "",
                  "| run | Gaussians | train s | relit PSNR aligned | relit FPS |", "|---|---|---|---|---|"]
        for key, r in room["runs"].items():
            lines.append(f"| {key} | {cell(r['gaussians'], '.0f')} | {cell(r['train_seconds'], '.1f')} | "
                         f"{cell(r['psnr_aligned'], '.2f')} | {cell(r['relit_fps'], '.1f')} |")
        lines += ["", "Per seed: choice vs spotless " + " / ".join(_signed(d, ".2f") for d in deltas["selection_db"])
                  + " dB; budget " + " / ".join(_signed(d, ".2f") for d in deltas["budget_db"]) + " dB at "
                  + " / ".join(_signed(-d, ".1f") for d in deltas["budget_reduction_pct"]) + "% Gaussians.", "",
                  "On the means:"]
        lines += [f"- {v}" for v in verdict_lines(room["verdicts"]["selection"], room["verdicts"]["budget"])]
        lines.append("")
    return "\n".join(lines)


def seed_budget_points(summary: dict[str, dict[str, Any]]) -> list:
    """BudgetPoints of the mean default and budget SpotlessGS run of every room (PSNR range over the seeds)."""
    points = []
    for name, room in summary.items():
        for strategy, key in (("default", "spotless"), ("budget", "budget")):
            r = room["runs"][key]
            points.append(BudgetPoint(name, strategy, max(1, round(r["gaussians"]["mean"])),
                                      r["psnr_aligned"]["mean"], r["relit_fps"]["mean"],
                                      psnr_range=(r["psnr_aligned"]["min"], r["psnr_aligned"]["max"])))
    return points


def run_seeds(data_dirs: list[Path], out: Path, settings: BenchmarkSettings, seeds: list[int]) -> dict[str, Any]:
    """:func:`run_selection_benchmark` for each seed; one seed writes to ``out`` itself, several to
    ``out/seed-<s>/`` plus the summary (:func:`aggregate_seeds`) in ``out``'s ``selection_benchmark.json`` / ``.md``
    and ``budget.png``.

    Returns the single seed's results, or ``settings``, ``seeds``, ``bounds``, ``rooms`` (the summary) and
    ``provenance``.
    """
    if not seeds:
        raise ValueError("run_seeds: no seeds given")
    if len(set(seeds)) != len(seeds):
        raise ValueError(f"run_seeds: a seed is given twice: {list(seeds)}")
    if len(seeds) == 1:
        return run_selection_benchmark(data_dirs, out, dataclasses.replace(settings, seed=seeds[0]))
    per_seed = {s: run_selection_benchmark(data_dirs, out / f"seed-{s}", dataclasses.replace(settings, seed=s))
                for s in seeds}
    summary = aggregate_seeds(per_seed)
    results = {"settings": {**dataclasses.asdict(settings), "seed": None}, "seeds": sorted(seeds),
               "bounds": BOUNDS,
               "rooms": summary, "provenance": provenance(seeds=sorted(seeds))}
    write_json(out / RESULTS_JSON, results)
    write_text(out / RESULTS_MD, seeds_markdown(summary, settings, sorted(seeds)))
    plot_budget(seed_budget_points(summary), out / PLOT,
                title=f"Gaussian budget: default vs budget strategy (mean of {len(seeds)} seeds)")
    return results
