"""Collect the finished stages of a reproduction folder into ``results.json``, ``REPORT.md`` and ``figures/``."""

from __future__ import annotations

import os
import platform
from pathlib import Path
from typing import Any

from evaluation.dataset import read_dataset
from spotlessgs.io.atomic import PARTIAL_MARK, write_json, write_text
from spotlessgs.io.json_files import read_json
from spotlessgs.io.provenance import provenance
from spotlessgs.experiments.reproduce import paper
from spotlessgs.experiments.reproduce.config import (
    CEILING_STAGE, INPUTS_STAGE, NOISY_VARIANT, RESIDUAL_VARIANT, RGBD_VARIANT, ROBOT_VARIANT, ReproduceConfig,
    dataset_id,
    train_stage,
)
from spotlessgs.experiments.reproduce.figures import qualitative_grid, speed_error_plot
from spotlessgs.jobs.graph import MARKER_DIR, read_marker
from spotlessgs.experiments.reproduce.tables import Agreement, Table, agreement_notes, all_tables
from spotlessgs.training.selection import run_decisions

RESULTS_FILE = "results.json"
REPORT_FILE = "REPORT.md"


def load_config(out: Path) -> ReproduceConfig:
    """The config recorded in ``OUT/reproduce.json`` (FileNotFoundError naming it when absent)."""
    path = Path(out) / "reproduce.json"
    if not path.is_file():
        raise FileNotFoundError(f"{path}: not a reproduction folder (reproduce.json missing)")
    raw = read_json(path, "the reproduction's settings", ("scenes_dir",))
    tuples = {k: tuple(v) for k, v in raw.items() if isinstance(v, list)}
    return ReproduceConfig(**{**raw, **tuples, "scenes_dir": Path(raw["scenes_dir"])})


def collect(out: Path, config: ReproduceConfig) -> dict[str, Any]:
    """Every finished stage's summary, arranged per dataset (the structure documented in :mod:`tables`), with what
    each 3D run needed (``decisions``: spotlessgs.training.selection.run_decisions of its run folder) and the uneven
    inputs' scores (``input``) from the dataset's ``eval-inputs`` stage.

    Raises:
        FileNotFoundError: a stage the report needs has not finished (named).
    """
    collected: dict[str, Any] = {"datasets": {}, "cyclegan": None}
    if "cyclegan" in config.baselines:
        collected["cyclegan"] = read_marker(out, "cyclegan/train")["result"] | {
            "stage_seconds": read_marker(out, "cyclegan/train")["seconds"]}
    rendered = set(config.datasets())
    for room, variant in config.all_datasets():
        ds = dataset_id(room, variant)
        entry: dict[str, Any] = {"room": room, "variant": variant, "methods": {}, "baselines2d": {},
                                 "input": read_marker(out, f"{INPUTS_STAGE}/{ds}")["result"]["metrics"]}
        ceiling = read_marker(out, f"{CEILING_STAGE}/{ds}")["result"]
        entry.update(ceiling=ceiling.get("metrics", {}), ceiling_uniform=ceiling.get("uniform", {}))
        if variant == NOISY_VARIANT:
            entry["sensor_noise"] = read_marker(out, f"noise/{ds}")["result"]
        if variant in (ROBOT_VARIANT, RGBD_VARIANT):
            entry["robot_camera"] = read_marker(out, f"robot/{ds}")["result"]
        for method in config.methods_for(variant):
            marker = read_marker(out, f"train/{ds}/{method}")
            entry["methods"][method] = marker["result"]
            entry["methods"][method]["stage"] = {"seconds": marker["seconds"], "peak_rss_mb": marker["peak_rss_mb"]}
            entry["methods"][method]["decisions"] = run_decisions(out / "runs" / ds / method)
        if config.extra_seeds and (room, variant) in rendered:
            entry["seeds"] = {method: [_seed_result(out, ds, method, seed, config) for seed in config.seeds()]
                              for method in config.methods_for(variant)}
        if variant in config.baseline_variants:
            for method in config.baselines:
                entry["baselines2d"][method] = read_marker(out, f"baseline2d/{ds}/{method}")["result"]
        collected["datasets"][ds] = entry
    return collected


def _seed_result(out: Path, ds: str, method: str, seed: int, config: ReproduceConfig) -> dict[str, Any]:
    """One seed's run of ``method`` on ``ds``: {"seed", "metrics", "train"} from its training stage's marker."""
    result = read_marker(out, train_stage(ds, method, seed, config))["result"]
    return {"seed": seed, "metrics": result["metrics"], "train": result["train"]}


def _stage_markers(out: Path) -> dict[str, dict[str, Any]]:
    """The marker of every finished stage but the report's, by stage name."""
    markers = {}
    for path in sorted((Path(out) / MARKER_DIR).rglob("*.json")):
        name = str(path.relative_to(Path(out) / MARKER_DIR))[: -len(".json")]
        if name != "report" and PARTIAL_MARK not in path.name:
            markers[name] = read_marker(out, name)
    return markers


def _stage_times(out: Path) -> dict[str, float]:
    """Wall time of every finished stage (from the markers)."""
    return {name: float(marker.get("seconds", 0.0)) for name, marker in _stage_markers(out).items()}


def _machine_lines(out: Path) -> list[str]:
    """Where and with how many threads the stages ran (from the markers), with a warning when a resumed folder mixes
    thread counts or hosts: a run's numbers depend on its thread count, its times on its machine."""
    markers = _stage_markers(out).values()
    threads = sorted({m["threads"] for m in markers if isinstance(m.get("threads"), int)})
    hosts = sorted({str(m["host"]) for m in markers if m.get("host")})
    lines = [f"Threads per stage: {', '.join(map(str, threads)) or 'not recorded'}; host(s): "
             f"{', '.join(hosts) or 'not recorded'}; this report written on {platform.node()} "
             f"({os.cpu_count()} cores, {platform.machine()})."]
    if len(threads) > 1 or len(hosts) > 1:
        lines.append("**Mixed**: the stages ran with different thread counts or on different hosts (a resumed folder): "
                     "the numbers of runs made with different thread counts differ in their last digits, and their "
                     "times are not comparable.")
    return lines + [""]


def render_markdown(config: ReproduceConfig, tables: list[Table], notes: list[Agreement], figures: dict[str, str],
                    stage_times: dict[str, float], machine_lines: list[str] | None = None) -> str:
    """The text of REPORT.md (``machine_lines``: :func:`_machine_lines`, under the stage times)."""
    lines = [
        "# SpotlessGS reproduction report", "",
        f"Preset `{config.preset}`: rooms {', '.join(config.scenes)}; variants {', '.join(config.variants)}"
        + (f"; also {', '.join(config.extra_datasets)}" if config.extra_datasets else "")
        + (f" (residual: the room's lamps at {config.residual_light:g} of their power in the spotlit input)"
           if any(v == RESIDUAL_VARIANT for _, v in config.datasets()) else "")
        + f"; {config.frames} frames at {config.width}x{config.height}, {config.samples} samples; trainer preset "
        f"`{config.train_preset}`" + (f" with {config.train_iterations} iterations" if config.train_iterations else "")
        + (f"; Cycle-GAN preset `{config.cyclegan_preset}` trained on {', '.join(config.gan_rooms)}"
           if "cyclegan" in config.baselines else "")
        + f"; seed {config.seed}" + (f", training also with seeds {', '.join(map(str, config.extra_seeds))}"
                                     if config.extra_seeds else "") + "."
        + (f" Sensor-noise copies of the uneven datasets (`<room>-{NOISY_VARIANT}`, shot variance "
           f"{config.sensor_noise[0]:g}, read noise {config.sensor_noise[1]:g} in linear intensity; Table III's "
           f"robot-camera case, as the paper's SfM test is on a real camera): "
           f"{', '.join(config.noisy_methods)}." if config.sensor_noise is not None else "")
        + (f" Robot-camera copies (`<room>-{ROBOT_VARIANT}`: {config.robot_lens} lens "
           f"{list(config.robot_distortion)}, auto-exposure, vignetting, sensor noise {list(config.robot_noise)}, "
           f"sparse start triangulated on its images): {', '.join(config.robot_methods)}."
           if config.robot_camera else "")
        + (f" The same with an RGB-D camera (`<room>-{RGBD_VARIANT}`: depth σ = {config.robot_depth_noise:g} · z² m, "
           f"the start back-projected from its depth images): {', '.join(config.rgbd_methods)}."
           if config.rgbd_datasets() else ""),
        "",
        f"Paper figures are from the {paper.SOURCE} (Table III: its real-world sequence); they come from other data "
        "(and a GPU), so compare orderings, "
        "not values.", "",
        "## Agreement with the paper's ordering", "",
    ]
    icon = {"agrees": "agrees", "disagrees": "**DISAGREES**", "unknown": "cannot check"}
    for note in notes:
        lines.append(f"- {note.claim} — {icon[note.status]}. {note.text}")
    lines += ["", "## Tables", ""]
    for table in tables:
        lines.append(table.markdown())
    lines += ["## Figures", ""]
    for title, rel in figures.items():
        lines += [f"**{title}**", "", f"![{title}]({rel})", ""]
    total = sum(stage_times.values())
    lines += ["## Stage times", "", *(machine_lines or []),
              f"Sum of stage wall times: {total:.1f} s (stages run in parallel overlap).", "",
              "| Stage | Seconds |", "|---|---|"]
    lines += [f"| {name} | {sec:.1f} |" for name, sec in stage_times.items()]
    return "\n".join(lines) + "\n"


def write_report(out: Path) -> dict[str, Any]:
    """Write ``results.json``, ``REPORT.md`` and ``figures/*.png`` for a finished reproduction folder.

    Returns:
        {"report": path, "results": path, "figures": [paths]}.
    """
    out = Path(out)
    config = load_config(out)
    collected = collect(out, config)
    tables = all_tables(collected)
    notes = agreement_notes(collected)
    figures: dict[str, str] = {}
    for room, variant in config.all_datasets():
        ds = dataset_id(room, variant)
        data_dir = out / "datasets" / ds
        test_views = [f.name for f in read_dataset(data_dir).test_frames if f.gt_path is not None]
        rel = f"figures/qualitative_{ds}.png"
        columns = qualitative_grid(out / rel, data_dir, out / "runs" / ds, collected["datasets"][ds]["methods"],
                                   test_views, ceiling_dir=out / "ceiling" / ds)
        figures[f"Qualitative comparison, {ds} ({' / '.join(columns)})"] = rel
    speed_error_plot(out / "figures" / "speed_vs_error.png", collected)
    figures["Test PSNR (exposure-aligned) against training time; one point per curve milestone"] = \
        "figures/speed_vs_error.png"
    stage_times = _stage_times(out)
    results = {
        "preset": config.preset,
        "config": config.to_dict(),
        "datasets": collected["datasets"],
        "cyclegan": collected["cyclegan"],
        "tables": {t.key: t.to_dict() for t in tables},
        "agreement": [n.to_dict() for n in notes],
        "paper": {"source": paper.SOURCE, "table1": paper.TABLE1, "table2": paper.TABLE2, "table3": paper.TABLE3,
                  "table4": paper.TABLE4, "runtime": paper.RUNTIME, "runtime_source": paper.RUNTIME_SOURCE},
        "figures": sorted(figures.values()),
        "stage_seconds": stage_times,
        "provenance": provenance(seed=config.seed),
    }
    write_json(out / RESULTS_FILE, results)
    write_text(out / REPORT_FILE, render_markdown(config, tables, notes, figures, stage_times, _machine_lines(out)))
    return {"report": str(out / REPORT_FILE), "results": str(out / RESULTS_FILE),
            "figures": [str(out / f) for f in sorted(figures.values())]}

