"""What each robot-camera component costs per training step and buys in relit quality, in one table.

    spotless reproduce --preset quick --out out/quick --jobs 2
    spotless benchmark robot --ideal out/quick/datasets/bedroom-uneven --robot out/quick/datasets/bedroom-robot \\
        --out bench/robot --threads 2 [--set depth_spread=off]

One model (SpotlessGS by default) is trained once per row on the same robot-camera dataset (lens, auto-exposure,
vignetting, noise, a sparse start without normals), each row with one component switched off, and once on the ideal
input of the same room as the reference:

* ``ideal``: the ideal input (pinhole, fixed exposure, no noise, dense start with normals);
* ``robot``: every component on (the lens's working camera, the photometric camera, estimated normals, the sparse
  start's early densification);
* ``no-photometric``: the photometric camera off (no exposure, no vignetting);
* ``no-normals``: the SfM points' normals not estimated (the Gaussians start facing the camera);
* ``no-sparse-start``: densification from the preset's ``densify_from``, as for a dense start;
* ``lens-ignored``: the lens treated as a pinhole (a copy of the dataset with its distortion set to 0): what reading
  the lens buys, against what its larger working image costs per step.

Each row: training ms/step (wall clock, this machine: compare rows of one run), relit PSNR / SSIM of the test views
after one exposure gain (against the lamps-on ground truth, and the uniform one where the dataset has it), the relit
sequence's flicker and its flicker beyond the ground truths' (the brightness steps that what enters the view does not
explain), and the differences to ``robot``. Rows are resumable: a rerun skips trained rows (their run folders hold
the result) and trains the rest; a row trained under other settings (``--set``, seed, preset, ...) or on other files
(the dataset's fingerprint) is refused by name, before anything trains.
"""

from __future__ import annotations

import logging
import shutil
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from spotlessgs.io.atomic import write_json, write_text
from spotlessgs.io.dataset_fingerprint import dataset_fingerprint
from spotlessgs.io.json_files import read_json
from spotlessgs.io.paths import refuse_overlap
from spotlessgs.io.provenance import provenance

log = logging.getLogger(__name__)

#: Row name -> (dataset: "ideal" / "robot" / "lens-ignored", training overrides, what the row switches off).
ROWS: dict[str, tuple[str, tuple[tuple[str, Any], ...], str]] = {
    "ideal": ("ideal", (), "the ideal input: pinhole, fixed exposure, no noise, dense start with normals"),
    "robot": ("robot", (("photometric", "on"),), "every robot-camera component on"),
    "no-photometric": ("robot", (("photometric", "off"),), "photometric camera (exposure, vignetting)"),
    "no-normals": ("robot", (("photometric", "on"), ("estimate_normals", False)), "normals of the SfM points"),
    "no-sparse-start": ("robot", (("photometric", "on"), ("sparse_start", False)),
                        "early densification of a sparse start"),
    "lens-ignored": ("lens-ignored", (("photometric", "on"),), "the lens model (read as a pinhole)"),
}
RESULTS_JSON, RESULTS_MD = "robot_components.json", "robot_components.md"


#: The file in the lens-ignored copy that records which dataset (its fingerprint) it was made from.
SOURCE_RECORD = "lens_ignored_source.json"
#: The distortion fields of a transforms.json record (top level or per frame) that the lens-ignored copy sets to 0.
DISTORTION_KEYS = ("k1", "k2", "k3", "k4", "p1", "p2")


def lens_ignored_copy(robot: Path, out: Path) -> Path:
    """A copy of the dataset ``robot`` whose cameras have no distortion (what a tool that ignores the lens sees);
    made once, atomically (an interrupted copy is redone).

    Raises:
        ValueError: ``out`` holds a copy of another dataset (other frames or poses).
    """
    def frames(transforms: dict) -> list:
        return [{k: v for k, v in f.items() if k not in DISTORTION_KEYS} if isinstance(f, dict) else f
                for f in transforms["frames"]]

    from spotlessgs.io.dataset import read_dataset

    source = dataset_fingerprint(read_dataset(robot, check_files=True))  # also checks --robot (one line naming it)
    if (out / "transforms.json").is_file():
        made = read_json(out / "transforms.json", "lens-ignored copy", ("frames",))
        recorded = read_json(out / SOURCE_RECORD, "lens-ignored copy's source").get("fingerprint") \
            if (out / SOURCE_RECORD).is_file() else source  # copies made before 2026-12-07 record none
        if (frames(made) != frames(read_json(robot / "transforms.json", "robot dataset", ("frames",)))
                or recorded != source):
            raise ValueError(f"{out}: the lens-ignored copy was made from another dataset than {robot} (other frames, "
                             f"poses or images); use a new --out")
        return out
    partial = out.with_name(out.name + ".partial")
    shutil.rmtree(partial, ignore_errors=True)
    shutil.copytree(robot, partial)
    write_json(partial / SOURCE_RECORD, {"source": str(robot), "fingerprint": source})
    transforms = read_json(partial / "transforms.json", "robot dataset", ("frames",))
    for record in [transforms, *transforms["frames"]]:
        for key in DISTORTION_KEYS:
            if key in record:
                record[key] = 0.0
    write_json(partial / "transforms.json", transforms)
    partial.rename(out)
    return out


def row_spec(name: str, data: Path, model: str, preset: str, threads: int, seed: int, iterations: int | None,
             settings: Sequence[tuple[str, Any]] = ()):
    """The :class:`~spotlessgs.run.RunSpec` row ``name`` trains on ``data``: ``settings`` (TrainConfig (field,
    value) pairs for every row), then the row's own switches, which win over them."""
    from spotlessgs.run import RunSpec

    overrides = (("num_threads", threads), *settings, *ROWS[name][1])
    if iterations is not None:
        overrides += (("iterations", iterations),)
    return RunSpec(data=data, model=model, preset=preset, seed=seed, overrides=overrides)


def run_row(name: str, data: Path, out: Path, spec) -> dict[str, Any]:
    """Train row ``name`` (its :func:`row_spec` ``spec``) on ``data`` into ``out/name`` (resumed when interrupted),
    relight and score its test views; the row's result, also kept in ``out/name/row.json`` so that a rerun with the
    same settings skips it.

    Raises:
        ValueError: ``out/name`` holds a row trained with other settings
            (:func:`spotlessgs.experiments.run_settings.check_finished_row`).
    """
    from evaluation.runner import score_test_views
    from spotlessgs.experiments.run_settings import check_finished_row
    from spotlessgs.io.dataset import available_ground_truths, read_dataset
    from spotlessgs.run import train

    row_file = out / name / "row.json"
    if row_file.is_file():
        check_finished_row(out / name, spec)
        return read_json(row_file, "benchmark row")
    run = train(spec, out / name / "run", resume=(out / name / "run" / "run.json").is_file(), progress=False)
    threads = spec.train_config().num_threads
    scores = run.score_views(out / name / "relit", "all", threads)
    has_uniform = "uniform" in available_ground_truths(read_dataset(data))
    temporal = _flicker(out / name / "relit", data, has_uniform)
    row = {"row": name, "switched_off": ROWS[name][2], "data": str(data), "ms_per_step": run.summary["ms_per_step"],
           "gaussians": run.summary["num_gaussians"], "psnr_aligned": scores["psnr_aligned"],
           "ssim_aligned": scores["ssim_aligned"], "psnr": scores["psnr"], **temporal}
    if has_uniform:  # the same relit views against the even light
        uniform = score_test_views(data, out / name / "relit", threads, ground_truth="uniform")
        row.update(psnr_aligned_uniform=uniform["psnr_aligned"], ssim_aligned_uniform=uniform["ssim_aligned"])
    write_json(row_file, row)
    return row


def _flicker(relit: Path, data: Path, has_uniform: bool) -> dict[str, float]:
    """The relit sequence's and the ground truth's flicker (evaluation.temporal.sequence_flicker), and the relit
    sequence's flicker beyond each ground truth's (evaluation.temporal.excess_flicker: ``flicker_excess`` against the
    lamps-on one, ``flicker_excess_uniform`` against the uniform one when the dataset has it: ``has_uniform``)."""
    import torch

    from evaluation.dataset import read_dataset
    from evaluation.temporal import excess_flicker, sequence_flicker
    from spotlessgs.io.images import read_image

    def frames(paths):
        for path in paths:
            yield torch.from_numpy(read_image(path)).permute(2, 0, 1)

    views = read_dataset(data)
    relit_paths = [relit / f.name for f in views.frames]
    truth = [f.gt_path for f in views.frames]
    scores = {"flicker": sequence_flicker(frames(relit_paths)), "flicker_truth": sequence_flicker(frames(truth)),
              "flicker_excess": excess_flicker(frames(relit_paths), frames(truth))}
    if has_uniform:
        uniform = [f.gt_path for f in read_dataset(data, "uniform").frames]
        scores["flicker_excess_uniform"] = excess_flicker(frames(relit_paths), frames(uniform))
    return scores


def run_robot_benchmark(ideal: Path, robot: Path, out: Path, rows: Sequence[str] = tuple(ROWS), model: str = "spotless",
                        preset: str = "quick", threads: int = 1, seed: int = 0, iterations: int | None = None,
                        settings: Sequence[tuple[str, Any]] = ()) -> list[dict[str, Any]]:
    """Every row of :data:`ROWS` asked for, in order, each trained with the TrainConfig ``settings`` (field, value)
    besides its own switches; writes ``out/robot_components.json`` and ``.md``."""
    from evaluation.runner import require_ground_truth
    from spotlessgs.experiments.run_settings import check_finished_row

    unknown = [r for r in rows if r not in ROWS]
    if unknown:
        raise ValueError(f"unknown rows {unknown}; choose from {list(ROWS)}")
    refuse_overlap(out, {"--ideal": ideal, "--robot": robot}, "--out")  # a copy of --robot goes into --out
    given = {"ideal": ("--ideal", ideal), "robot": ("--robot", robot), "lens-ignored": ("--robot", robot)}
    for option, data in sorted({given[ROWS[name][0]] for name in rows}):  # before a row trains
        require_ground_truth(data, option)
    out.mkdir(parents=True, exist_ok=True)
    datasets = {"ideal": ideal, "robot": robot, "lens-ignored": out / "data-lens-ignored"}
    specs = {name: row_spec(name, datasets[ROWS[name][0]], model, preset, threads, seed, iterations, settings)
             for name in rows}
    for name, spec in specs.items():  # every finished row checked before any trains
        check_finished_row(out / name, spec)
    results = []
    for name in rows:
        data = lens_ignored_copy(robot, datasets["lens-ignored"]) if ROWS[name][0] == "lens-ignored" \
            else datasets[ROWS[name][0]]
        log.info("robot benchmark: row %s on %s", name, data)
        results.append(run_row(name, data, out, specs[name]))
    recorded = {"model": model, "preset": preset, "threads": threads, "seed": seed, "iterations": iterations,
                "set": [list(pair) for pair in settings], "ideal": str(ideal), "robot": str(robot)}
    write_json(out / RESULTS_JSON, {"settings": recorded, "rows": results, "provenance": provenance(seed=seed)})
    write_text(out / RESULTS_MD, markdown_table(results))
    return results


def markdown_table(rows: Sequence[dict[str, Any]]) -> str:
    """The rows as a Markdown table, each with its cost (ms/step) and what it buys (dB) against ``robot``."""
    full = next((r for r in rows if r["row"] == "robot"), None)
    lines = ["| row | switched off | ms / step | relit PSNR aligned (dB): lamps-on / uniform truth | SSIM aligned | "
             "flicker (truth) | "
             "flicker beyond the truth's: lamps-on / uniform | the component costs (ms / step) | and buys (dB) |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        cost = buys = "–"
        if full is not None and r["row"] not in ("robot", "ideal"):
            cost = f"{full['ms_per_step'] - r['ms_per_step']:+.1f}"
            buys = f"{full['psnr_aligned'] - r['psnr_aligned']:+.2f}"
        elif full is not None and r["row"] == "ideal":
            buys = f"{full['psnr_aligned'] - r['psnr_aligned']:+.2f} (robot − ideal)"
        excess = " / ".join("–" if r.get(key) is None else f"{r[key]:.3f}"  # rows of earlier versions lack them
                            for key in ("flicker_excess", "flicker_excess_uniform"))
        uniform = "–" if r.get("psnr_aligned_uniform") is None else f"{r['psnr_aligned_uniform']:.2f}"
        lines.append(f"| {r['row']} | {r['switched_off']} | {r['ms_per_step']:.1f} | {r['psnr_aligned']:.2f} / {uniform} | "
                     f"{r['ssim_aligned']:.3f} | {r['flicker']:.3f} ({r['flicker_truth']:.3f}) | {excess} | {cost} | "
                     f"{buys} |")
    return "\n".join(lines) + "\n"
