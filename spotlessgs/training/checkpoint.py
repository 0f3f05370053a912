"""Run folders and checkpoints: written atomically, loaded with clear errors.

Run folder layout::

    RUN/run.json            data_dir, model variant, seed, preset (what ``spotless eval RUN`` reads)
    RUN/config.json         the resolved TrainConfig and model config, provenance
    RUN/metrics.jsonl       one JSON object per logged step
    RUN/checkpoints/last.safetensors  the latest checkpoint (atomic; a crash never leaves a half-written one)

A checkpoint is a safetensors file (tensors) whose metadata holds the rest as JSON (:mod:`spotlessgs.io.tensor_file`):
loading one from a shared or downloaded run folder cannot run code. Runs of older versions have
``checkpoints/last.pt`` (a torch pickle); it is read with ``torch.load(weights_only=True)``, which only rebuilds
tensors and plain containers and refuses anything else with a clear message, and the next save replaces it.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any, Sequence

import torch

from spotlessgs.io.atomic import write_text
from spotlessgs.io.dataset import read_dataset
from spotlessgs.io.dataset_fingerprint import dataset_fingerprints, other_dataset
from spotlessgs.io.errors import InputError
from spotlessgs.io.json_files import read_json
from spotlessgs.io.tensor_file import load_plain_torch_file, load_tree, save_tree

CHECKPOINT_VERSION = 1
#: The ``format`` recorded in a checkpoint file's metadata.
CHECKPOINT_FORMAT = "spotlessgs-checkpoint"
#: Checkpoint file of runs written before the safetensors format (a torch pickle).
LEGACY_CHECKPOINT = Path("checkpoints") / "last.pt"


def checkpoint_path(run_dir: str | Path) -> Path:
    """Where the latest checkpoint of a run is written."""
    return Path(run_dir) / "checkpoints" / "last.safetensors"


def existing_checkpoint(run_dir: str | Path) -> Path | None:
    """The run's latest checkpoint file: the safetensors one, else an older version's ``last.pt``, else None."""
    for path in (checkpoint_path(run_dir), Path(run_dir) / LEGACY_CHECKPOINT):
        if path.is_file():
            return path
    return None


def save_checkpoint(run_dir: Path, payload: dict[str, Any]) -> Path:
    """Write ``payload`` (tensors, state dicts, plain data) as the run's latest checkpoint, atomically."""
    path = save_tree(checkpoint_path(run_dir), {"version": CHECKPOINT_VERSION, **payload}, CHECKPOINT_FORMAT)
    (Path(run_dir) / LEGACY_CHECKPOINT).unlink(missing_ok=True)  # an older version's file is superseded
    return path


def load_checkpoint(run_dir: Path) -> dict[str, Any]:
    """Read the run's latest checkpoint (CPU tensors); nothing in the file can run code."""
    path = existing_checkpoint(run_dir)
    if path is None:
        raise FileNotFoundError(f"{run_dir}: no checkpoint at {checkpoint_path(run_dir)} "
                                "(train first with `spotless train`)")
    data = load_tree(path, CHECKPOINT_FORMAT) if path.suffix == ".safetensors" else \
        load_plain_torch_file(path, "this older-format checkpoint")
    if not isinstance(data, dict) or data.get("version") != CHECKPOINT_VERSION:
        found = data.get("version") if isinstance(data, dict) else type(data).__name__
        raise InputError(f"{path}: checkpoint version {found} is not {CHECKPOINT_VERSION}")
    check_checkpoint(data, path)
    return data


def check_checkpoint(data: dict[str, Any], path: Path) -> None:
    """InputError naming ``path`` where a checkpoint ``data`` cannot be a model: ``gaussians`` and ``appearance``
    tables of tensors, the Gaussians' float32 tensors sharing one count N ≥ 1, every floating tensor finite, and
    ``step`` a whole number ≥ 0 (a damaged or hand-edited file; training never saves a non-finite model)."""
    for table in ("gaussians", "appearance"):
        values = data.get(table)
        if not isinstance(values, dict) or not all(isinstance(v, torch.Tensor) for v in values.values()):
            raise InputError(f"{path}: damaged checkpoint: '{table}' is not a table of tensors")
    counts = set()
    for name, tensor in data["gaussians"].items():
        if tensor.dtype != torch.float32 or tensor.ndim == 0:
            raise InputError(f"{path}: damaged checkpoint: gaussians.{name} is a {tensor.dtype} tensor of shape "
                             f"{tuple(tensor.shape)}, expected float32 with one row per Gaussian")
        counts.add(tensor.shape[0])
    if len(counts) != 1 or 0 in counts:
        raise InputError(f"{path}: damaged checkpoint: the Gaussians' tensors hold {sorted(counts)} rows, expected "
                         "one count of at least 1")
    for table in ("gaussians", "appearance"):
        for name, tensor in data[table].items():
            if tensor.is_floating_point() and not torch.isfinite(tensor).all():
                bad = int((~torch.isfinite(tensor)).sum())
                raise InputError(f"{path}: damaged checkpoint: {table}.{name} has {bad} value(s) that are not finite")
    step = data.get("step")
    if isinstance(step, torch.Tensor) and step.numel() == 1 and not step.is_floating_point():
        step = int(step)
    if not isinstance(step, int) or isinstance(step, bool) or step < 0:
        raise InputError(f"{path}: damaged checkpoint: step {step!r} is not a whole number of at least 0")


def _recorded_data_dirs(run_dir: Path, info: dict[str, Any]) -> list[Path]:
    """The folders run.json's ``data_dir_relative`` and ``data_dir`` name (resolved; the paths that are text)."""
    recorded = [info.get(key) for key in ("data_dir_relative", "data_dir")]
    return [(Path(v) if Path(v).is_absolute() else run_dir / v).resolve() for v in recorded if isinstance(v, str) and v]


def _check_views(run_dir: Path, info: dict[str, Any], data: Path, given: str | Path) -> None:
    """InputError where the dataset folder ``data`` (given as ``given``) holds other views than the run trained on:
    run.json's ``views_fingerprint`` where it has one (the start cloud may differ), else its ``data_fingerprint``;
    a run saved before fingerprints is not compared."""
    key = "views_fingerprint" if info.get("views_fingerprint") is not None else "data_fingerprint"
    if info.get(key) is None:
        return
    whole, views = dataset_fingerprints(read_dataset(data))
    if other_dataset(info[key], views if key == "views_fingerprint" else whole):
        raise InputError(f"{given}: --data holds other files than the run {run_dir} was trained on (another "
                         "dataset fingerprint); point --data at the run's own dataset")


def read_run_info(run_dir: Path, required: Sequence[str] = ()) -> dict[str, Any]:
    """The run's ``run.json`` (a JSON object).

    Args:
        run_dir: the run folder.
        required: keys the caller needs (e.g. ``("model", "seed")`` to rebuild the model).

    Raises:
        FileNotFoundError: the folder has no run.json.
        InputError: run.json is damaged (not a JSON object) or lacks a required key (names the file and the key).
    """
    path = Path(run_dir) / "run.json"
    if not path.is_file():
        raise FileNotFoundError(f"{run_dir}: not a training run (no run.json)")
    info = read_json(path, "run description", required)
    check_schema_version(path, info)
    return info


#: Version of the run folder's JSON files (run.json, config.json, train_summary.json, light.json, relit.json,
#: render.json, gaussian_budget.json: their ``schema_version``; docs/run.md). Files without one are version 0
#: (older runs: read as before). Raise it when a file's meaning changes; readers refuse newer versions.
RUN_SCHEMA_VERSION = 1


def recorded_data_fingerprint(run_dir: Path) -> str | None:
    """The fingerprint of the files the run in ``run_dir`` trained on (run.json's ``data_fingerprint``:
    :mod:`spotlessgs.io.dataset_fingerprint`); None for a run saved before fingerprints or without a run.json."""
    return read_run_info(run_dir).get("data_fingerprint") if (Path(run_dir) / "run.json").is_file() else None


def check_schema_version(path: Path, record: dict[str, Any]) -> None:
    """InputError naming ``path`` when ``record`` was written by a newer version of the run folder's files."""
    version = record.get("schema_version", 0)
    if not isinstance(version, int) or isinstance(version, bool) or version < 0:
        raise InputError(f"{path}: damaged file: schema_version {version!r} is not a version number")
    if version > RUN_SCHEMA_VERSION:
        raise InputError(f"{path}: written by a newer SpotlessGS (run schema version {version}; this version reads "
                         f"up to {RUN_SCHEMA_VERSION}): update SpotlessGS to read this run")


def data_dir_fields(data_dir: str | Path, run_dir: str | Path) -> dict[str, str | None]:
    """run.json's dataset fields: ``data_dir`` (absolute) and ``data_dir_relative`` (relative to the run folder, so
    that a run moved together with its dataset still finds it; None where no relative path exists)."""
    data = Path(data_dir).resolve()
    try:
        relative = Path(os.path.relpath(data, Path(run_dir).resolve())).as_posix()
    except ValueError:  # another drive (Windows)
        relative = None
    return {"data_dir": str(data), "data_dir_relative": relative}


def resolve_data_dir(run_dir: str | Path, info: dict[str, Any], override: str | Path | None = None) -> Path:
    """The dataset folder of a run: ``override`` (``--data``) when given, else run.json's path relative to the run
    folder (``data_dir_relative``), else its absolute ``data_dir`` (older runs have only that; a relative
    ``data_dir`` is taken relative to the run folder).

    Raises:
        InputError: ``override`` is not a folder or holds other files than the run was trained on (its dataset
            fingerprint differs from run.json's: :mod:`spotlessgs.io.dataset_fingerprint`), or neither recorded path
            is a folder (names the run and both paths and suggests ``--data``).
    """
    run_dir = Path(run_dir)
    if override is not None:
        if not Path(override).is_dir():
            raise InputError(f"{override}: --data is not a dataset folder (not found)")
        data = Path(override).resolve()
        if data not in _recorded_data_dirs(run_dir, info):  # the dataset moved: it must hold the run's own views
            _check_views(run_dir, info, data, override)
        return data
    tried: list[str] = []
    for key in ("data_dir_relative", "data_dir"):
        value = info.get(key)
        if not value:
            continue
        if not isinstance(value, str):
            raise InputError(f"{run_dir / 'run.json'}: damaged run description: {key} {value!r} is not a path")
        path = Path(value)
        path = path if path.is_absolute() else run_dir / path
        if path.is_dir():
            return path.resolve()
        tried.append(f"{key} {value!r} ({path})" if not Path(value).is_absolute() else f"{key} {value!r}")
    shown = f"not found at {' nor at '.join(tried)}" if tried else "not recorded (run.json has no data_dir)"
    raise InputError(f"{run_dir}: the run's dataset was {shown}; if the dataset moved, point at it with --data DIR")


def truncate_metrics(path: Path, last_step: int) -> None:
    """Drop metric lines after ``last_step`` (when resuming from a checkpoint taken at that step)."""
    if not path.is_file():
        return
    keep = []
    for line in path.read_text(encoding="utf-8", errors="replace").splitlines():
        try:
            record = json.loads(line)
        except (json.JSONDecodeError, RecursionError):
            continue  # a line cut by a crash
        step = record.get("step") if isinstance(record, dict) else None
        if isinstance(step, (int, float)) and not isinstance(step, bool) and step <= last_step:
            keep.append(line)  # a line that is not a step's record (hand-edited, damaged) is dropped with the rest
    write_text(path, "".join(f"{line}\n" for line in keep))
