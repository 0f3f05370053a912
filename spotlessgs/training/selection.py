"""Automatic model selection (``spotless train --model auto``): the cheapest light/reflectance model the scene needs.

Candidates are spotlight models with an SH low-frequency light of degree 0-3 (degree 0 = an RGB constant ambient, the
DarkGS ambient per colour channel) and a Lambertian or learned (MLP) BRDF. Their cost order is structural, so the
choice does not depend on timing noise of a busy machine: Lambertian before MLP, then lower SH degree first
(``cost_rank``). The measured ms/step and the parameter count of each candidate are reported beside it.

Criterion, from the uneven training images alone (no ground truth, the test split untouched): every k-th training view
is held out (:mod:`spotlessgs.training.validation`). A shared base model (Lambert, SH degree 0) is fitted once on the
remaining training views for ``base_fraction`` of the full schedule; every candidate then starts from its Gaussians and
spotlight (:mod:`spotlessgs.training.warm_start`) and trains for ``proxy_fraction`` of the schedule, so the candidates
differ in the compared components only, not in how far geometry and light got. A candidate's error is the
spotlight-lit PSNR of the held-out views. The chosen model is the cheapest candidate whose PSNR is within
``tolerance_db`` of the best candidate's. Cost with the defaults (coordinate search): 0.1 + 5 × 0.05 = 0.35 of the
full run's steps (proxies skip densification, so they are cheaper per step than the full run).

Search (``SelectionConfig.search``): ``grid`` trains every (degree, BRDF) pair; ``coordinate`` (default, about half
the cost) first compares the SH degrees with the Lambertian BRDF, then adds the MLP BRDF at the degree chosen so far
(the BRDF and the low-frequency light model different effects: view-dependent highlights vs. light arriving from
elsewhere than the spotlight). Every trained candidate is in the decision file ``RUN/model_selection.json``; proxy runs
live in ``RUN/selection/<candidate>/`` (their checkpoints are removed once scored).
"""

from __future__ import annotations

import dataclasses
import json
import logging
import shutil
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from spotlessgs.io.atomic import write_json
from spotlessgs.models.shading import ModelConfig, build_appearance_models
from spotlessgs.training.config import TrainConfig

log = logging.getLogger(__name__)

SELECTION_FILE = "model_selection.json"
SELECTION_VERSION = 1
BRDFS = ("lambert", "mlp")


@dataclass(frozen=True)
class SelectionConfig:
    """Settings of automatic model selection."""

    # A candidate within this many dB of the best held-out PSNR counts as good enough (the cheapest of those wins).
    tolerance_db: float = 0.25
    # Shared base run (Lambert, SH degree 0) that fits geometry and spotlight once, as a fraction of the full run's
    # iterations; every candidate starts from it (warm start).
    base_fraction: float = 0.1
    # Each candidate's proxy run (from the base) as a fraction of the full run's iterations; both at least
    # min_proxy_iterations steps.
    proxy_fraction: float = 0.05
    min_proxy_iterations: int = 100
    # Hold out every k-th training view for validation during the proxy runs.
    validation_every: int = 5
    # "coordinate" (SH degrees with Lambert, then the MLP BRDF at the chosen degree) or "grid" (every pair).
    search: str = "coordinate"
    # Candidate SH degrees of the low-frequency light.
    sh_degrees: tuple[int, ...] = (0, 1, 2, 3)

    def __post_init__(self) -> None:
        if not self.tolerance_db >= 0:
            raise ValueError(f"SelectionConfig: tolerance_db must be >= 0, got {self.tolerance_db}")
        for name in ("base_fraction", "proxy_fraction"):
            if not 0 < getattr(self, name) <= 1:
                raise ValueError(f"SelectionConfig: {name} must be in (0, 1], got {getattr(self, name)}")
        if self.min_proxy_iterations < 1:
            raise ValueError(f"SelectionConfig: min_proxy_iterations must be >= 1, got {self.min_proxy_iterations}")
        if self.validation_every < 2:
            raise ValueError(f"SelectionConfig: validation_every must be >= 2, got {self.validation_every}")
        if self.search not in ("coordinate", "grid"):
            raise ValueError(f"SelectionConfig: search must be 'coordinate' or 'grid', got {self.search!r}")
        if not self.sh_degrees or any(d not in (0, 1, 2, 3) for d in self.sh_degrees):
            raise ValueError(f"SelectionConfig: sh_degrees must be a non-empty subset of 0..3, got {self.sh_degrees}")


def candidate_model(sh_degree: int, brdf: str) -> ModelConfig:
    """The spotlight model with an SH light of ``sh_degree`` and the ``brdf`` (``lambert`` or ``mlp``)."""
    if brdf not in BRDFS:
        raise ValueError(f"candidate_model: brdf must be one of {BRDFS}, got {brdf!r}")
    return ModelConfig(f"auto-sh{sh_degree}-{brdf}", light_model="spotlight", ambient="sh", sh_degree=sh_degree,
                       brdf=brdf)


def cost_rank(model: ModelConfig) -> tuple[int, int]:
    """Structural cost order: (MLP BRDF?, SH degree); smaller is cheaper."""
    return (int(model.brdf == "mlp"), int(model.sh_degree))


@dataclass(frozen=True)
class CandidateResult:
    """One scored candidate."""

    # ModelConfig name (auto-sh<d>-<brdf>).
    name: str
    sh_degree: int
    brdf: str
    # Spotlight-lit PSNR (dB, linear) of the held-out training views after the proxy run.
    validation_psnr: float
    # Measured proxy training cost (ms per step, on this machine at this time) and proxy length.
    ms_per_step: float
    proxy_steps: int
    # Learned parameters of the shared appearance modules (spotlight, SH light, BRDF MLP).
    appearance_parameters: int

    @property
    def model(self) -> ModelConfig:
        return candidate_model(self.sh_degree, self.brdf)


def choose(results: Sequence[CandidateResult], tolerance_db: float) -> CandidateResult:
    """The cheapest (``cost_rank``) candidate whose validation PSNR is within ``tolerance_db`` of the best."""
    if not results:
        raise ValueError("choose: no candidates were scored")
    best = max(r.validation_psnr for r in results)
    good = [r for r in results if r.validation_psnr >= best - tolerance_db]
    return min(good, key=lambda r: cost_rank(r.model))


def appearance_parameters(model: ModelConfig) -> int:
    """Number of learned scalars in the shared appearance modules of ``model``."""
    return int(sum(p.numel() for p in build_appearance_models(model).module_dict().parameters()))


def proxy_config(config: TrainConfig, selection: SelectionConfig, fraction: float | None = None) -> TrainConfig:
    """The short proxy schedule: ``fraction`` (default: proxy_fraction) of the iterations, no densification or opacity
    reset, validation views held out."""
    fraction = selection.proxy_fraction if fraction is None else fraction
    steps = max(int(round(fraction * config.iterations)), selection.min_proxy_iterations)
    return config.replace(
        iterations=steps, validation_every=selection.validation_every, validation_rejoin=False,
        gaussian_budget=False, densify_from=steps, densify_until=0, opacity_reset_every=0, checkpoint_every=steps,
        log_every=min(config.log_every, steps),
    )


def _settings(config: TrainConfig, selection: SelectionConfig, seed: int, data_dir: Path) -> dict:
    return {"selection": dataclasses.asdict(selection), "proxy_iterations": proxy_config(config, selection).iterations,
            "base_iterations": proxy_config(config, selection, selection.base_fraction).iterations,
            "full_iterations": config.iterations, "seed": seed, "data_dir": str(data_dir)}


def _score(data_dir: Path, proxy_dir: Path, model: ModelConfig, config: TrainConfig, seed: int,
           light_prior, resume: bool, progress: bool, base_dir: Path) -> CandidateResult:
    from spotlessgs.training.trainer import train

    result = train(data_dir, proxy_dir, model, config, seed=seed, resume=resume, light_prior=light_prior,
                   progress=progress, init_from=base_dir)
    if result.validation_psnr is None:
        raise RuntimeError(f"{proxy_dir}: the proxy run of {model.name} has no validation PSNR")
    shutil.rmtree(proxy_dir / "checkpoints", ignore_errors=True)
    return CandidateResult(model.name, model.sh_degree, model.brdf, float(result.validation_psnr),
                           float(result.ms_per_step), int(result.steps), appearance_parameters(model))


def select_model(
    data_dir: str | Path, run_dir: str | Path, config: TrainConfig, seed: int = 0,
    selection: SelectionConfig = SelectionConfig(), light_prior: Sequence[float] | None = None,
    resume: bool = False, progress: bool = False,
) -> dict:
    """Score the candidates with proxy runs and write the decision to ``RUN/model_selection.json``.

    Returns:
        the decision: ``chosen`` (name), ``chosen_model`` (ModelConfig fields), ``best`` (name of the highest PSNR),
        ``tolerance_db``, ``candidates`` (every scored CandidateResult as a dict, in the order trained), ``settings``.
    Raises:
        FileExistsError: a decision exists and ``resume`` is False; ValueError: ``resume`` with other settings.
    """
    from spotlessgs.training.trainer import train

    data_dir, run_dir = Path(data_dir).resolve(), Path(run_dir)
    path = run_dir / SELECTION_FILE
    settings = json.loads(json.dumps(_settings(config, selection, seed, data_dir)))  # as stored (tuples -> lists)
    if path.is_file():
        if not resume:
            raise FileExistsError(f"{path} exists: pass --resume to continue this run or use a new --out")
        decision = json.loads(path.read_text())
        if decision.get("settings") != settings:
            raise ValueError(f"{path}: --resume with other selection settings than the run was started with")
        return decision
    proxy = proxy_config(config, selection)
    base_dir = run_dir / "selection" / "base"
    base_model = dataclasses.replace(candidate_model(0, "lambert"), name="auto-base")
    log.info("model selection: shared base run (%s)", base_model.name)
    base = train(data_dir, base_dir, base_model, proxy_config(config, selection, selection.base_fraction), seed=seed,
                 resume=resume, light_prior=light_prior, progress=progress)
    scored: dict[str, CandidateResult] = {}

    def score(model: ModelConfig) -> CandidateResult:
        if model.name not in scored:
            log.info("model selection: proxy run of %s (%d steps)", model.name, proxy.iterations)
            scored[model.name] = _score(data_dir, run_dir / "selection" / model.name, model, proxy, seed,
                                        light_prior, resume,
                                        progress, base_dir)
        return scored[model.name]

    degrees = sorted(set(selection.sh_degrees))
    if selection.search == "grid":
        for brdf in BRDFS:
            for d in degrees:
                score(candidate_model(d, brdf))
    else:
        lambert = [score(candidate_model(d, "lambert")) for d in degrees]
        degree = choose(lambert, selection.tolerance_db).sh_degree
        score(candidate_model(degree, "mlp"))
    results = list(scored.values())
    chosen = choose(results, selection.tolerance_db)
    best = max(results, key=lambda r: r.validation_psnr)
    decision = {
        "version": SELECTION_VERSION,
        "criterion": "cheapest candidate (Lambert before MLP BRDF, then lower SH degree) whose spotlight-lit PSNR on "
                     "held-out training views is within tolerance_db of the best",
        "chosen": chosen.name,
        "chosen_model": dataclasses.asdict(chosen.model),
        "best": best.name,
        "tolerance_db": selection.tolerance_db,
        "candidates": [dataclasses.asdict(r) for r in results],
        "base": {"steps": base.steps, "validation_psnr": base.validation_psnr, "ms_per_step": base.ms_per_step},
        "settings": settings,
    }
    write_json(path, decision)
    shutil.rmtree(base_dir / "checkpoints", ignore_errors=True)
    return decision


def format_selection_table(decision: dict) -> str:
    """A short plain-text table of a decision: one row per candidate, the chosen one marked with ``*``."""
    best = max(c["validation_psnr"] for c in decision["candidates"])
    lines = [f"{'':1} {'candidate':<18} {'SH':>2} {'BRDF':<7} {'val PSNR':>8} {'Δbest':>6} {'ms/step':>8} "
             f"{'params':>7}"]
    for c in decision["candidates"]:
        mark = "*" if c["name"] == decision["chosen"] else " "
        lines.append(f"{mark} {c['name']:<18} {c['sh_degree']:>2} {c['brdf']:<7} {c['validation_psnr']:>8.2f} "
                     f"{c['validation_psnr'] - best:>6.2f} {c['ms_per_step']:>8.1f} {c['appearance_parameters']:>7}")
    lines.append(f"chosen: {decision['chosen']} (cheapest within {decision['tolerance_db']:g} dB of the best, "
                 f"{decision['best']})")
    return "\n".join(lines)


def train_auto(
    data_dir: str | Path, run_dir: str | Path, config: TrainConfig, seed: int = 0,
    selection: SelectionConfig = SelectionConfig(), light_prior: Sequence[float] | None = None,
    resume: bool = False, progress: bool = True,
):
    """Select the model (:func:`select_model`), then train it fully into ``run_dir``.

    Returns:
        (decision dict, :class:`~spotlessgs.training.trainer.TrainResult` of the full run).
    """
    from spotlessgs.training.trainer import train

    decision = select_model(data_dir, run_dir, config, seed, selection, light_prior, resume, progress=False)
    model = ModelConfig(**decision["chosen_model"])
    result = train(data_dir, run_dir, model, config, seed=seed, resume=resume, light_prior=light_prior,
                   progress=progress)
    return decision, result


def run_decisions(run_dir: str | Path) -> dict:
    """What a run needed, for reports: ``model chosen`` (the auto decision, else the trained model's name) and
    ``Gaussians`` (final count from train_summary.json; None when the run is unfinished)."""
    run_dir = Path(run_dir)
    info_path = run_dir / "run.json"
    if not info_path.is_file():
        raise FileNotFoundError(f"{run_dir}: not a training run (no run.json)")
    chosen = json.loads(info_path.read_text())["model"]
    selection = run_dir / SELECTION_FILE
    if selection.is_file():
        chosen = json.loads(selection.read_text())["chosen"]
    summary = run_dir / "train_summary.json"
    gaussians = json.loads(summary.read_text())["num_gaussians"] if summary.is_file() else None
    return {"model chosen": chosen, "Gaussians": gaussians}


def selection_config(tolerance_db: float | None = None, search: str | None = None) -> SelectionConfig:
    """SelectionConfig with the given fields changed (None keeps the default)."""
    changes = {k: v for k, v in (("tolerance_db", tolerance_db), ("search", search)) if v is not None}
    return dataclasses.replace(SelectionConfig(), **changes)
