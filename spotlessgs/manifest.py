"""Provenance manifests of derived output folders: which checkpoint, options and dataset made which files.

Every folder a command derives from a training run gets a manifest, ``FOLDER/.manifest.json`` (a hidden file, so that
image folders still hold images only): the relit images of ``spotless relight`` and the renders of ``spotless render``
(:func:`spotlessgs.rendering.render_run`) and the results of ``spotless eval`` (:mod:`evaluation.runner`). Before
scoring, ``spotless eval`` checks it (:func:`verify_frames`, :func:`checkpoint_identity`): images of another
checkpoint than the run's current one, edited frames, frames the manifest does not list, or a run's folder without a
manifest are refused with one line saying what to do.

The manifest is JSON written atomically (:func:`spotlessgs.io.atomic.write_json`), version ``schema_version`` 1::

    schema_version  1; a reader refuses other versions
    kind            "relit" (spotless relight), "render" (spotless render, the learned spotlight), "eval" (spotless
                    eval RUN) or "eval-folders" (spotless eval --pred --gt)
    created_utc     when the folder was finished (ISO 8601)
    run_dir         the run folder (absolute, at the time), or null
    checkpoint      the checkpoint the outputs came from, or null (no run or no checkpoint):
                      file    its path relative to the run folder (e.g. "checkpoints/last.safetensors")
                      step    the training step it holds
                      sha256  hash of the checkpoint file's content: a resumed training replaces it, so images of
                              an earlier checkpoint are recognised as stale
    options         what the command was asked and chose: relit/render: mode, views (test/train/all), l0 (the
                    linear RGB value used, null for 3dgs and spot renders), l0_mode (auto/lamp/given),
                    low_frequency_gain ("lamp" only: the learned low-frequency light's scale in the view), low_frequency,
                    exr, width, height; eval: the EvalConfig fields
    dataset         the dataset used: path (absolute), path_relative_to_run (or null), num_views (views of the
                    dataset), transforms_sha256 (hash of its transforms.json, null for COLMAP folders)
    frames          the files written, sorted by name: [{"name": "frame_00000.png", "sha256": "..."}, ...] (names
                    are relative to the folder, "/"-separated; relit/render folders hold every image and EXR file)
    scored          eval only: the folder scored and its manifest: {"folder", "manifest_sha256", "kind"} (or null)
    provenance      the command line, versions and time (spotlessgs.io.provenance)
"""

from __future__ import annotations

import datetime as _dt
import json
import os
from pathlib import Path
from typing import Any, Iterable, Mapping

from spotlessgs.io.atomic import to_jsonable, write_json
from spotlessgs.io.errors import InputError
from spotlessgs.io.json_files import read_json
from spotlessgs.io.provenance import provenance, sha256_file
from spotlessgs.training.checkpoint import existing_checkpoint, load_checkpoint

MANIFEST_NAME = ".manifest.json"
SCHEMA_VERSION = 1
KINDS = ("relit", "render", "eval", "eval-folders")
_COMMANDS = {"relit": "spotless relight", "render": "spotless render", "eval": "spotless eval",
             "eval-folders": "spotless eval"}
_REQUIRED = ("schema_version", "kind", "checkpoint", "options", "dataset", "frames")


def manifest_path(folder: str | os.PathLike) -> Path:
    """Where the manifest of ``folder`` lives."""
    return Path(folder) / MANIFEST_NAME


def current_checkpoint(run_dir: str | os.PathLike) -> Path | None:
    """The run's checkpoint file as the trainer finds it (an older version's ``last.pt`` too), or None."""
    return existing_checkpoint(run_dir)


def checkpoint_identity(run_dir: str | os.PathLike, step: int | None = None) -> dict[str, Any] | None:
    """``{"file", "step", "sha256"}`` of the run's current checkpoint (None when it has none).

    ``step`` is the step the caller already knows (it loaded the checkpoint); None reads it from the checkpoint.
    """
    path = current_checkpoint(run_dir)
    if path is None:
        return None
    if step is None:
        step = checkpoint_step(run_dir)
    return {"file": Path(os.path.relpath(path, run_dir)).as_posix(), "step": step, "sha256": sha256_file(path)}


def checkpoint_step(run_dir: str | os.PathLike) -> int | None:
    """The training step the run's checkpoint holds (None when it cannot be read). A safetensors checkpoint's step
    is read from its metadata alone (no tensors loaded); other files are loaded."""
    path = current_checkpoint(run_dir)
    if path is not None and path.suffix == ".safetensors":
        try:
            from safetensors import safe_open

            with safe_open(str(path), framework="pt", device="cpu") as fh:
                step = json.loads((fh.metadata() or {})["tree"])["step"]
            if isinstance(step, int):
                return step
        except Exception:  # noqa: BLE001 - any other layout: load the checkpoint below
            pass
    try:
        step = load_checkpoint(Path(run_dir)).get("step")
    except (OSError, ValueError, RuntimeError):
        return None
    return None if step is None else int(step)


def dataset_record(data_dir: str | os.PathLike, run_dir: str | os.PathLike | None, num_views: int) -> dict[str, Any]:
    """The ``dataset`` block of a manifest (see the module docstring)."""
    data = Path(data_dir).resolve()
    relative = None
    if run_dir is not None:
        try:
            relative = Path(os.path.relpath(data, Path(run_dir).resolve())).as_posix()
        except ValueError:  # another drive (Windows)
            relative = None
    transforms = data / "transforms.json"
    return {"path": str(data), "path_relative_to_run": relative, "num_views": int(num_views),
            "transforms_sha256": sha256_file(transforms) if transforms.is_file() else None}


def hash_frames(folder: str | os.PathLike, names: Iterable[str]) -> list[dict[str, str]]:
    """``[{"name", "sha256"}]`` of the files ``names`` (relative to ``folder``), sorted by name."""
    folder = Path(folder)
    return [{"name": n, "sha256": sha256_file(folder / n)} for n in sorted(set(names))]


def write_manifest(folder: str | os.PathLike, kind: str, *, run_dir: str | os.PathLike | None,
                   checkpoint: Mapping[str, Any] | None, options: Mapping[str, Any],
                   dataset: Mapping[str, Any] | None, frames: list[dict[str, str]],
                   scored: Mapping[str, Any] | None = None) -> Path:
    """Write ``FOLDER/.manifest.json`` atomically (fields: see the module docstring); returns its path."""
    if kind not in KINDS:
        raise ValueError(f"manifest kind must be one of {KINDS}, got {kind!r}")
    record: dict[str, Any] = {
        "schema_version": SCHEMA_VERSION,
        "kind": kind,
        "created_utc": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "run_dir": None if run_dir is None else str(Path(run_dir).resolve()),
        "checkpoint": None if checkpoint is None else dict(checkpoint),
        "options": dict(options),
        "dataset": None if dataset is None else dict(dataset),
        "frames": list(frames),
    }
    if kind.startswith("eval"):
        record["scored"] = None if scored is None else dict(scored)
    record["provenance"] = provenance()
    path = manifest_path(folder)
    write_json(path, to_jsonable(record))
    return path


def read_manifest(folder: str | os.PathLike) -> dict[str, Any] | None:
    """The manifest of ``folder``, or None when it has none.

    Raises:
        InputError: the manifest is not valid JSON, has another ``schema_version`` or lacks a field (named).
    """
    path = manifest_path(folder)
    if not path.is_file():
        return None
    try:
        record = read_json(path, "manifest")
    except InputError as exc:
        raise InputError(f"{exc}; write the folder again") from None
    if record.get("schema_version") != SCHEMA_VERSION:
        raise InputError(f"{path}: manifest schema_version {record.get('schema_version')!r} is not {SCHEMA_VERSION} "
                         "(written by another version of spotlessgs); write the folder again")
    missing = [k for k in _REQUIRED if k not in record]
    if missing or not isinstance(record["frames"], list):
        raise InputError(f"{path}: damaged manifest (missing {', '.join(missing) or 'frames list'}); "
                         "write the folder again")
    problem = _manifest_form_problem(record)
    if problem:
        raise InputError(f"{path}: damaged manifest ({problem}); write the folder again")
    return record


def _manifest_form_problem(record: dict[str, Any]) -> str | None:
    """What is of the wrong form in a manifest ``record`` that has every required field, or None: ``kind`` text,
    ``checkpoint``, ``options`` and ``dataset`` JSON objects (or null), each frame an object with a ``name`` inside
    the folder and a ``sha256`` text."""
    if not isinstance(record["kind"], str):
        return f"kind {record['kind']!r} is not text"
    for key in ("checkpoint", "options", "dataset"):
        if record[key] is not None and not isinstance(record[key], dict):
            return f"{key} is not a JSON object"
    for k, frame in enumerate(record["frames"]):
        if not isinstance(frame, dict) or not isinstance(frame.get("name"), str) \
                or not isinstance(frame.get("sha256"), str):
            return f"frames[{k}] is not an object with a name and a sha256"
        name = frame["name"]
        if not name or Path(name).is_absolute() or ".." in Path(name).parts:
            return f"frames[{k}] names {name!r}, not a file inside the folder"
    return None


def manifest_sha256(folder: str | os.PathLike) -> str:
    """Hex sha256 of ``folder``'s manifest file (what eval results record as the manifest they scored)."""
    return sha256_file(manifest_path(folder))


def folder_files(folder: str | os.PathLike) -> list[str]:
    """The names of the regular files directly in ``folder`` that are outputs: not hidden (the manifest, locks,
    temporary ``.partial-`` files), not folders."""
    return sorted(p.name for p in Path(folder).iterdir() if not p.name.startswith(".") and p.is_file())


def _short(names: list[str], limit: int = 3) -> str:
    return ", ".join(names[:limit]) + (f" (and {len(names) - limit} more)" if len(names) > limit else "")


def verify_frames(folder: str | os.PathLike, manifest: Mapping[str, Any], remedy: str) -> None:
    """Check that ``folder`` holds exactly the files its manifest lists, each with its recorded hash.

    Args:
        folder: the folder (its manifest is ``manifest``).
        manifest: :func:`read_manifest`'s record.
        remedy: what the user should do, appended to the message (e.g. "run `spotless relight RUN` again").

    Raises:
        InputError: naming the folder, the offending frames (not listed, missing, or changed since written) and the
            remedy.
    """
    folder = Path(folder)
    listed = {f["name"]: f["sha256"] for f in manifest["frames"]}
    present = set(folder_files(folder))
    top_level = {n for n in listed if "/" not in n}
    extra = sorted(present - top_level)
    if extra:
        command = _COMMANDS.get(manifest["kind"], manifest["kind"])
        raise InputError(f"{folder}: {len(extra)} file(s) not listed in its manifest (not written by the `{command}` "
                         f"it records): {_short(extra)}; {remedy}")
    absent = sorted(n for n in listed if not (folder / n).is_file())
    if absent:
        raise InputError(f"{folder}: {len(absent)} file(s) listed in its manifest are missing: {_short(absent)}; "
                         f"{remedy}")
    changed = sorted(n for n, digest in listed.items() if sha256_file(folder / n) != digest)
    if changed:
        raise InputError(f"{folder}: {len(changed)} file(s) changed since they were written (sha256 differs from "
                         f"the manifest): {_short(changed)}; {remedy}")
