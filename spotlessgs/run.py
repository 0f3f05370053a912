"""The library's entry point for a run: a frozen :class:`RunSpec`, one call :func:`train` that makes a run folder,
and :class:`Run`, which owns that folder (its summary, model-selection decision and light report) and relights,
renders and evaluates it.

    from spotlessgs.run import RunSpec, Run, train

    run = train(RunSpec(data="data/bedroom", model="auto", preset="quick", strategy="budget"), "runs/bedroom")
    run.relight()                  # RUN/relit: every view under even light
    scores = run.evaluate()        # RUN/eval/results.json
    Run.load("runs/bedroom").summary["num_gaussians"]

The CLI (``spotless train``), the reproduction and the benchmarks build their training configuration through
:meth:`RunSpec.train_config` and train through :func:`train`. The folder's files are listed in
docs/architecture.md ("The run folder").
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

from evaluation.runner import EvalConfig, evaluate_run, score_test_views
from spotlessgs.io.json_files import read_json
from spotlessgs.models.shading import MODEL_VARIANTS
from spotlessgs.rendering import render_run
from spotlessgs.training import trainer
from spotlessgs.training.checkpoint import check_schema_version, read_run_info, resolve_data_dir
from spotlessgs.training.config import PRESETS, STRATEGIES, TrainConfig, preset
from spotlessgs.training.pose_file import RefinedPoses, read_refined_poses
from spotlessgs.training.selection import SELECTION_FILE, SelectionConfig, train_auto

#: ``RunSpec.model``: a model variant, or ``auto`` (choose one from held-out training views, then train it).
AUTO = "auto"


@dataclass(frozen=True)
class RunSpec:
    """Everything that decides what a training run computes (a value: hashable, comparable, printable).

    Attributes:
        data: the dataset folder (ours, nerfstudio or COLMAP).
        model: a model variant (``spotlessgs.models.shading.MODEL_VARIANTS``) or ``auto``.
        preset: the training preset (``tiny``, ``quick``, ``paper``).
        strategy: the densification strategy (``default``, ``budget``: ``spotlessgs.training.config.STRATEGIES``).
        seed: the run's seed.
        overrides: TrainConfig fields that differ from the preset and strategy, as (name, value) pairs
            (e.g. ``(("iterations", 300), ("num_threads", 2))``; a field given twice keeps its last value);
            ``iterations`` scales the densification schedule.
        light_prior: prior light position in the camera frame (m, OpenCV axes), or None.
        selection: model selection's settings (``auto`` only; None: the defaults).
    """

    data: Path
    model: str = "spotless"
    preset: str = "quick"
    strategy: str = "default"
    seed: int = 0
    overrides: tuple[tuple[str, Any], ...] = ()
    light_prior: tuple[float, float, float] | None = None
    selection: SelectionConfig | None = field(default=None)

    def __post_init__(self) -> None:
        object.__setattr__(self, "data", Path(self.data))
        # a field given twice keeps its last value (a benchmark row's own switches win over its settings)
        object.__setattr__(self, "overrides", tuple((str(k), v) for k, v in dict(self.overrides).items()))
        if "preset" in dict(self.overrides):  # the schedule comes from RunSpec.preset; the field only records it
            raise ValueError("RunSpec: set the preset with RunSpec.preset (--preset), not as an override")
        if self.light_prior is not None:
            object.__setattr__(self, "light_prior", tuple(float(v) for v in self.light_prior))
            if len(self.light_prior) != 3:
                raise ValueError(f"RunSpec: light_prior needs 3 values (x, y, z), got {self.light_prior}")
        if self.model != AUTO and self.model not in MODEL_VARIANTS:
            raise ValueError(f"RunSpec: unknown model {self.model!r}; choose one of {[*MODEL_VARIANTS, AUTO]}")
        if self.preset not in PRESETS:
            raise ValueError(f"RunSpec: unknown preset {self.preset!r}; choose one of {sorted(PRESETS)}")
        if self.strategy not in STRATEGIES:
            raise ValueError(f"RunSpec: unknown strategy {self.strategy!r}; choose one of {sorted(STRATEGIES)}")
        if self.selection is not None and self.model != AUTO:
            raise ValueError("RunSpec: selection settings only apply to model 'auto'")
        unknown = sorted(set(dict(self.overrides)) - {f.name for f in dataclasses.fields(TrainConfig)})
        if unknown:
            raise ValueError(f"RunSpec: overrides name no TrainConfig field: {unknown}")

    def train_config(self) -> TrainConfig:
        """The training configuration: the preset, the strategy's fields, then the overrides."""
        return preset(self.preset, strategy=self.strategy, **dict(self.overrides))


def given_overrides(**fields: Any) -> tuple[tuple[str, Any], ...]:
    """``RunSpec.overrides`` of the fields that are not None: ``given_overrides(iterations=None, num_threads=2)`` is
    ``(("num_threads", 2),)``."""
    return tuple((name, value) for name, value in fields.items() if value is not None)


def train(spec: RunSpec, run_dir: str | Path, resume: bool = False, progress: bool = True,
          stop_after: int | None = None) -> Run:
    """Train (or, with ``resume``, continue) the run ``spec`` describes into ``run_dir``; for ``auto``, select the
    model first (``RUN/model_selection.json``). ``stop_after``: stop with a checkpoint after this many steps in all
    (as if interrupted; a later call with ``resume`` continues), e.g. to score the model on the way.

    Returns:
        the Run, with ``result``: what this call measured (steps, seconds of its training loop, ms per step, ...).
    Raises:
        FileExistsError: ``run_dir`` holds a run and ``resume`` is False; ValueError: ``resume`` with other settings;
        and what :func:`spotlessgs.training.trainer.train` raises.
    """
    config = spec.train_config()
    prior = list(spec.light_prior) if spec.light_prior is not None else None
    if spec.model == AUTO:
        _decision, result = train_auto(spec.data, run_dir, config, seed=spec.seed,
                                       selection=spec.selection or SelectionConfig(), light_prior=prior,
                                       resume=resume, progress=progress, stop_after=stop_after)
    else:
        result = trainer.train(spec.data, run_dir, spec.model, config, seed=spec.seed, resume=resume,
                               light_prior=prior, progress=progress, stop_after=stop_after)
    return dataclasses.replace(Run.load(run_dir), result=result)


@dataclass(frozen=True)
class Run:
    """A run folder made by :func:`train` (or ``spotless train``).

    Attributes:
        dir: the run folder.
        result: what the :func:`train` call that returned this Run measured; None from :meth:`load`.
    """

    dir: Path
    result: trainer.TrainResult | None = field(default=None, compare=False)

    @classmethod
    def load(cls, run_dir: str | Path) -> Run:
        """The run in ``run_dir``.

        Raises:
            FileNotFoundError: ``run_dir`` holds no ``run.json``; InputError: it is damaged (names the file).
        """
        run = cls(Path(run_dir))
        read_run_info(run.dir)
        return run

    @property
    def info(self) -> dict[str, Any]:
        """``run.json``: dataset paths, model, seed, preset, light prior (see docs/architecture.md)."""
        return read_run_info(self.dir)

    @property
    def config(self) -> TrainConfig:
        """The training configuration the run was made with (``config.json``)."""
        return trainer.saved_train_config(self.dir / "config.json")

    @property
    def model(self) -> str:
        """The trained model's name (for ``auto``: the chosen candidate's)."""
        return str(self.info["model"])

    @property
    def summary(self) -> dict[str, Any] | None:
        """``train_summary.json`` (steps, Gaussians, speed, reconstruction PSNR), or None while training is
        unfinished."""
        return self._optional("train_summary.json", "training summary")

    @property
    def decision(self) -> dict[str, Any] | None:
        """Model selection's decision (``model_selection.json``), or None when the model was given."""
        return self._optional(SELECTION_FILE, "model selection decision")

    @property
    def light(self) -> dict[str, Any] | None:
        """The learned light against the dataset's true light (``light.json``), or None before training ends."""
        return self._optional("light.json", "light report")

    @property
    def poses(self) -> RefinedPoses | None:
        """The refined camera poses (``poses.json``) of a run trained with ``refine_poses``, or None (see
        :mod:`spotlessgs.training.pose_file`)."""
        return read_refined_poses(self.dir)

    @property
    def finished(self) -> bool:
        return self.summary is not None

    @property
    def data_dir(self) -> Path:
        """The run's dataset folder (run.json's relative path, else its absolute one).

        Raises:
            InputError: neither is a folder (the dataset moved: pass ``data_dir`` to the methods below).
        """
        return resolve_data_dir(self.dir, self.info)

    def relight(self, which: str = "all", out_dir: str | Path | None = None, l0: Sequence[float] | str = "auto",
                **options: Any) -> dict[str, Any]:
        """Render ``which`` views (``test``, ``train``, ``all``) under even light into ``out_dir`` (default
        ``RUN/relit``); ``options`` are :func:`spotlessgs.rendering.render_run`'s (``exr``, ``progress``, ``device``,
        ``low_frequency``, ``data_dir``, ``align_poses``). Returns the render summary."""
        return render_run(self.dir, "relit", which, out_dir, l0=l0, **options)

    def render(self, which: str = "all", out_dir: str | Path | None = None, **options: Any) -> dict[str, Any]:
        """Render ``which`` views under the learned spotlight into ``out_dir`` (default ``RUN/render``)."""
        return render_run(self.dir, "spot", which, out_dir, **options)

    def evaluate(self, config: EvalConfig = EvalConfig(), out_dir: str | Path | None = None,
                 data_dir: str | Path | None = None) -> dict[str, Any]:
        """Score the relit views against the ground truth (``spotless eval RUN``) into ``out_dir`` (default
        ``RUN/eval``). Returns the results (also in ``results.json``)."""
        return evaluate_run(self.dir, config, out_dir=out_dir, data_dir=data_dir)

    def score_views(self, out_dir: str | Path, which: str = "test", num_threads: int | None = None,
                    data_dir: str | Path | None = None, **relight_options: Any) -> dict[str, Any]:
        """Relight ``which`` views into ``out_dir`` and score its test views against the ground truth: the one
        train -> relight -> score step of the reproduction's curve points and the benchmarks' rows.

        Returns:
            ``psnr``, ``ssim``, ``psnr_aligned``, ``ssim_aligned`` (means over the test views, see
            :func:`evaluation.runner.score_test_views`), ``pose_alignment`` (the views aligned before rendering, for a
            run that refined its poses, else None) and ``relight`` (the render summary: fps, count, ...).
        """
        relit = self.relight(which, out_dir, progress=False, data_dir=data_dir, **relight_options)
        data = resolve_data_dir(self.dir, self.info, data_dir)
        return {"relight": relit, **score_test_views(data, out_dir, num_threads)}

    def _optional(self, name: str, what: str) -> dict[str, Any] | None:
        path = self.dir / name
        if not path.is_file():
            return None
        record = read_json(path, what)
        check_schema_version(path, record)
        return record
