"""Automatic model selection (``spotless train --model auto``): the cheapest light/reflectance model the scene needs.

Candidates are spotlight models with an SH low-frequency light of degree 0-3 (degree 0 = an RGB constant ambient, the
DarkGS ambient per colour channel) and a Lambertian or learned (MLP) BRDF. Their cost order is structural, so the
choice does not depend on timing noise of a busy machine: Lambertian before MLP, then lower SH degree first
(``cost_rank``). The measured ms/step and the parameter count of each candidate are reported beside it.

Criterion, from the uneven training images alone (no ground truth, the test split untouched): a seeded 10% of the
8×8 pixel blocks of every training view is held out (:func:`spotlessgs.training.validation.holdout_blocks`): never
fitted, they are new observations of surfaces whose geometry the other views pin down, so their error reflects the
light and reflectance model rather than how well a short run extrapolates geometry to a new viewpoint (whole held-out
views, ``holdout="views"``, hid the BRDF behind geometry error: on the glossy storage room every candidate scored
~11.7 dB). A shared base model (Lambert, SH degree 0) is fitted once for ``base_fraction`` of the full schedule; the
candidates start from its Gaussians and spotlight (:mod:`spotlessgs.training.warm_start`), so they differ in the
compared components only. A candidate's error is the spotlight-lit PSNR of the held-out pixels, averaged over
``validation_average`` scores in the last third of its proxy run; in the light phase it is the darkest half of the
held-out pixels (``light_criterion``), where the low-frequency light dominates, and the proxies train that light at
``proxy_light_lr_scale`` times its learning rate so that it can move in a few hundred steps. Each decision picks the
cheapest candidate within half of ``tolerance_db`` of the best (:func:`phase_tolerance`); the SH degree is no
such ranking (below), its guard against a light that fits noise allows the whole ``tolerance_db``.

The SH degree also needs a signal the held-out pixels do not give: whether the scene has ambient or bounce light at
all. Held-out scores of degrees 0-3 differed by 0.1-0.2 dB in no consistent order on the bounce-lit bedroom, whose
relit images nevertheless gain 0.16-0.19 dB from degree 3. So the light phase asks two questions without ground
truth (:func:`measure_light_need`, :mod:`spotlessgs.training.light_need`): are the parts of the training images the
spotlight misses lit at all (``min_dark_level``), and does the highest-degree proxy use its low-frequency light
(``min_low_frequency_share`` of its spotlight-lit rendered radiance)? Both yes: the highest degree, unless its
held-out score falls beyond the tolerance; otherwise the lowest (:func:`choose_light`). The degrees cost the same per
step within timing noise (48 vs 3 SH coefficients next to thousands of Gaussians), so the highest degree is the cheap
answer whenever the light exists.

Search (``SelectionConfig.search``), ``coordinate`` (default): phase "reflectance" trains the Lambertian and the MLP
BRDF at the lowest SH degree for ``reflectance_proxy_fraction`` each and keeps the cheaper one within its tolerance;
phase "light" continues that winner with the lowest and the highest SH degree for ``proxy_fraction`` each, and the
final choice is made between these (equally long) runs. Cost with the defaults: 0.1 + 2 × 0.15 + 2 × 0.05 = 0.5 of
the full run's steps, at the cheaper per-step cost of runs without densification (50 s against 115 s for a quick
bedroom run, 2 threads). ``grid`` trains every (degree, BRDF) pair for ``reflectance_proxy_fraction`` (1.3 runs'
steps) and applies the same light rule, measured on the highest-degree Lambertian candidate. Every trained candidate,
with its phase, and the light measurements are in the decision file ``RUN/model_selection.json``; proxy runs live in
``RUN/selection/<candidate>[-light]/`` (their checkpoints are removed when the search ends).

A start the trainer trusts (``TrainConfig.trust_start_geometry``: a dense start with normals) is what the held-out
pixels judge worst. SpotlessGS holds its normals there, and held normals fit the spotlit pixels less than free ones,
which lean towards the camera, while they relight far better (quick bedroom: the trusted candidate scored 22.88 dB on
the held-out pixels against 23.69 with free normals; relit against the uniform ground truth SpotlessGS scores 25.80 dB,
the Lambertian model ``auto`` chose 23.37). ``trusted_start_reflectance="learned"`` (the default) therefore takes
the reflectance from that rule rather than from the held-out pixels: on a trusted start the BRDF is the learned one
(the model that the start's normals are held for; a Lambertian albedo paints a held surface's glints in), the shared
base run holds the start's normals as well (else the candidates would hold the base's free-trained ones), and only
the SH degree is searched.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import shutil
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from spotlessgs.io.atomic import write_json
from spotlessgs.io.dataset import load_initial_points, read_dataset
from spotlessgs.io.dataset_fingerprint import dataset_fingerprint, other_dataset
from spotlessgs.io.errors import InputError
from spotlessgs.io.folder_lock import folder_lock
from spotlessgs.io.json_files import read_json, require_keys
from spotlessgs.io.paths import refuse_overlap
from spotlessgs.models.shading import ModelConfig, build_appearance_models
from spotlessgs.training import trainer  # called as trainer.train: patching spotlessgs.training.trainer reaches here
from spotlessgs.training.checkpoint import checkpoint_path, load_checkpoint
from spotlessgs.training.config import TrainConfig, with_defaults
from spotlessgs.training.light_need import dark_level, low_frequency_share
from spotlessgs.training.validation import block_size, evenly_spaced

log = logging.getLogger(__name__)

SELECTION_FILE = "model_selection.json"
#: 6 since 66edae3: a trusted start's proxies have the monotone profile and the irradiance shading
#: (trainer.TRUSTED_START_LIGHT). 7 since 2026-12-07: SpotlessGS-type proxies (an MLP BRDF) train the depth-spread
#: term on every dataset. 8 since 2026-12-07: a trusted start's SpotlessGS-type proxies and chosen model have no
#: camera-frame bounce SH (trainer.TRUSTED_START_SETTINGS).
SELECTION_VERSION = 8
BRDFS = ("lambert", "mlp")


@dataclass(frozen=True)
class SelectionConfig:
    """Settings of automatic model selection."""

    # A candidate within this many dB of the best held-out PSNR counts as good enough (the cheapest of those wins).
    tolerance_db: float = 0.25
    # Shared base run (Lambert, SH degree 0) that fits geometry and spotlight once, as a fraction of the full run's
    # iterations; every candidate starts from it (warm start).
    base_fraction: float = 0.1
    # Coordinate search, phase 1 (reflectance): the Lambertian and the MLP BRDF (lowest SH degree) each train this
    # fraction of the full run's iterations from the base (a BRDF needs longer than a light to show what it buys: at
    # 0.05 the glossy storage room and the diffuse bedroom looked alike). Grid search trains every pair this long.
    reflectance_proxy_fraction: float = 0.15
    # Phase 2 (low-frequency light): the lowest and the highest SH degree with the chosen BRDF train this fraction from
    # phase 1's winner.
    # Every proxy run is at least min_proxy_iterations steps.
    proxy_fraction: float = 0.05
    min_proxy_iterations: int = 100
    # What the proxies do not fit and are scored on: "blocks" (a seeded fraction holdout_fraction of the 8×8 pixel
    # blocks of every training view: new observations of surfaces whose geometry other views pin down, so the score
    # reflects the light/reflectance model) or "views" (every validation_every-th training view: also measures how
    # far the short proxies got with geometry, which can hide the appearance model).
    holdout: str = "blocks"
    holdout_fraction: float = 0.1
    # Side of a held-out block in pixels of the training resolution; None = 1/20 of the image width (8 px at 160 px):
    # small against the image, so that the neighbouring fitted pixels pin the geometry inside it (at 64 px, 8-px
    # blocks let SH degree 1 fit proxy artefacts in a room without ambient light; 3-px blocks do not).
    holdout_block: int | None = None
    validation_every: int = 5
    # Each proxy's score is the mean of this many held-out scores over the last third of its run
    # (TrainConfig.validation_average): one score at the last step varied by ~0.15 dB between runs on 1 and 2 threads,
    # as much as the tolerance.
    validation_average: int = 4
    # Which held-out PSNR decides the SH degree (phase "light"): "dark" (the darkest half of the held-out pixels,
    # where the low-frequency light dominates; on all pixels the spotlight's error hid it: every degree scored within
    # 0.02 dB on the bedroom, whose relit output gains ~0.2 dB from degree 3) or "all".
    light_criterion: str = "dark"
    # The proxies train the low-frequency light at this multiple of its learning rate: at the full run's rate it
    # barely moves in a proxy's few hundred steps (SH coefficients reached ~0.02 in a 150-step proxy against ~0.3 at
    # the end of the full bedroom run), so no SH degree could show what it buys. (Scaling the BRDF's rate as well
    # made the MLP lead by 0.16-0.25 dB on the diffuse rooms, against 0.40 dB on the glossy one: not used.)
    proxy_light_lr_scale: float = 10.0
    # Does the scene need a low-frequency light (ambient or bounce)? Two measurements without ground truth, both
    # must say so (spotlessgs.training.light_need): the dark level of the training images (the 20th-percentile block
    # brightness over the 99th, median over views; blocks of the held-out block size, 8 px at 160 px) at least
    # min_dark_level, and the share of the spotlight-lit rendered radiance (over share_views training views) that the
    # highest-degree proxy's low-frequency light carries at least min_low_frequency_share. If so, the highest SH
    # degree, else the lowest (either unless its held-out score is beyond tolerance_db of the best). Measured on the
    # 36-frame quick rooms: dark level 0.054 / 0.050 (bedroom, Lambertian bedroom), 0.026 (storage room), 0 (bedroom
    # without bounce light; 0.0014 with sensor noise of read sigma 0.012); proxy share over 3 seeds 0.068-0.122
    # (bedrooms), 0.030-0.049 (storage room), 0.001 (no bounce light, seed 0). The share alone fails on tiny images,
    # where the light makes up for a spotlight not fitted yet (64-px bedroom without bounce light: share 0.22, dark
    # level 0). The held-out pixels cannot rank the degrees themselves: degrees 0-3 scored within 0.1-0.2 dB of each
    # other in no consistent order over 3 seeds, while degree 3 relit the bounce-lit bedroom 0.16-0.19 dB better than
    # the degree 0-2 that rule had picked.
    min_dark_level: float = 0.01
    min_low_frequency_share: float = 0.01
    share_views: int = 12
    # "coordinate" (the BRDF at the lowest SH degree, then the SH degree with that BRDF) or "grid" (every pair).
    search: str = "coordinate"
    # Candidate SH degrees of the low-frequency light.
    sh_degrees: tuple[int, ...] = (0, 1, 2, 3)
    # On a start the trainer trusts (trusted_start): "learned" (the learned BRDF without a reflectance phase, the
    # shared base holding the start's normals; see the module docstring) or "compare" (the BRDFs compete on the
    # held-out pixels, as on any other start; the default before 2026-11-27, seventh session).
    trusted_start_reflectance: str = "learned"

    def __post_init__(self) -> None:
        if not self.tolerance_db >= 0:
            raise ValueError(f"SelectionConfig: tolerance_db must be >= 0, got {self.tolerance_db}")
        for name in ("base_fraction", "reflectance_proxy_fraction", "proxy_fraction"):
            if not 0 < getattr(self, name) <= 1:
                raise ValueError(f"SelectionConfig: {name} must be in (0, 1], got {getattr(self, name)}")
        if self.min_proxy_iterations < 1:
            raise ValueError(f"SelectionConfig: min_proxy_iterations must be >= 1, got {self.min_proxy_iterations}")
        if self.holdout not in ("blocks", "views"):
            raise ValueError(f"SelectionConfig: holdout must be 'blocks' or 'views', got {self.holdout!r}")
        if not 0 < self.holdout_fraction < 1:
            raise ValueError(f"SelectionConfig: holdout_fraction must be in (0, 1), got {self.holdout_fraction}")
        if self.holdout_block is not None and self.holdout_block < 1:
            raise ValueError(f"SelectionConfig: holdout_block must be >= 1, got {self.holdout_block}")
        if self.validation_every < 2:
            raise ValueError(f"SelectionConfig: validation_every must be >= 2, got {self.validation_every}")
        if not self.proxy_light_lr_scale > 0:
            raise ValueError(f"SelectionConfig: proxy_light_lr_scale must be > 0, got {self.proxy_light_lr_scale}")
        if self.validation_average < 1:
            raise ValueError(f"SelectionConfig: validation_average must be >= 1, got {self.validation_average}")
        if self.light_criterion not in ("dark", "all"):
            raise ValueError(f"SelectionConfig: light_criterion must be 'dark' or 'all', got {self.light_criterion!r}")
        if not 0 <= self.min_dark_level < 1:
            raise ValueError(f"SelectionConfig: min_dark_level must be in [0, 1), got {self.min_dark_level}")
        if not 0 <= self.min_low_frequency_share < 1:
            raise ValueError(f"SelectionConfig: min_low_frequency_share must be in [0, 1), "
                             f"got {self.min_low_frequency_share}")
        if self.share_views < 1:
            raise ValueError(f"SelectionConfig: share_views must be >= 1, got {self.share_views}")
        if self.search not in ("coordinate", "grid"):
            raise ValueError(f"SelectionConfig: search must be 'coordinate' or 'grid', got {self.search!r}")
        if self.trusted_start_reflectance not in ("compare", "learned"):
            raise ValueError("SelectionConfig: trusted_start_reflectance must be 'compare' or 'learned', got "
                             f"{self.trusted_start_reflectance!r}")
        if not self.sh_degrees or any(d not in (0, 1, 2, 3) for d in self.sh_degrees):
            raise ValueError(f"SelectionConfig: sh_degrees must be a non-empty subset of 0..3, got {self.sh_degrees}")


def trusted_start(config: TrainConfig, data_dir: str | Path) -> bool:
    """Whether a SpotlessGS model trained on ``data_dir`` with ``config`` holds its start's normals
    (:func:`~spotlessgs.training.trainer.start_is_trusted` of the dataset's start point cloud)."""
    return trainer.start_is_trusted(config, load_initial_points(read_dataset(data_dir)))


def proxy_light(config: TrainConfig, trusted: bool) -> dict[str, object]:
    """The light model of every proxy run of a selection (each proxy's lamp and SH light start from the shared base's,
    so all have one), and of the chosen model's run, whatever the candidate's SH degree and BRDF. On a ``trusted``
    start SpotlessGS's, :data:`~spotlessgs.training.trainer.TRUSTED_START_LIGHT`; elsewhere ``config.rid_model``,
    with "auto" the paper's MLP profile: on the robot copy's sparse start the monotone one, SpotlessGS's there, cost
    ``--model auto`` 0.19 / 0.11 dB (lamps-on / uniform ground truth, three seeds; docs/results.md, "SpotlessGS's lamp
    profile and depth-spread term on every start")."""
    if trusted:
        return dict(trainer.TRUSTED_START_LIGHT)
    return {"rid_model": "mlp" if config.rid_model == "auto" else config.rid_model}


def chosen_model_train_config(config: TrainConfig, data_dir: str | Path) -> TrainConfig:
    """``config`` as the chosen model of a ``--model auto`` run on ``data_dir`` trains with it, and as its
    ``config.json`` saves it: with the light model its proxies had (:func:`proxy_light`), also for a Lambertian model
    (which alone resolves ``rid_model`` "auto" to the MLP profile and which trust_start_geometry leaves alone)."""
    return config.replace(**proxy_light(config, trusted_start(config, data_dir)))


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
    # Search phase: "reflectance" or "light" (coordinate search), "grid"; only candidates of the last phase, which all
    # trained equally long, compete for the final choice.
    phase: str = "grid"
    # The same PSNR on the darkest half of the held-out pixels (HeldOutScore.psnr_dark); None in old decision files.
    validation_psnr_dark: float | None = None
    # Which of the two PSNRs this candidate's phase compared: "all" or "dark".
    criterion: str = "all"

    @property
    def score(self) -> float:
        """The PSNR its phase compared (``criterion``)."""
        return self.validation_psnr_dark if self.criterion == "dark" else self.validation_psnr

    @property
    def model(self) -> ModelConfig:
        return candidate_model(self.sh_degree, self.brdf)


def choose(results: Sequence[CandidateResult], tolerance_db: float) -> CandidateResult:
    """The cheapest (``cost_rank``) candidate whose score (its phase's PSNR) is within ``tolerance_db`` of the best."""
    if not results:
        raise ValueError("choose: no candidates were scored")
    best = max(r.score for r in results)
    good = [r for r in results if r.score >= best - tolerance_db]
    return min(good, key=lambda r: cost_rank(r.model))


def choose_light(results: Sequence[CandidateResult], light_needed: bool,
                 selection: SelectionConfig) -> CandidateResult:
    """The final choice among the last phase's candidates, given whether the scene needs a low-frequency light.

    Not needed (no ambient or bounce light to model): the candidates of the lowest SH degree compete
    (:func:`choose`, phase tolerance). Needed: those of the highest degree compete. Either way only if the best of
    them is within the whole ``tolerance_db`` of the best candidate overall; if not (the measurement and the held-out
    pixels disagree), every candidate competes. The guard gets the whole tolerance, not the phase's half, because it
    is no ranking: the held-out scores of the degrees differ by 0.1-0.2 dB in no consistent order (at half the
    tolerance it refused degree 3 on one seed of the Lambertian bedroom, 0.19 dB behind on the dark held-out pixels,
    and the relit result lost 0.17 dB against 0.04 dB with degree 3). (Degree 0 has an RGB constant ambient, so it
    also serves a faint uniform one.)

    Args:
        results: the candidates of the final phase (light phase: one BRDF, lowest and highest degree; grid: all).
        light_needed: :func:`measure_light_need`'s verdict.
    """
    if not results:
        raise ValueError("choose_light: no candidates were scored")
    tolerance = phase_tolerance(selection)
    degrees = [r.sh_degree for r in results]
    wanted = max(degrees) if light_needed else min(degrees)
    pool = [r for r in results if r.sh_degree == wanted]
    if max(r.score for r in pool) >= max(r.score for r in results) - selection.tolerance_db:
        return choose(pool, tolerance)
    return choose(results, tolerance)


def measure_light_need(run_dir: Path, selection: SelectionConfig, device: str = "cpu") -> dict:
    """Whether the scene needs a low-frequency light, measured with the proxy run in ``run_dir`` (its checkpoint).

    Returns:
        ``dark_level`` (:func:`~spotlessgs.training.light_need.dark_level` of the training images at the training
        resolution, blocks of the held-out block size), ``low_frequency_share``
        (:func:`~spotlessgs.training.light_need.low_frequency_share` over ``share_views`` evenly spaced training
        views), ``measured_on`` (the proxy's folder name) and ``needed`` (both at least their thresholds).
    """
    scene, views, config, _info = trainer.load_run(run_dir, device=device)
    dev = scene.gaussians.means.device
    images = views.images[views.train]
    if views.unseen is not None:  # a distorted camera's working pixels without a sample say nothing (NaN is skipped)
        images = images.masked_fill(views.unseen[views.train][..., None], float("nan"))
    level = dark_level(images, block_size(views.cameras.width, selection.holdout_block))
    share = low_frequency_share(scene, views.cameras.to(dev), evenly_spaced(views.train, selection.share_views),
                                config.raster_backend, config.num_threads)
    return {"dark_level": level, "low_frequency_share": share, "measured_on": Path(run_dir).name,
            "needed": level >= selection.min_dark_level and share >= selection.min_low_frequency_share}


def phase_tolerance(selection: SelectionConfig) -> float:
    """The tolerance of a ranking by held-out scores. The coordinate search ranks the BRDFs, and the SH degrees only
    where the light rule's guard falls back (:func:`choose_light`); each gets half of ``tolerance_db`` so that two
    rankings cannot compound past it (when both phases ranked, the bedroom's -0.12 dB for the BRDF and -0.19 dB for
    the SH degree compounded to -0.31 dB). Grid search ranks once, with all of it."""
    return selection.tolerance_db / 2 if selection.search == "coordinate" else selection.tolerance_db


def appearance_parameters(model: ModelConfig, brdf_hidden: int) -> int:
    """Number of learned scalars in the shared appearance modules of ``model`` with a BRDF MLP ``brdf_hidden`` wide."""
    sized = dataclasses.replace(model, brdf_hidden=brdf_hidden)
    return int(sum(p.numel() for p in build_appearance_models(sized).module_dict().parameters()))


def proxy_config(config: TrainConfig, selection: SelectionConfig, fraction: float | None = None) -> TrainConfig:
    """The short proxy schedule: ``fraction`` (default: proxy_fraction) of the iterations, no densification or opacity
    reset, validation views held out."""
    fraction = selection.proxy_fraction if fraction is None else fraction
    steps = max(int(round(fraction * config.iterations)), selection.min_proxy_iterations)
    blocks = selection.holdout == "blocks"
    return config.replace(
        iterations=steps, validation_every=0 if blocks else selection.validation_every,
        validation_blocks=selection.holdout_fraction if blocks else 0.0, validation_block=selection.holdout_block,
        validation_rejoin=False, validation_average=selection.validation_average,
        lr_lf_light=(config.lr_light if config.lr_lf_light is None else config.lr_lf_light)
        * selection.proxy_light_lr_scale,
        gaussian_budget=False, densify_from=steps, densify_until=0, opacity_reset_every=0, checkpoint_every=steps,
        log_every=min(config.log_every, steps),
    )


def _settings(config: TrainConfig, selection: SelectionConfig, seed: int, data_dir: Path) -> dict:
    return {"selection": dataclasses.asdict(selection), "proxy_iterations": proxy_config(config, selection).iterations,
            "reflectance_proxy_iterations": proxy_config(config, selection,
                                                         selection.reflectance_proxy_fraction).iterations,
            "base_iterations": proxy_config(config, selection, selection.base_fraction).iterations,
            "full_iterations": config.iterations, "seed": seed, "data_dir": str(data_dir),
            "train": dataclasses.asdict(config)}


def _score(data_dir: Path, proxy_dir: Path, model: ModelConfig, config: TrainConfig, seed: int,
           light_prior, resume: bool, progress: bool, start_dir: Path, phase: str,
           criterion: str = "all") -> CandidateResult:
    """Train one proxy run from ``start_dir``'s checkpoint (its checkpoint is kept until the search ends)."""
    result = trainer.train(data_dir, proxy_dir, model, config, seed=seed, resume=resume, light_prior=light_prior,
                           progress=progress, init_from=start_dir)
    if result.validation_psnr is None:
        raise RuntimeError(f"{proxy_dir}: the proxy run of {model.name} has no validation PSNR")
    # the model as the run trained it: a trusted start adds the lamp bounce's gain (the checkpoint's model_settings)
    trained = config.replace(**trainer.recorded_model_settings(load_checkpoint(proxy_dir), config,
                                                               checkpoint_path(proxy_dir)))
    return CandidateResult(model.name, model.sh_degree, model.brdf, float(result.validation_psnr),
                           float(result.ms_per_step), int(result.steps),
                           appearance_parameters(trainer.model_config(model, trained), config.brdf_hidden), phase,
                           float(result.validation_psnr_dark), criterion)


def select_model(
    data_dir: str | Path, run_dir: str | Path, config: TrainConfig, seed: int = 0,
    selection: SelectionConfig = SelectionConfig(), light_prior: Sequence[float] | None = None,
    resume: bool = False, progress: bool = False,
) -> dict:
    """Score the candidates with proxy runs and write the decision to ``RUN/model_selection.json``.

    Returns:
        the decision: ``chosen`` (name), ``chosen_model`` (ModelConfig fields), ``best`` (name of the highest PSNR),
        ``tolerance_db``, ``candidates`` (every scored CandidateResult as a dict, in the order trained), ``settings``,
        ``seconds`` (wall time of the session that made the decision: the shared base run, the proxy runs and their
        held-out scoring; absent in decisions of earlier versions).
    Raises:
        FileExistsError: a decision exists and ``resume`` is False; ValueError: ``resume`` with other settings;
        InputError: the stored decision is damaged (not JSON, a missing entry; names the file).
    """
    data_dir, run_dir = Path(data_dir).resolve(), Path(run_dir)
    path = run_dir / SELECTION_FILE
    settings = json.loads(json.dumps(_settings(config, selection, seed, data_dir)))  # as stored (tuples -> lists)
    if path.is_file():
        if not resume:
            raise FileExistsError(f"{path} exists: pass --resume to continue this run or use a new --out")
        decision = read_json(path, "model selection decision")
        if decision.get("version") != SELECTION_VERSION:
            raise ValueError(f"{path}: made by model selection version {decision.get('version')}, this is version "
                             f"{SELECTION_VERSION} (other candidates and measurements); remove {path} and "
                             f"{run_dir / 'selection'} to decide again, or use a new --out")
        stored = dict(decision["settings"]) if isinstance(decision.get("settings"), dict) else {}
        if isinstance(stored.get("selection"), dict):  # decisions before 2026-11-27 compared the BRDFs everywhere
            stored["selection"] = {"trusted_start_reflectance": "compare", **stored["selection"]}
        # the dataset may have moved (--data DIR): not another setting; train, data_fingerprint: below
        moved = ("data_dir", "train", "data_fingerprint")
        differ = trainer.differing_settings({k: v for k, v in stored.items() if k not in moved},
                                            {k: v for k, v in settings.items() if k not in moved})
        if "train" in stored:  # absent in decisions written before the training settings were recorded
            differ += [f"train {d}" for d in trainer.differing_train_settings(stored["train"], settings["train"])]
        recorded = stored.get("data_fingerprint")  # absent in decisions written before 2026-11-26
        if recorded is not None and other_dataset(recorded, dataset_fingerprint(read_dataset(data_dir))):
            differ.append(f"dataset: decided on other files than {data_dir} holds")
        if differ:
            raise ValueError(f"{path}: --resume with other selection settings than the run was started with "
                             f"({'; '.join(differ)})")
        require_keys(decision, path, "model selection decision", ("chosen", "chosen_model"))
        if not isinstance(decision["chosen_model"], dict):
            raise InputError(f"{path}: damaged model selection decision: 'chosen_model' is not a JSON object")
        return decision
    start = time.perf_counter()
    proxy = proxy_config(config, selection)
    reflectance_proxy = proxy_config(config, selection, selection.reflectance_proxy_fraction)
    selection_dir = run_dir / "selection"
    base_dir = selection_dir / "base"
    base_model = dataclasses.replace(candidate_model(0, "lambert"), name="auto-base")
    base_config = proxy_config(config, selection, selection.base_fraction)
    trusted = trusted_start(config, data_dir)
    light = proxy_light(config, trusted)
    base_config, proxy, reflectance_proxy = (schedule.replace(**light)
                                             for schedule in (base_config, proxy, reflectance_proxy))
    log.info("model selection: every proxy, and the chosen model, with one light model (%s)",
             ", ".join(f"{name}={value}" for name, value in light.items()))
    # the learned BRDF by rule on a trusted start, whose normals the base then holds too
    learned_by_rule = selection.trusted_start_reflectance == "learned" and trusted
    if learned_by_rule:
        base_config = base_config.replace(lr_normals=trainer.TRUSTED_START_SETTINGS["lr_normals"])
        log.info("model selection: a trusted start: the learned BRDF, the start's normals held")
    log.info("model selection: shared base run (%s)", base_model.name)
    base = trainer.train(data_dir, base_dir, base_model, base_config, seed=seed, resume=resume,
                         light_prior=light_prior, progress=progress)
    scored: list[CandidateResult] = []

    def score(model: ModelConfig, schedule: TrainConfig, start_dir: Path, phase: str,
              criterion: str = "all") -> CandidateResult:
        log.info("model selection: proxy run of %s (%d steps, %s phase)", model.name, schedule.iterations, phase)
        folder = selection_dir / (model.name if phase != "light" else f"{model.name}-light")
        scored.append(_score(data_dir, folder, model, schedule, seed, light_prior, resume, progress, start_dir,
                             phase, criterion))
        return scored[-1]

    degrees = sorted(set(selection.sh_degrees))
    brdfs = ("mlp",) if learned_by_rule else BRDFS
    if selection.search == "grid":
        final = [score(candidate_model(d, brdf), reflectance_proxy, base_dir, "grid") for brdf in brdfs
                 for d in degrees]
        share_dir = selection_dir / candidate_model(degrees[-1], brdfs[0]).name
    else:
        if learned_by_rule:
            brdf, winner_dir = "mlp", base_dir
        else:
            reflectance = [score(candidate_model(degrees[0], brdf), reflectance_proxy, base_dir, "reflectance")
                           for brdf in BRDFS]
            brdf = choose(reflectance, phase_tolerance(selection)).brdf
            winner_dir = selection_dir / candidate_model(degrees[0], brdf).name
        # the lowest and the highest degree only: the held-out pixels cannot rank the degrees in between (see
        # min_dark_level), and the need for a low-frequency light is measured on the highest
        final = [score(candidate_model(d, brdf), proxy, winner_dir, "light", selection.light_criterion)
                 for d in sorted({degrees[0], degrees[-1]})]
        share_dir = selection_dir / f"{candidate_model(degrees[-1], brdf).name}-light"
    need = measure_light_need(share_dir, selection, config.device)
    for folder in selection_dir.iterdir():  # proxies keep their metrics and summaries, not their checkpoints
        shutil.rmtree(folder / "checkpoints", ignore_errors=True)
    chosen = choose_light(final, need["needed"], selection)
    best = max(final, key=lambda r: r.score)
    decision = {
        "version": SELECTION_VERSION,
        "criterion": "cheapest candidate (Lambert before MLP BRDF, then lower SH degree) whose spotlight-lit PSNR on "
                     "held-out pixels of the training views (mean of validation_average scores over the last third "
                     "of each proxy) is within phase_tolerance_db of the best; coordinate search decides the BRDF "
                     "first (phase 'reflectance', all held-out pixels), then the SH degree (phase 'light', the "
                     "darkest half of the held-out pixels when light_criterion is 'dark'): the highest degree "
                     "(if within the tolerance) when the scene needs a low-frequency light (low_frequency_light: "
                     "the training images' dark level and the highest-degree proxy's share of low-frequency "
                     "radiance both at least their minimum), else the lowest",
        "low_frequency_light": need,
        # "learned by rule" (a trusted start, trusted_start_reflectance "learned") or "compared"
        "reflectance": "learned by rule" if learned_by_rule else "compared",
        "chosen": chosen.name,
        "chosen_model": dataclasses.asdict(chosen.model),
        "best": best.name,
        "tolerance_db": selection.tolerance_db,
        "phase_tolerance_db": phase_tolerance(selection),
        "candidates": [dataclasses.asdict(r) for r in scored],
        "base": {"steps": base.steps, "validation_psnr": base.validation_psnr, "ms_per_step": base.ms_per_step},
        # the files the candidates trained on, as the shared base run recorded them
        "settings": {**settings, "data_fingerprint": read_json(base_dir / "run.json", "run description").get(
            "data_fingerprint")},
        "seconds": time.perf_counter() - start,
    }
    write_json(path, decision)
    return decision


def format_selection_table(decision: dict) -> str:
    """A short plain-text table of a decision: one row per candidate, the chosen one marked with ``*``; Δbest is on
    the PSNR the candidate's phase compared (``crit``: all held-out pixels or the darkest half)."""
    cands = decision["candidates"]
    phases = [c.get("phase", "grid") for c in cands]

    def score(c: dict) -> float:
        return c["validation_psnr_dark"] if c.get("criterion", "all") == "dark" else c["validation_psnr"]

    best = {p: max(score(c) for c, q in zip(cands, phases) if q == p) for p in phases}
    final = phases[-1]
    lines = [f"{'':1} {'candidate':<18} {'phase':<11} {'SH':>2} {'BRDF':<7} {'val PSNR':>8} {'dark':>6} {'crit':>4} "
             f"{'Δbest':>6} {'ms/step':>8} {'params':>7}"]
    for c, phase in zip(cands, phases):
        mark = "*" if c["name"] == decision["chosen"] and phase == final else " "
        dark = c.get("validation_psnr_dark")
        lines.append(f"{mark} {c['name']:<18} {phase:<11} {c['sh_degree']:>2} {c['brdf']:<7} "
                     f"{c['validation_psnr']:>8.2f} {'n/a' if dark is None else f'{dark:.2f}':>6} "
                     f"{c.get('criterion', 'all'):>4} {score(c) - best[phase]:>6.2f} "
                     f"{c['ms_per_step']:>8.1f} {c['appearance_parameters']:>7}")
    need, limits = decision["low_frequency_light"], decision["settings"]["selection"]
    lines.append(f"low-frequency light {'needed' if need['needed'] else 'not needed'}: dark level "
                 f"{need['dark_level']:.3f} (min {limits['min_dark_level']:g}), share "
                 f"{100 * need['low_frequency_share']:.1f}% of {need['measured_on']}'s radiance "
                 f"(min {100 * limits['min_low_frequency_share']:g}%) -> "
                 f"{'highest' if need['needed'] else 'lowest'} SH degree (if within {decision['tolerance_db']:g} dB)")
    if decision.get("reflectance") == "learned by rule":
        lines.append("reflectance: the learned BRDF by rule (a trusted start: its normals held)")
    lines.append(f"chosen: {decision['chosen']} (SH degree by the light rule, then the cheapest within "
                 f"{decision['phase_tolerance_db']:g} dB of the best; best held-out: {decision['best']})")
    return "\n".join(lines)


def train_auto(
    data_dir: str | Path, run_dir: str | Path, config: TrainConfig, seed: int = 0,
    selection: SelectionConfig = SelectionConfig(), light_prior: Sequence[float] | None = None,
    resume: bool = False, progress: bool = True, stop_after: int | None = None,
):
    """Select the model (:func:`select_model`), then train it into ``run_dir`` (fully, or up to step ``stop_after``
    as :func:`~spotlessgs.training.trainer.train` does).

    Returns:
        (decision dict, :class:`~spotlessgs.training.trainer.TrainResult` of the full run).
    """
    # before the lock, which creates the folder and its .lock file: `--out` inside `--data` leaves nothing there
    refuse_overlap(run_dir, {"--data": Path(data_dir).resolve()}, "the run folder (--out)")
    with folder_lock(run_dir, "spotless train --model auto"):
        if (Path(run_dir) / "run.json").is_file() and not (Path(run_dir) / SELECTION_FILE).is_file():
            # a run trained with a fixed model (or by hand): selecting first would take minutes, then fail the
            # trainer's settings check and leave a decision that the run never followed
            raise ValueError(f"{run_dir}: holds a run trained without model selection (no {SELECTION_FILE}); "
                             "--model auto cannot resume it: resume it with its own --model, or use a new --out")
        decision = select_model(data_dir, run_dir, config, seed, selection, light_prior, resume, progress=False)
        try:
            model = ModelConfig(**with_defaults(ModelConfig, decision["chosen_model"]))
        except TypeError as exc:  # an unknown or missing field: a decision of another version
            raise InputError(f"{Path(run_dir) / SELECTION_FILE}: the chosen model does not fit this version "
                             f"({exc})") from None
        config = chosen_model_train_config(config, data_dir)
        result = trainer.train(data_dir, run_dir, model, config, seed=seed, resume=resume, light_prior=light_prior,
                               progress=progress, stop_after=stop_after)
    return decision, result


def run_decisions(run_dir: str | Path) -> dict:
    """What a run needed, for reports: ``model chosen`` (the auto decision, else the trained model's name) and
    ``Gaussians`` (final count from train_summary.json; None when the run is unfinished)."""
    run_dir = Path(run_dir)
    info_path = run_dir / "run.json"
    if not info_path.is_file():
        raise FileNotFoundError(f"{run_dir}: not a training run (no run.json)")
    chosen = read_json(info_path, "run description", ("model",))["model"]
    selection = run_dir / SELECTION_FILE
    if selection.is_file():
        chosen = read_json(selection, "model selection decision", ("chosen",))["chosen"]
    summary = run_dir / "train_summary.json"
    gaussians = read_json(summary, "training summary", ("num_gaussians",))["num_gaussians"] \
        if summary.is_file() else None
    return {"model chosen": chosen, "Gaussians": gaussians}


def selection_config(tolerance_db: float | None = None, search: str | None = None,
                     trusted_start_reflectance: str | None = None) -> SelectionConfig:
    """SelectionConfig with the given fields changed (None keeps the default)."""
    changes = {k: v for k, v in (("tolerance_db", tolerance_db), ("search", search),
                                 ("trusted_start_reflectance", trusted_start_reflectance)) if v is not None}
    return dataclasses.replace(SelectionConfig(), **changes)
