"""Run folders and checkpoints: written atomically, loaded with clear errors.

Run folder layout::

    RUN/run.json            data_dir, model variant, seed, preset (what ``spotless eval RUN`` reads)
    RUN/config.json         the resolved TrainConfig and model config, provenance
    RUN/metrics.jsonl       one JSON object per logged step
    RUN/checkpoints/last.pt the latest checkpoint (atomic; a crash never leaves a half-written one)
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import torch

from spotlessgs.io.atomic import atomic_path

CHECKPOINT_VERSION = 1


def checkpoint_path(run_dir: Path) -> Path:
    """Where the latest checkpoint of a run lives."""
    return Path(run_dir) / "checkpoints" / "last.pt"


def save_checkpoint(run_dir: Path, payload: dict[str, Any]) -> Path:
    """Write ``payload`` (tensors, state dicts, plain data) as the run's latest checkpoint, atomically."""
    path = checkpoint_path(run_dir)
    with atomic_path(path) as tmp:
        torch.save({"version": CHECKPOINT_VERSION, **payload}, tmp)
    return path


def load_checkpoint(run_dir: Path) -> dict[str, Any]:
    """Read the run's latest checkpoint (CPU tensors)."""
    path = checkpoint_path(run_dir)
    if not path.is_file():
        raise FileNotFoundError(f"{run_dir}: no checkpoint at {path} (train first with `spotless train`)")
    try:
        data = torch.load(path, map_location="cpu", weights_only=False)
    except Exception as exc:  # torch raises several types for corrupt files
        raise RuntimeError(f"{path}: cannot read checkpoint ({exc})") from None
    if data.get("version") != CHECKPOINT_VERSION:
        raise RuntimeError(f"{path}: checkpoint version {data.get('version')} is not {CHECKPOINT_VERSION}")
    return data


def read_run_info(run_dir: Path) -> dict[str, Any]:
    """The run's ``run.json``."""
    path = Path(run_dir) / "run.json"
    if not path.is_file():
        raise FileNotFoundError(f"{run_dir}: not a training run (no run.json)")
    return json.loads(path.read_text())


def truncate_metrics(path: Path, last_step: int) -> None:
    """Drop metric lines after ``last_step`` (when resuming from a checkpoint taken at that step)."""
    if not path.is_file():
        return
    keep = []
    for line in path.read_text().splitlines():
        try:
            if json.loads(line).get("step", -1) <= last_step:
                keep.append(line)
        except json.JSONDecodeError:
            continue  # a line cut by a crash
    from spotlessgs.io.atomic import write_text

    write_text(path, "".join(f"{line}\n" for line in keep))
