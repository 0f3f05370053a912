"""A benchmark's finished run is reused only under the settings it was trained with.

The benchmarks keep each trained run in their output folder and skip it on a rerun. A rerun asked for other settings
(another seed, preset, ``--set``) must not report the old run as if it were the new one: :func:`refuse_other_settings`
compares what the run's ``config.json`` records (its resolved TrainConfig, completed for settings added since the run
as the trainer completes them on a resume, its model and seed) and the fingerprint of its dataset's files
(``run.json``) with a :class:`~spotlessgs.run.RunSpec` and its dataset, and names every difference.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

from spotlessgs.io.dataset import read_dataset
from spotlessgs.io.dataset_fingerprint import dataset_fingerprint, other_dataset
from spotlessgs.io.json_files import read_json
from spotlessgs.run import AUTO, RunSpec
from spotlessgs.training.checkpoint import recorded_data_fingerprint
from spotlessgs.training.config import TrainConfig
from spotlessgs.training.selection import chosen_model_train_config, proxy_light
from spotlessgs.training.trainer import differing_settings, differing_train_settings


def settings_differences(run_dir: Path, spec: RunSpec) -> list[str]:
    """``name: run X, now Y`` for each training setting, and the model (unless ``spec`` asks for ``auto``) and seed,
    in which the run in ``run_dir`` (its ``config.json``) differs from ``spec``, and ``dataset: ...`` when it was
    trained on other files than ``spec.data`` holds (:func:`dataset_difference`). An ``auto`` run is compared with
    the settings its chosen model trains with (:func:`~spotlessgs.training.selection.chosen_model_train_config`: its
    proxies' light model).

    Raises:
        InputError: ``config.json`` is missing or damaged (names the file).
    """
    saved = read_json(run_dir / "config.json", "run settings", ("train", "run"))
    old_run = saved["run"] if isinstance(saved["run"], dict) else {}
    # a `--model auto` run holds the model its selection chose (that selection compares its own settings on a resume)
    keys = ("seed",) if spec.model == AUTO else ("model", "seed")
    wanted = {"model": spec.model, "seed": spec.seed}
    wanted_train = spec.train_config()
    if spec.model == AUTO:
        wanted_train = _auto_train_config(wanted_train, Path(spec.data))
    return (differing_train_settings(saved["train"], dataclasses.asdict(wanted_train))
            + differing_settings({key: old_run.get(key) for key in keys}, {key: wanted[key] for key in keys})
            + dataset_difference(run_dir, spec.data))


def _auto_train_config(config: TrainConfig, data: Path) -> TrainConfig:
    """``config`` as an ``auto`` run's chosen model trains with it on the dataset ``data``; where ``data`` holds no
    dataset (a benchmark's own copy, removed), as on a start that is not trusted."""
    try:
        return chosen_model_train_config(config, data)
    except FileNotFoundError:
        return config.replace(**proxy_light(config, trusted=False))


def dataset_difference(run_dir: Path, data: Path) -> list[str]:
    """``["dataset: ..."]`` when the run in ``run_dir`` was trained on other files than the dataset ``data`` holds
    now (:mod:`spotlessgs.io.dataset_fingerprint`), else []; [] too for a run saved before fingerprints (no
    ``data_fingerprint`` in its run.json), which has nothing to compare, and where ``data`` is not there (a
    benchmark's own copy of a dataset, removed: the benchmark makes it again)."""
    recorded = recorded_data_fingerprint(run_dir)
    if recorded is None or not Path(data).exists() or not other_dataset(recorded,
                                                                       dataset_fingerprint(read_dataset(data))):
        return []
    return [f"dataset: trained on other files than {data} holds"]


def refuse_other_settings(run_dir: Path, spec: RunSpec, what: str = "the run") -> None:
    """Raise ValueError (``RUN: the run was trained with other settings (...); use a new --out``) when the run in
    ``run_dir`` was trained with other settings than ``spec``; ``what`` names it in the message."""
    differ = settings_differences(run_dir, spec)
    if differ:
        raise ValueError(f"{run_dir}: {what} was trained with other settings ({'; '.join(differ)}); use a new --out")


def check_finished_row(row_dir: Path, spec: RunSpec) -> None:
    """A benchmark row kept as ``row_dir/row.json`` beside its run ``row_dir/run``: refuse it (ValueError naming each
    difference) when its run was trained with other settings than ``spec``. A row without both files is not checked
    (an unfinished row resumes through the trainer, which compares the settings itself)."""
    if (row_dir / "row.json").is_file() and (row_dir / "run" / "config.json").is_file():
        refuse_other_settings(row_dir / "run", spec, "the row")
