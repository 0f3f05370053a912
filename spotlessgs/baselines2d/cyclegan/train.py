"""Training the Cycle-GAN baseline on unpaired folders: uneven (spotlight-lit) images -> evenly lit images.

Domain a = uneven, domain b = even. Per step (Zhu et al. 2017): generators first (LSGAN + lambda * cycle L1 +
lambda * lambda_identity * identity L1, discriminators frozen), then discriminators (0.5 * LSGAN on real and pooled
fake images). Adam for each pair; constant learning rate, then a linear decay to zero.

Output folder: ``checkpoint.safetensors`` (latest good state, rewritten atomically every ``checkpoint_every`` steps
and at the end), ``metrics.jsonl`` (one JSON record per ``log_every`` steps, rewritten with each checkpoint so it
never runs ahead of it) and ``provenance.json``. Calling ``train_cyclegan`` again on the same folder continues from the
checkpoint and gives bitwise the weights of an uninterrupted run (same thread count).
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import time
from pathlib import Path
from typing import Any, Iterable, Iterator

import torch
from tqdm import tqdm

from spotlessgs.baselines2d.cyclegan import losses
from spotlessgs.baselines2d.cyclegan.checkpoint import (
    CHECKPOINT_FORMAT,
    CHECKPOINT_NAME,
    LEGACY_CHECKPOINT_NAME,
    existing_checkpoint,
    load_checkpoint,
    restore,
    save_checkpoint,
)
from spotlessgs.baselines2d.cyclegan.config import PRESETS, CycleGANConfig
from spotlessgs.baselines2d.cyclegan.data import ImageDomain, domain_fingerprint, load_domain, sample_crops
from spotlessgs.baselines2d.cyclegan.networks import build_discriminator, build_generator, init_weights
from spotlessgs.baselines2d.cyclegan.pool import ImagePool
from spotlessgs.io.atomic import write_json, write_text
from spotlessgs.io.errors import InputError
from spotlessgs.io.folder_lock import folder_lock
from spotlessgs.io.paths import refuse_foreign_folder, refuse_overlap
from spotlessgs.io.provenance import provenance
from spotlessgs.io.seeding import numpy_rng, torch_generator

METRICS_NAME = "metrics.jsonl"
PROVENANCE_NAME = "provenance.json"
# Config fields that may differ when resuming: they do not change the computation.
_RESUMABLE_CHANGES = frozenset({"num_threads", "checkpoint_every", "log_every"})


class NonFiniteLossError(FloatingPointError):
    """A loss became NaN or infinite during a training step."""


@contextlib.contextmanager
def torch_threads(count: int | None) -> Iterator[None]:
    """Use ``count`` torch intra-op threads inside the block (None: unchanged), restoring the previous setting."""
    previous = torch.get_num_threads()
    if count is not None:
        torch.set_num_threads(count)
    try:
        yield
    finally:
        torch.set_num_threads(previous)


class CycleGANTrainer:
    """Networks, optimisers, image pools and the step counter of one Cycle-GAN run."""

    def __init__(self, config: CycleGANConfig, seed: int) -> None:
        self.config = config
        self.seed = int(seed)
        self.step = 0
        self.nets = {
            "G_ab": build_generator(config),
            "G_ba": build_generator(config),
            "D_a": build_discriminator(config),
            "D_b": build_discriminator(config),
        }
        for name, net in self.nets.items():
            init_weights(net, config.init_std, torch_generator(seed, f"cyclegan/init/{name}"))
        betas = (config.beta1, config.beta2)
        self.opt_g = torch.optim.Adam(
            [*self.nets["G_ab"].parameters(), *self.nets["G_ba"].parameters()], lr=config.lr, betas=betas
        )
        self.opt_d = torch.optim.Adam(
            [*self.nets["D_a"].parameters(), *self.nets["D_b"].parameters()], lr=config.lr, betas=betas
        )
        self.pool_a = ImagePool(config.pool_size)  # generated uneven images, for D_a
        self.pool_b = ImagePool(config.pool_size)  # generated even images, for D_b

    def learning_rate(self, step: int) -> float:
        """Constant until ``decay_start * steps``, then linear towards zero (never reaching it)."""
        begin = int(self.config.decay_start * self.config.steps)
        return self.config.lr * (1.0 - max(0, step - begin) / (self.config.steps - begin + 1))

    def train_step(self, real_a: torch.Tensor, real_b: torch.Tensor, rng) -> dict[str, float]:
        """One generator update and one discriminator update; returns the losses of this step.

        Args:
            real_a: (B, 3, h, w) uneven crops in [-1, 1]. real_b: (B, 3, h, w) even crops in [-1, 1].
            rng: numpy Generator for the image pools.
        Raises:
            NonFiniteLossError before any parameter is changed by a non-finite loss.
        """
        cfg = self.config
        g_ab, g_ba, d_a, d_b = (self.nets[k] for k in ("G_ab", "G_ba", "D_a", "D_b"))
        lr = self.learning_rate(self.step)
        for group in (*self.opt_g.param_groups, *self.opt_d.param_groups):
            group["lr"] = lr

        fake_b, fake_a = g_ab(real_a), g_ba(real_b)
        rec_a, rec_b = g_ba(fake_b), g_ab(fake_a)
        for p in (*d_a.parameters(), *d_b.parameters()):
            p.requires_grad_(False)
        terms = {
            "gan_ab": losses.lsgan_loss(d_b(fake_b), True),
            "gan_ba": losses.lsgan_loss(d_a(fake_a), True),
            "cycle_a": cfg.lambda_cycle * losses.l1_loss(rec_a, real_a),
            "cycle_b": cfg.lambda_cycle * losses.l1_loss(rec_b, real_b),
        }
        if cfg.lambda_identity > 0:
            weight = cfg.lambda_cycle * cfg.lambda_identity
            terms["identity_a"] = weight * losses.l1_loss(g_ba(real_a), real_a)
            terms["identity_b"] = weight * losses.l1_loss(g_ab(real_b), real_b)
        loss_g = sum(terms.values())
        self._check_finite("loss_G", loss_g)
        self.opt_g.zero_grad(set_to_none=True)
        loss_g.backward()
        self.opt_g.step()

        for p in (*d_a.parameters(), *d_b.parameters()):
            p.requires_grad_(True)
        pooled_b = self.pool_b.query(fake_b.detach(), rng)
        pooled_a = self.pool_a.query(fake_a.detach(), rng)
        loss_d_b = 0.5 * (losses.lsgan_loss(d_b(real_b), True) + losses.lsgan_loss(d_b(pooled_b), False))
        loss_d_a = 0.5 * (losses.lsgan_loss(d_a(real_a), True) + losses.lsgan_loss(d_a(pooled_a), False))
        loss_d = loss_d_a + loss_d_b
        self._check_finite("loss_D", loss_d)
        self.opt_d.zero_grad(set_to_none=True)
        loss_d.backward()
        self.opt_d.step()
        self.step += 1

        record = {name: float(value.detach()) for name, value in terms.items()}
        record.update(loss_G=float(loss_g.detach()), loss_D_a=float(loss_d_a.detach()), lr=lr)
        record["loss_D_b"] = float(loss_d_b.detach())
        return record

    def _check_finite(self, name: str, value: torch.Tensor) -> None:
        if not torch.isfinite(value).all():
            raise NonFiniteLossError(f"{name} = {float(value.detach())} at step {self.step}")

    def non_finite_parameters(self) -> list[str]:
        """Names ('net.param') of parameters holding NaN or inf."""
        return [
            f"{net_name}.{name}"
            for net_name, net in self.nets.items()
            for name, param in net.named_parameters()
            if not torch.isfinite(param).all()
        ]

    def state(self, fingerprints: dict[str, str]) -> dict[str, Any]:
        """Everything needed to continue bitwise: networks, optimisers, pools, step."""
        return {
            "format": CHECKPOINT_FORMAT,
            "config": self.config.to_dict(),
            "seed": self.seed,
            "step": self.step,
            "fingerprints": dict(fingerprints),
            "networks": {name: net.state_dict() for name, net in self.nets.items()},
            "optimizers": {"G": self.opt_g.state_dict(), "D": self.opt_d.state_dict()},
            "pools": {"a": self.pool_a.state(), "b": self.pool_b.state()},
        }

    def load_state(self, state: dict[str, Any], source: Path) -> None:
        """Restore from ``state()`` (networks, optimisers, pools, step), as read from ``source`` (named by the
        InputError a part that does not fit raises)."""
        for name, net in self.nets.items():
            restore(source, f"network {name}", lambda: net.load_state_dict(state["networks"][name]))
        for key, opt in (("G", self.opt_g), ("D", self.opt_d)):
            restore(source, f"optimiser {key}", lambda: opt.load_state_dict(state["optimizers"][key]))
            moments = [v for group in opt.state.values() for v in group.values() if isinstance(v, torch.Tensor)]
            if any(v.is_floating_point() and not torch.isfinite(v).all() for v in moments):
                raise InputError(f"{source}: damaged Cycle-GAN checkpoint: optimiser {key} holds values that are "
                                 "not finite")
        for key, pool in (("a", self.pool_a), ("b", self.pool_b)):
            restore(source, f"image pool {key}", lambda: pool.load_state(state["pools"][key]))
        self.step = int(state["step"])


def _as_folder_list(dirs: str | os.PathLike | Iterable[str | os.PathLike]) -> list[Path]:
    if isinstance(dirs, (str, os.PathLike)):
        return [Path(dirs)]
    return [Path(d) for d in dirs]


def _check_resume(state: dict[str, Any], config: CycleGANConfig, seed: int, fingerprints: dict[str, str], path: Path):
    saved: CycleGANConfig = state["config"]
    changed = sorted(
        k for k, v in config.to_dict().items() if saved.to_dict()[k] != v and k not in _RESUMABLE_CHANGES
    )
    if changed:
        detail = ", ".join(f"{k}: {saved.to_dict()[k]!r} -> {config.to_dict()[k]!r}" for k in changed)
        raise ValueError(f"{path}: cannot resume, the config differs ({detail}); use a new output folder")
    if int(state["seed"]) != int(seed):
        raise ValueError(f"{path}: cannot resume, checkpoint seed {state['seed']} != requested seed {seed}")
    if state.get("fingerprints") != fingerprints:
        raise ValueError(f"{path}: cannot resume, the training images differ from those of the checkpoint")


def _read_metrics(path: Path, up_to_step: int) -> list[dict[str, Any]]:
    """The records of ``metrics.jsonl`` up to ``up_to_step``; InputError naming the file and line for a record that
    is not a JSON object with a whole-number ``step`` and finite numbers (checked before anything is trained)."""
    if not path.is_file():
        return []
    records = []
    for number, line in enumerate(path.read_text().splitlines(), start=1):
        if not line.strip():
            continue
        try:
            record = json.loads(line)
        except json.JSONDecodeError as exc:
            raise InputError(f"{path}: line {number} is not JSON ({exc})") from None
        step = record.get("step") if isinstance(record, dict) else None
        if isinstance(step, bool) or not isinstance(step, int):
            raise InputError(f"{path}: line {number} is not a record with a whole-number step")
        if any(isinstance(v, float) and not math.isfinite(v) for v in record.values()):
            raise InputError(f"{path}: line {number} holds a value that is not finite")
        if step <= up_to_step:
            records.append(record)
    return records


def _write_metrics(path: Path, records: list[dict[str, Any]]) -> None:
    write_text(path, "".join(json.dumps(r, allow_nan=False) + "\n" for r in records))


def train_cyclegan(
    uneven_dirs: str | os.PathLike | Iterable[str | os.PathLike],
    even_dirs: str | os.PathLike | Iterable[str | os.PathLike],
    out_dir: str | os.PathLike,
    config: CycleGANConfig = PRESETS["quick"],
    seed: int = 0,
    progress: bool = True,
) -> Path:
    """Train uneven -> even translation on unpaired folders; resume from the checkpoint in ``out_dir`` when
    there is one (``checkpoint.safetensors``, or an older version's ``checkpoint.pt``).

    Args:
        uneven_dirs: folder(s) of spotlight-lit images (domain a).
        even_dirs: folder(s) of evenly lit images of OTHER scenes than the test scene (domain b).
        out_dir: output folder (created); holds checkpoint.safetensors, metrics.jsonl, provenance.json.
        config: network and optimisation settings.
        seed: seeds initialisation, crops and image pools (per stage, via spotlessgs.io.seeding).
        progress: show a tqdm progress bar.
    Returns:
        the path of the final checkpoint.
    Raises:
        FloatingPointError: a loss or weight became NaN/inf; the last good checkpoint is kept on disk.
        ValueError: unreadable/too small images, or a checkpoint from a different config, seed or data.
    """
    out_dir = Path(out_dir)
    uneven_folders, even_folders = _as_folder_list(uneven_dirs), _as_folder_list(even_dirs)
    refuse_overlap(out_dir, {f"--uneven/--even {d}": d for d in [*uneven_folders, *even_folders]}, "--out")
    metrics_path = out_dir / METRICS_NAME
    refuse_foreign_folder(out_dir, [CHECKPOINT_NAME, LEGACY_CHECKPOINT_NAME, PROVENANCE_NAME], "--out",
                          "a Cycle-GAN run (training would replace some of them)")
    domain_a = load_domain("uneven", uneven_folders, config.crop_height, config.crop_width)
    domain_b = load_domain("even", even_folders, config.crop_height, config.crop_width)
    fingerprints = {"uneven": domain_fingerprint(domain_a), "even": domain_fingerprint(domain_b)}
    out_dir.mkdir(parents=True, exist_ok=True)

    with folder_lock(out_dir, "spotless baseline2d train-cyclegan"), torch_threads(config.num_threads):
        trainer = CycleGANTrainer(config, seed)
        records: list[dict[str, Any]] = []
        found = existing_checkpoint(out_dir)
        if found is not None:
            state = load_checkpoint(found)
            _check_resume(state, config, seed, fingerprints, found)
            records = _read_metrics(metrics_path, int(state["step"]))
            trainer.load_state(state, found)
        else:
            write_json(
                out_dir / PROVENANCE_NAME,
                provenance(
                    seed=seed,
                    method="cyclegan",
                    config=config.to_dict(),
                    uneven_dirs=[str(p) for p in uneven_folders],
                    even_dirs=[str(p) for p in even_folders],
                    images={"uneven": len(domain_a.files), "even": len(domain_b.files)},
                    fingerprints=fingerprints,
                ),
            )
        _run_steps(trainer, domain_a, domain_b, fingerprints, out_dir, metrics_path, records, progress)
    return out_dir / CHECKPOINT_NAME


def _run_steps(
    trainer: CycleGANTrainer,
    domain_a: ImageDomain,
    domain_b: ImageDomain,
    fingerprints: dict[str, str],
    out_dir: Path,
    metrics_path: Path,
    records: list[dict[str, Any]],
    progress: bool,
) -> None:
    cfg = trainer.config
    sums: dict[str, float] = {}
    window = 0
    started = time.perf_counter()
    ckpt_path = existing_checkpoint(out_dir)  # the last good checkpoint, named when training diverges
    last_saved = trainer.step if ckpt_path is not None else None
    with tqdm(total=cfg.steps, initial=trainer.step, desc="cycle-gan", unit="step", disable=not progress) as bar:
        while trainer.step < cfg.steps:
            rng = numpy_rng(trainer.seed, f"cyclegan/step/{trainer.step}")
            real_a = sample_crops(domain_a, rng, cfg.batch_size, cfg.crop_height, cfg.crop_width, cfg.flip)
            real_b = sample_crops(domain_b, rng, cfg.batch_size, cfg.crop_height, cfg.crop_width, cfg.flip)
            try:
                step_losses = trainer.train_step(real_a, real_b, rng)
            except NonFiniteLossError as exc:
                raise FloatingPointError(_divergence_message(str(exc), ckpt_path, last_saved)) from exc
            for key, value in step_losses.items():
                sums[key] = sums.get(key, 0.0) + value
            window += 1
            bar.update(1)
            if trainer.step % cfg.log_every == 0 or trainer.step == cfg.steps:
                record = {"step": trainer.step, **{k: v / window for k, v in sums.items()}}
                record["lr"] = step_losses["lr"]
                record["seconds"] = round(time.perf_counter() - started, 3)
                records.append(record)
                loss_d = record["loss_D_a"] + record["loss_D_b"]
                bar.set_postfix(loss_G=f"{record['loss_G']:.3f}", loss_D=f"{loss_d:.3f}")
                sums, window = {}, 0
            if trainer.step % cfg.checkpoint_every == 0 or trainer.step == cfg.steps:
                bad = trainer.non_finite_parameters()
                if bad:
                    problem = f"non-finite weights {bad[:5]} after step {trainer.step}"
                    raise FloatingPointError(_divergence_message(problem, ckpt_path, last_saved))
                _write_metrics(metrics_path, records)  # first: a resume keeps the records up to its checkpoint's step
                ckpt_path = save_checkpoint(out_dir, trainer.state(fingerprints))
                last_saved = trainer.step


def _divergence_message(problem: str, ckpt_path: Path | None, last_saved: int | None) -> str:
    kept = (
        f"the last good checkpoint {ckpt_path} (step {last_saved}) is kept"
        if last_saved is not None
        else "no checkpoint had been written yet"
    )
    return (
        f"Cycle-GAN training diverged: {problem}; {kept}. Lower the learning rate or check the training images "
        f"for corrupt data."
    )
