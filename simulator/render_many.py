"""Render many rooms and variants as one resumable job (``spotless-sim render-many``), on this machine or on a Ray
cluster (bpy-free orchestration: every render runs :func:`simulator.render_pipeline.render_dataset`).

Each dataset ``ROOT/<room>-<variant>/`` is split into ranges of ``frames_per_task`` frames: one task renders a range
(``render/<dataset>/frames-A-B``), and one more (``finish/<dataset>``) writes the dataset-level files (point cloud,
COLMAP model, ``transforms.json``) once every range is done. The tasks form a :class:`spotlessgs.jobs.StageGraph`
with its done-markers under ``ROOT/.stages/``; a rerun skips what is done, and a range that was interrupted resumes
from its finished frames. ``ROOT/render_many.json`` summarises what was rendered, skipped and failed (with each
failure's error).
"""

from __future__ import annotations

import glob
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable, Sequence

from simulator.render_pipeline import (ExecutionOptions, RenderConfig, check_plan_settings, frame_done,
                                       render_dataset)
from simulator.trajectory import PATHS
from spotlessgs.io.atomic import write_json
from spotlessgs.io.errors import InputError
from spotlessgs.io.folder_lock import folder_lock
from spotlessgs.jobs import ExecutorSpec, Stage, StageGraph, StageResources, execute
from spotlessgs.jobs.graph import is_done

SUMMARY_FILE = "render_many.json"
TASKS = "simulator.render_many"
#: RenderConfig fields that render-many's settings may set (besides the variant, which picks the spotlight preset).
SETTING_FIELDS = ("frames", "width", "height", "samples", "seed", "h_fov_deg", "max_bounces", "denoise", "uniform_gt")
# Expected peak memory of one render task (Blender with a room and its EXRs), declared to the Ray scheduler: the
# 64x48 test renders peaked at about 0.5 GiB, the quick reproduction's 160x120 ones below 1 GiB.
RENDER_MEMORY_MB = 2048


@dataclass(frozen=True)
class RenderJob:
    """One dataset of the job: a room's house file rendered with one spotlight preset into ``out_dir``."""

    scene_file: Path
    variant: str
    out_dir: Path

    @property
    def name(self) -> str:
        """The dataset's folder name, ``<room>-<variant>``."""
        return self.out_dir.name


def scene_name(scene_file: Path) -> str:
    """A room's name: its file's stem, or its folder's name for a ``house.json`` (the shipped rooms' layout)."""
    return scene_file.parent.name if scene_file.stem == "house" else scene_file.stem


def find_scenes(patterns: Iterable[str], _lists: tuple[Path, ...] = ()) -> list[Path]:
    """The house files that ``patterns`` name: a glob (``scenes/*/house.json``), a file, a comma-separated list of
    either, or a ``.txt`` file with one per line (relative paths from the list's folder; ``#`` starts a comment;
    ``_lists``: the list files being read, which a list may not name again).

    Raises:
        InputError: a pattern that matches nothing, a path that is not a file, a list that is not UTF-8 text or
            names itself through other lists (named).
    """
    found: list[Path] = []
    for value in patterns:
        for pattern in (p.strip() for p in str(value).split(",")):
            if not pattern:
                continue
            path = Path(pattern)
            if path.suffix == ".txt" and path.is_file():
                if path.resolve() in _lists:
                    raise InputError(f"{path}: the scene list names itself (through {_lists[-1]})")
                try:
                    text = path.read_text(encoding="utf-8")
                except UnicodeDecodeError as exc:
                    raise InputError(f"{path}: the scene list is not UTF-8 text ({exc.reason} at byte "
                                     f"{exc.start})") from None
                lines = [line.split("#", 1)[0].strip() for line in text.splitlines()]
                entries = [str((path.parent / line) if not Path(line).is_absolute() else Path(line))
                           for line in lines if line]
                if not entries:
                    raise InputError(f"{path}: the scene list names no house file")
                found += find_scenes(entries, (*_lists, path.resolve()))
            elif glob.has_magic(pattern):
                matches = sorted(Path(m) for m in glob.glob(pattern, recursive=True) if Path(m).is_file())
                if not matches:
                    raise InputError(f"{pattern}: no house file matches this pattern")
                found += matches
            elif path.is_file():
                found.append(path)
            else:
                raise InputError(f"{path}: no such house file")
    unique = list(dict.fromkeys(p.resolve() for p in found))
    if not unique:
        raise InputError("no house file given (--scenes)")
    return unique


def plan_jobs(scene_files: Sequence[Path], variants: Sequence[str], root: Path) -> list[RenderJob]:
    """One job per scene and variant, ``root/<room>-<variant>`` (InputError when two rooms share a name)."""
    names: dict[str, Path] = {}
    for scene in scene_files:
        other = names.setdefault(scene_name(scene), scene)
        if other != scene:
            raise InputError(f"{scene}: its room name {scene_name(scene)!r} is also that of {other}; rename one of "
                             "the files or render them into different --out folders")
    return [RenderJob(scene, variant, Path(root) / f"{scene_name(scene)}-{variant}")
            for scene in scene_files for variant in variants]


def render_config(variant: str, settings: dict[str, Any]) -> RenderConfig:
    """The RenderConfig of a dataset: the variant's spotlight preset with ``settings`` (SETTING_FIELDS and ``path``,
    the camera path's name)."""
    settings = dict(settings)
    path = settings.pop("path", "paper")
    unknown = set(settings) - set(SETTING_FIELDS)
    if unknown:
        raise ValueError(f"unknown render setting(s) {sorted(unknown)}; allowed: {list(SETTING_FIELDS) + ['path']}")
    if path not in PATHS:
        raise ValueError(f"unknown camera path {path!r}; choose one of {sorted(PATHS)}")
    return RenderConfig.from_preset(variant, trajectory=PATHS[path], **settings)


def frame_ranges(frames: int, per_task: int) -> list[tuple[int, int]]:
    """``[start, stop)`` ranges of at most ``per_task`` consecutive frames covering ``0 .. frames - 1``."""
    if frames < 1 or per_task < 1:
        raise ValueError(f"frames and frames per task must be at least 1, got {frames} and {per_task}")
    return [(start, min(start + per_task, frames)) for start in range(0, frames, per_task)]


def build_render_graph(jobs: Sequence[RenderJob], settings: dict[str, Any], frames_per_task: int) -> StageGraph:
    """The tasks of ``jobs``: every frame range of every dataset, then one ``finish`` task per dataset."""
    frames = render_config("uneven", settings).frames
    stages: list[Stage] = []
    for job in jobs:
        common = {"scene_file": str(job.scene_file), "out_dir": str(job.out_dir), "variant": job.variant,
                  "settings": dict(settings)}
        ranges = [Stage(f"render/{job.name}/frames-{start}-{stop}", f"{TASKS}:render_frames",
                        kwargs={**common, "frame_range": [start, stop]}, output=job.out_dir, clean_on_retry=False,
                        resources=StageResources(memory_mb=RENDER_MEMORY_MB))
                  for start, stop in frame_ranges(frames, frames_per_task)]
        stages += ranges
        stages.append(Stage(f"finish/{job.name}", f"{TASKS}:finish_dataset", kwargs=common,
                            deps=tuple(s.name for s in ranges), output=job.out_dir, clean_on_retry=False,
                            resources=StageResources(memory_mb=RENDER_MEMORY_MB)))
    return StageGraph(stages)


# ---------------------------------------------------------------------------------------------------------------------
# The tasks (module level: the executors' workers import them)


def render_frames(scene_file: str, out_dir: str, variant: str, settings: dict[str, Any], frame_range: Sequence[int],
                  threads: int) -> dict[str, Any]:
    """Render (or resume) the frames ``frame_range`` of one dataset; returns render_dataset's summary."""
    execution = ExecutionOptions(frame_range=(int(frame_range[0]), int(frame_range[1])), threads=threads,
                                 progress=False, quiet=True)
    return render_dataset(scene_file, out_dir, render_config(variant, settings), execution=execution)


def finish_dataset(scene_file: str, out_dir: str, variant: str, settings: dict[str, Any],
                   threads: int) -> dict[str, Any]:
    """Write the dataset-level files once every frame exists (a whole-dataset render_dataset call, which renders any
    frame still missing first); RuntimeError when the dataset is still incomplete afterwards."""
    execution = ExecutionOptions(threads=threads, progress=False, quiet=True)
    summary = render_dataset(scene_file, out_dir, render_config(variant, settings), execution=execution)
    if not summary["complete"] or not (Path(out_dir) / "transforms.json").is_file():
        raise RuntimeError(f"{out_dir}: the dataset is incomplete after its last task: {summary}")
    return summary


# ---------------------------------------------------------------------------------------------------------------------
# The job


def frames_done(job: RenderJob, frames: int, uniform_gt: bool = False) -> int:
    """How many of a dataset's ``frames`` frames are on disk (``uniform_gt``: with the uniform ground truth)."""
    return sum(frame_done(job.out_dir, k, uniform_gt) for k in range(frames)) if job.out_dir.is_dir() else 0


def render_many(scene_files: Sequence[Path], variants: Sequence[str], root: str | Path, settings: dict[str, Any],
                frames_per_task: int = 20, executor: ExecutorSpec = ExecutorSpec(),
                progress: bool = True) -> dict[str, Any]:
    """Render (or resume) every variant of every room into ``root`` with ``executor``; write and return the summary
    (``ROOT/render_many.json``): per dataset its frames done before, rendered now and in all, whether it is complete,
    and every failed task with its error. A failed task does not stop the others; the datasets it belongs to stay
    incomplete (rerun to retry them).

    Raises:
        InputError: bad scene names (see :func:`plan_jobs`), or settings; FolderLockedError: another render-many
        writes ``root``; ImportError / ConnectionError: the Ray executor without Ray or without a cluster.
    """
    from tqdm import tqdm

    root = Path(root)
    if executor.kind == "ray":  # a Ray worker resolves a relative path in its node's working directory, not this one
        root, scene_files = root.resolve(), [Path(p).resolve() for p in scene_files]
    if frames_per_task < 1:
        raise InputError(f"--frames-per-task must be at least 1, got {frames_per_task}")
    try:
        base = render_config(variants[0] if variants else "uneven", settings)
        frames, uniform_gt = base.frames, base.uniform_gt
    except ValueError as exc:
        raise InputError(str(exc)) from exc
    jobs = plan_jobs(scene_files, variants, root)
    for job in jobs:  # a dataset of other settings is refused before any task runs (a rerun skips finished tasks)
        check_plan_settings(job.out_dir, job.scene_file, render_config(job.variant, settings))
    graph = build_render_graph(jobs, settings, frames_per_task)
    executor.check()  # a cluster that is not there is said before anything is written
    root.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    with folder_lock(root, "spotless-sim render-many"):
        before = {job.name: frames_done(job, frames, uniform_gt) for job in jobs}
        bar = tqdm(total=frames * len(jobs), initial=sum(before.values()), desc="render-many", unit="frame",
                   disable=not progress)

        def on_done(name: str, summary: dict | None) -> None:
            if summary is not None and name.startswith("render/"):
                bar.update(int(summary["result"].get("rendered", 0)))

        try:
            report = execute(graph, root, executor, on_done=on_done, raise_on_failure=False)
        finally:
            bar.close()
        summary = _summary(jobs, graph, root, frames, before, report, time.perf_counter() - start, uniform_gt)
        summary["executor"] = {"kind": executor.kind, "threads_per_task": executor.stage_threads(),
                               "frames_per_task": frames_per_task}
        write_json(root / SUMMARY_FILE, summary)
    return summary


def _summary(jobs: Sequence[RenderJob], graph: StageGraph, root: Path, frames: int, before: dict[str, int],
             report, seconds: float, uniform_gt: bool = False) -> dict[str, Any]:
    """The job's summary: per dataset its frames done before and after, whether it is complete, its failures."""
    datasets = []
    for job in jobs:
        done = frames_done(job, frames, uniform_gt)
        own = [name for name in graph.order if name.split("/")[1] == job.name]
        datasets.append({
            "dataset": job.name, "scene_file": str(job.scene_file), "variant": job.variant, "frames": frames,
            "done_before": before[job.name], "rendered_now": done - before[job.name], "done": done,
            "complete": is_done(root, f"finish/{job.name}") and (job.out_dir / "transforms.json").is_file(),
            "failed": {name: report.failed[name] for name in own if name in report.failed},
            "blocked": [name for name in own if name in report.blocked],
        })
    return {"datasets": datasets, "seconds": seconds, "tasks_run": len(report.ran), "tasks_skipped":
            len(report.skipped), "failed": dict(report.failed), "blocked": list(report.blocked),
            "complete": all(d["complete"] for d in datasets)}
