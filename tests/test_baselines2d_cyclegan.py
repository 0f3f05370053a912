"""Cycle-GAN baseline: learning on a synthetic unpaired set, bitwise resume, NaN guard, full-resolution translation."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest
import torch
from click.testing import CliRunner
from scipy.ndimage import zoom

from spotlessgs.baselines2d.cli import baseline2d
from spotlessgs.baselines2d.cyclegan import (
    CycleGANConfig,
    load_generator,
    preset,
    train_cyclegan,
    translate_folder,
    translate_image,
)
from spotlessgs.baselines2d.cyclegan import losses as losses_module
from spotlessgs.baselines2d.cyclegan.checkpoint import CHECKPOINT_FORMAT, load_checkpoint
from spotlessgs.baselines2d.cyclegan.pool import ImagePool
from spotlessgs.baselines2d.cyclegan.train import CycleGANTrainer
from spotlessgs.baselines2d.enhance import enhance_folder
from spotlessgs.io.colorspace import to_uint8
from spotlessgs.io.images import read_image, write_png
from spotlessgs.io.tensor_file import load_tree, save_tree

HEIGHT, WIDTH, COUNT = 48, 64, 8


def texture(rng: np.random.Generator) -> np.ndarray:
    """(48, 64, 3) smooth random texture in [0.35, 0.75] (evenly lit)."""
    base = rng.random((HEIGHT // 8 + 2, WIDTH // 8 + 2, 3))
    return 0.35 + 0.4 * zoom(base, (8, 8, 1), order=1)[:HEIGHT, :WIDTH]


def spotlight(img: np.ndarray) -> np.ndarray:
    """Multiply by a centred spotlight fall-off (about 0.1 in the corners), slightly over-exposed at the centre."""
    h, w = img.shape[:2]
    yy, xx = np.mgrid[0:h, 0:w]
    fall_off = np.exp(-(((yy - h / 2) ** 2 + (xx - w / 2) ** 2) / (0.35 * max(h, w)) ** 2))
    return np.clip(img * fall_off[..., None] * 1.4, 0.0, 1.0)


def corner_centre_ratio(img: np.ndarray) -> float:
    """Mean brightness of the four corner patches over that of the centre patch (1 = evenly lit)."""
    h, w = img.shape[:2]
    k = max(h // 5, 1)
    grey = img.mean(axis=2)
    corners = np.mean([grey[:k, :k].mean(), grey[:k, -k:].mean(), grey[-k:, :k].mean(), grey[-k:, -k:].mean()])
    centre = grey[h // 2 - k // 2 : h // 2 + k // 2 + 1, w // 2 - k // 2 : w // 2 + k // 2 + 1].mean()
    return float(corners / centre)


@pytest.fixture(scope="module")
def unpaired(tmp_path_factory):
    """Uneven images of some textures and evenly lit images of OTHER textures; returns (root, truths of uneven)."""
    root = tmp_path_factory.mktemp("unpaired")
    rng = np.random.default_rng(0)
    truths = []
    for i in range(COUNT):
        truth = texture(rng)
        truths.append(truth)
        write_png(root / "uneven" / f"u{i}.png", spotlight(truth))
        write_png(root / "even" / f"e{i}.png", texture(rng))
    return root, truths


def short_config(**overrides) -> CycleGANConfig:
    return preset("tiny", **{"steps": 6, "checkpoint_every": 3, "log_every": 1, **overrides})


@pytest.fixture(scope="module")
def trained(unpaired):
    root, _ = unpaired
    checkpoint = train_cyclegan(root / "uneven", root / "even", root / "run", preset("tiny"), seed=0, progress=False)
    return checkpoint


def test_training_makes_outputs_more_even(unpaired, trained):
    root, truths = unpaired
    records = [json.loads(line) for line in (root / "run" / "metrics.jsonl").read_text().splitlines()]
    assert [r["step"] for r in records] == list(range(5, 61, 5))
    assert records[-1]["loss_G"] < 0.7 * records[0]["loss_G"]  # measured 10.7 -> ~5
    assert records[-1]["cycle_a"] < 0.7 * records[0]["cycle_a"]

    trained_g = load_generator(trained)
    untrained_g = CycleGANTrainer(preset("tiny"), seed=0).nets["G_ab"].eval()
    ratio_in, ratio_out, err_in, err_out, err_untrained = [], [], [], [], []
    for i, truth in enumerate(truths):
        uneven = read_image(root / "uneven" / f"u{i}.png")
        out = translate_image(trained_g, uneven)
        ratio_in.append(corner_centre_ratio(uneven))
        ratio_out.append(corner_centre_ratio(out))
        err_in.append(np.abs(uneven - truth).mean())
        err_out.append(np.abs(out - truth).mean())
        err_untrained.append(np.abs(translate_image(untrained_g, uneven) - truth).mean())
    # Measured: ratio 0.11 -> ~0.8; error to the evenly lit truth 0.26 (input), 0.12 (untrained: near-grey), ~0.08.
    assert np.mean(ratio_in) < 0.15
    assert np.mean(ratio_out) > 0.5
    assert np.mean(err_out) < 0.5 * np.mean(err_in)
    assert np.mean(err_out) < 0.85 * np.mean(err_untrained)


def _states_equal(x, y) -> bool:
    """Bitwise equality of nested dicts/lists of tensors and plain values."""
    if isinstance(x, torch.Tensor):
        return isinstance(y, torch.Tensor) and x.dtype == y.dtype and torch.equal(x, y)
    if isinstance(x, dict):
        return isinstance(y, dict) and x.keys() == y.keys() and all(_states_equal(x[k], y[k]) for k in x)
    if isinstance(x, (list, tuple)):
        return isinstance(y, (list, tuple)) and len(x) == len(y) and all(map(_states_equal, x, y))
    return x == y


class _Interrupt(Exception):
    pass


def _train_interrupted(root, out, config, monkeypatch, at_step: int) -> None:
    """Train into ``out`` with a kill simulated when step ``at_step`` begins (its checkpoint: the last before it)."""
    original_step = CycleGANTrainer.train_step

    def interrupted(self, *args, **kwargs):
        if self.step == at_step:
            raise _Interrupt("simulated kill")
        return original_step(self, *args, **kwargs)

    monkeypatch.setattr(CycleGANTrainer, "train_step", interrupted)
    with pytest.raises(_Interrupt):
        train_cyclegan(root / "uneven", root / "even", out, config, seed=5, progress=False)
    monkeypatch.setattr(CycleGANTrainer, "train_step", original_step)


def test_resume_gives_bitwise_the_uninterrupted_weights(unpaired, tmp_path, monkeypatch):
    root, _ = unpaired
    config = short_config()
    whole = train_cyclegan(root / "uneven", root / "even", tmp_path / "whole", config, seed=5, progress=False)
    _train_interrupted(root, tmp_path / "resumed", config, monkeypatch, at_step=4)
    assert load_checkpoint(tmp_path / "resumed" / "checkpoint.safetensors")["step"] == 3
    resumed = train_cyclegan(root / "uneven", root / "even", tmp_path / "resumed", config, seed=5, progress=False)

    a, b = load_checkpoint(whole), load_checkpoint(resumed)
    assert a["step"] == b["step"] == 6
    assert _states_equal(a["networks"], b["networks"])
    assert _states_equal(a["optimizers"], b["optimizers"])
    assert _states_equal(a["pools"], b["pools"])
    strip = [{k: v for k, v in json.loads(line).items() if k != "seconds"} for line in
             (tmp_path / "whole" / "metrics.jsonl").read_text().splitlines()]  # fmt: skip
    strip_resumed = [{k: v for k, v in json.loads(line).items() if k != "seconds"} for line in
                     (tmp_path / "resumed" / "metrics.jsonl").read_text().splitlines()]  # fmt: skip
    assert strip == strip_resumed and [r["step"] for r in strip] == [1, 2, 3, 4, 5, 6]

    other_seed = load_checkpoint(
        train_cyclegan(root / "uneven", root / "even", tmp_path / "seed6", config, seed=6, progress=False)
    )
    assert not _states_equal(a["networks"], other_seed["networks"])

    # A finished run is not trained further when called again.
    before = whole.stat().st_mtime_ns
    assert train_cyclegan(root / "uneven", root / "even", tmp_path / "whole", config, seed=5, progress=False) == whole
    assert whole.stat().st_mtime_ns == before


def test_resume_refuses_a_different_run(unpaired, tmp_path):
    root, _ = unpaired
    config = short_config(steps=3)
    train_cyclegan(root / "uneven", root / "even", tmp_path / "run", config, seed=1, progress=False)
    with pytest.raises(ValueError, match=r"config differs \(lr: 0.0002 -> 0.001\); use a new output folder"):
        train_cyclegan(root / "uneven", root / "even", tmp_path / "run", short_config(steps=3, lr=1e-3), seed=1)
    with pytest.raises(ValueError, match="checkpoint seed 1 != requested seed 2"):
        train_cyclegan(root / "uneven", root / "even", tmp_path / "run", config, seed=2)
    with pytest.raises(ValueError, match="training images differ"):
        train_cyclegan(root / "even", root / "uneven", tmp_path / "run", config, seed=1)
    # Settings that do not change the computation may differ.
    train_cyclegan(root / "uneven", root / "even", tmp_path / "run", short_config(steps=3, log_every=2), seed=1)


def test_training_leaves_global_state_alone(unpaired, tmp_path):
    root, _ = unpaired
    torch_state, numpy_state = torch.get_rng_state(), np.random.get_state()
    threads = torch.get_num_threads()
    train_cyclegan(root / "uneven", root / "even", tmp_path / "run", short_config(steps=2), seed=0, progress=False)
    assert torch.equal(torch.get_rng_state(), torch_state)
    assert np.array_equal(np.random.get_state()[1], numpy_state[1])
    assert torch.get_num_threads() == threads


def test_nan_guard_stops_and_keeps_the_last_good_checkpoint(unpaired, tmp_path, monkeypatch):
    root, _ = unpaired
    config = short_config()
    calls = {"n": 0}
    original = losses_module.lsgan_loss
    calls_per_step = 6  # 2 generator terms + 4 discriminator terms

    def poisoned(scores, target_is_real):
        calls["n"] += 1
        value = original(scores, target_is_real)
        return value * float("nan") if calls["n"] > 4 * calls_per_step else value

    monkeypatch.setattr(losses_module, "lsgan_loss", poisoned)
    with pytest.raises(
        FloatingPointError,
        match=r"diverged: loss_G = nan at step 4; the last good checkpoint .*checkpoint\.safetensors \(step 3\) is kept",
    ):
        train_cyclegan(root / "uneven", root / "even", tmp_path / "run", config, seed=0, progress=False)
    state = load_checkpoint(tmp_path / "run" / "checkpoint.safetensors")
    assert state["step"] == 3
    assert all(torch.isfinite(t).all() for net in state["networks"].values() for t in net.values())
    records = [json.loads(line) for line in (tmp_path / "run" / "metrics.jsonl").read_text().splitlines()]
    assert [r["step"] for r in records] == [1, 2, 3]

    calls["n"] = 10**9  # poisoned from the first call: a fresh run fails before its first checkpoint
    with pytest.raises(FloatingPointError, match="no checkpoint had been written yet"):
        train_cyclegan(root / "uneven", root / "even", tmp_path / "fresh", config, seed=0, progress=False)
    assert not any((tmp_path / "fresh").glob("checkpoint.*"))


def test_non_finite_weights_are_named():
    trainer = CycleGANTrainer(short_config(), seed=0)
    assert trainer.non_finite_parameters() == []
    with torch.no_grad():
        trainer.nets["D_b"].model[0].bias[0] = float("inf")
    assert trainer.non_finite_parameters() == ["D_b.model.0.bias"]


@pytest.mark.parametrize("direction", ["uneven_to_even", "even_to_uneven"])
def test_translate_folder_keeps_names_and_sizes(trained, tmp_path, direction):
    rng = np.random.default_rng(1)
    shapes = {"frame_a.png": (37, 53), "tiny.png": (1, 1), "odd.jpg": (5, 3), "square.png": (16, 16), "b.png": (48, 64)}
    for name, (h, w) in shapes.items():
        img = rng.random((h, w, 3))
        if name.endswith(".jpg"):
            from PIL import Image

            (tmp_path / "in").mkdir(exist_ok=True)
            Image.fromarray(to_uint8(img)).save(tmp_path / "in" / name, quality=95)
        else:
            write_png(tmp_path / "in" / name, img)
    written = translate_folder(trained, tmp_path / "in", tmp_path / "out", direction=direction)
    assert [p.name for p in written] == ["b.png", "frame_a.png", "odd.png", "square.png", "tiny.png"]
    generator = load_generator(trained, direction)
    for path in written:
        source = next(p for p in (tmp_path / "in").iterdir() if p.stem == path.stem)
        out = read_image(path)
        assert out.shape[:2] == shapes[source.name]
        np.testing.assert_array_equal(np.rint(out * 255), to_uint8(translate_image(generator, read_image(source))))


def test_translation_pads_only_when_needed(trained):
    """A size that is already a multiple of 4 (>= 16) goes through the generator as it is; others come back cropped."""
    generator = load_generator(trained)
    img = np.random.default_rng(2).random((24, 36, 3)).astype(np.float32)
    with torch.no_grad():
        direct = generator(torch.from_numpy(img.transpose(2, 0, 1))[None] * 2 - 1)[0].numpy().transpose(1, 2, 0)
    np.testing.assert_allclose(translate_image(generator, img), np.clip((direct + 1) / 2, 0, 1), atol=1e-6)
    for shape in [(23, 35), (2, 1), (17, 4)]:
        out = translate_image(generator, img[: shape[0], : shape[1]])
        assert out.shape == (*shape, 3) and np.isfinite(out).all() and out.min() >= 0 and out.max() <= 1


def test_an_older_versions_torch_checkpoint_is_translated_with_and_resumed_into_safetensors(unpaired, tmp_path,
                                                                                            monkeypatch):
    """A run folder of an older version (checkpoint.pt, a torch file) still translates, and resuming it gives bitwise
    the uninterrupted run's weights in checkpoint.safetensors, the old file removed."""
    root, _ = unpaired
    config = short_config()
    whole = train_cyclegan(root / "uneven", root / "even", tmp_path / "whole", config, seed=5, progress=False)
    _train_interrupted(root, tmp_path / "old", config, monkeypatch, at_step=3)
    current = tmp_path / "old" / "checkpoint.safetensors"
    torch.save(load_tree(current, CHECKPOINT_FORMAT), tmp_path / "old" / "checkpoint.pt")  # as older versions wrote
    current.unlink()
    legacy = translate_folder(tmp_path / "old" / "checkpoint.pt", root / "uneven", tmp_path / "translated")
    assert len(legacy) == len(list((root / "uneven").iterdir()))

    resumed = train_cyclegan(root / "uneven", root / "even", tmp_path / "old", config, seed=5, progress=False)
    assert resumed == current and not (tmp_path / "old" / "checkpoint.pt").exists()
    a, b = load_checkpoint(whole), load_checkpoint(resumed)
    assert a["step"] == b["step"] == 6
    assert _states_equal(a["networks"], b["networks"]) and _states_equal(a["optimizers"], b["optimizers"])


def test_checkpoint_errors(tmp_path, trained):
    with pytest.raises(FileNotFoundError, match="Cycle-GAN checkpoint not found"):
        load_checkpoint(tmp_path / "missing.pt")
    (tmp_path / "garbage.pt").write_bytes(b"not a torch file")
    with pytest.raises(ValueError, match="cannot read Cycle-GAN checkpoint"):
        load_checkpoint(tmp_path / "garbage.pt")
    torch.save({"format": "something-else"}, tmp_path / "foreign.pt")
    with pytest.raises(ValueError, match="not a Cycle-GAN checkpoint"):
        load_checkpoint(tmp_path / "foreign.pt")
    (tmp_path / "garbage.safetensors").write_bytes(b"not a safetensors file")
    with pytest.raises(ValueError, match=r"garbage\.safetensors: not a readable safetensors file .*\(not a Cycle-GAN "
                                         r"checkpoint\)"):
        load_checkpoint(tmp_path / "garbage.safetensors")
    save_tree(tmp_path / "other.safetensors", {"step": 1}, "spotlessgs-checkpoint")  # a 3D run's checkpoint
    with pytest.raises(ValueError, match=r"other\.safetensors: holds 'spotlessgs-checkpoint', expected "
                                         r"'spotlessgs-cyclegan-v1' \(not a Cycle-GAN checkpoint\)"):
        load_checkpoint(tmp_path / "other.safetensors")
    with pytest.raises(ValueError, match="unknown direction 'sideways'"):
        load_generator(trained, "sideways")


def test_data_errors(unpaired, tmp_path):
    root, _ = unpaired
    with pytest.raises(ValueError, match=r"u0.png: uneven image is 48x64 pixels, smaller than the training crop 64x64"):
        train_cyclegan(root / "uneven", root / "even", tmp_path / "run", short_config(crop_height=64, crop_width=64))
    with pytest.raises(FileNotFoundError, match="image folder not found"):
        train_cyclegan(tmp_path / "nowhere", root / "even", tmp_path / "run", short_config())
    with pytest.raises(ValueError, match="no even image folders were given"):
        train_cyclegan(root / "uneven", [], tmp_path / "run", short_config())


@pytest.mark.parametrize(
    "overrides, match",
    [
        ({"crop_height": 30}, "must be a multiple of 2\\*\\*n_down = 4"),
        ({"crop_height": 8, "crop_width": 8, "disc_layers": 3}, "too small for a discriminator"),
        ({"steps": 0}, "steps must be a positive integer"),
        ({"lr": 0.0}, "lr must be positive"),
        ({"decay_start": 1.5}, "decay_start must be in"),
        ({"num_threads": 0}, "num_threads must be None or a positive integer"),
        ({"pool_size": -1}, "pool_size must be a non-negative integer"),
    ],
)
def test_config_errors(overrides, match):
    with pytest.raises(ValueError, match=match):
        preset("tiny", **overrides)


def test_presets_and_config_round_trip():
    with pytest.raises(ValueError, match="unknown CycleGAN preset 'huge'"):
        preset("huge")
    for name in ("tiny", "quick", "paper"):
        config = preset(name)
        assert CycleGANConfig.from_dict(config.to_dict()) == config
    with pytest.raises(ValueError, match=r"unknown fields \['colour'\]"):
        CycleGANConfig.from_dict({**preset("tiny").to_dict(), "colour": 1})
    quick = preset("quick")
    assert (quick.n_down, quick.lambda_cycle, quick.lambda_identity, quick.pool_size) == (2, 10.0, 0.5, 50)
    assert (quick.lr, quick.beta1, quick.beta2) == (2e-4, 0.5, 0.999)


def test_learning_rate_schedule():
    trainer = CycleGANTrainer(preset("tiny", steps=10, decay_start=0.5), seed=0)
    rates = [trainer.learning_rate(s) for s in range(10)]
    assert rates[:6] == [2e-4] * 6
    np.testing.assert_allclose(rates[6:], 2e-4 * (1 - np.arange(1, 5) / 6))


def test_image_pool():
    pool = ImagePool(2)
    rng = np.random.default_rng(0)
    first = torch.zeros(2, 3, 4, 4)
    assert torch.equal(pool.query(first, rng), first)  # filling: new images come back
    ones = torch.ones(50, 3, 4, 4)
    out = pool.query(ones, rng)
    returned_old = int((out.flatten(1).amax(1) == 0).sum())
    assert returned_old == 2  # both stored zeros are handed out once, replaced by ones
    assert all(torch.equal(img, torch.ones(3, 4, 4)) for img in pool.state())
    restored = ImagePool(2)
    restored.load_state(pool.state())
    assert all(torch.equal(a, b) for a, b in zip(restored.state(), pool.state()))
    with pytest.raises(ValueError, match="more than the pool size 1"):
        ImagePool(1).load_state(pool.state())
    assert torch.equal(ImagePool(0).query(ones, rng), ones)


def test_enhance_folder_and_cli_with_cyclegan(unpaired, trained, tmp_path):
    root, _ = unpaired
    written = enhance_folder("cyclegan", root / "uneven", tmp_path / "out", checkpoint=trained)
    assert [p.name for p in written] == [f"u{i}.png" for i in range(COUNT)]
    record = json.loads((tmp_path / "out" / "baseline2d_provenance.json").read_text())
    assert record["method"] == "cyclegan" and record["settings"]["checkpoint"] == str(trained)
    assert record["settings"]["checkpoint_sha256"] == hashlib.sha256(trained.read_bytes()).hexdigest()
    with pytest.raises(ValueError, match=r"unknown options \['clip_limit'\] for method 'cyclegan'"):
        enhance_folder("cyclegan", root / "uneven", tmp_path / "out", checkpoint=trained, clip_limit=2)

    runner = CliRunner()
    result = runner.invoke(
        baseline2d,
        ["train-cyclegan", "--uneven", str(root / "uneven"), "--even", str(root / "even"), "--out",
         str(tmp_path / "cli_run"), "--preset", "tiny", "--steps", "2", "--no-progress"],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    checkpoint = Path(result.output.strip().splitlines()[-1])
    assert load_checkpoint(checkpoint)["step"] == 2
    result = runner.invoke(
        baseline2d,
        ["enhance", "cyclegan", str(root / "even"), str(tmp_path / "cli_out"), "--checkpoint", str(checkpoint.parent)],
    )  # the run folder names its checkpoint
    assert result.exit_code == 0, result.output
    record = json.loads((tmp_path / "cli_out" / "baseline2d_provenance.json").read_text())
    assert record["settings"]["checkpoint"] == str(checkpoint)
    result = runner.invoke(baseline2d, ["enhance", "cyclegan", str(root / "even"), str(tmp_path / "cli_out"),
                                        "--checkpoint", str(tmp_path)])
    assert result.exit_code != 0 and "holds no Cycle-GAN checkpoint" in str(result.exception or result.output)
    assert sorted(p.name for p in (tmp_path / "cli_out").glob("*.png")) == [f"e{i}.png" for i in range(COUNT)]
    args = ["enhance", "msrcr", str(root / "even"), str(tmp_path / "x"), "--clip-limit", "2"]
    result = runner.invoke(baseline2d, args)
    assert result.exit_code != 0 and "options ['clip_limit'] do not apply to method 'msrcr'" in result.output
    result = runner.invoke(baseline2d, ["enhance", "clahe", str(root / "even"), str(tmp_path / "c"), "--tiles", "4"])
    assert result.exit_code == 0 and len(list((tmp_path / "c").glob("*.png"))) == COUNT


def _edited(trained: Path, where: Path, edit) -> Path:
    """A copy of the trained run's checkpoint, changed by ``edit(state)`` (the file's dict), at ``where``."""
    state = load_tree(trained, CHECKPOINT_FORMAT)
    edit(state)
    save_tree(where, state, CHECKPOINT_FORMAT)
    return where


@pytest.mark.parametrize("edit, problem", [
    (lambda s: s["networks"]["G_ab"].update({k: v[:1] for k, v in list(s["networks"]["G_ab"].items())[:1]}),
     r"its network G_ab does not fit this model \(Error\(s\) in loading state_dict"),
    (lambda s: s["networks"].pop("D_b"), r"it lacks the network\(s\) \['D_b'\]"),
    (lambda s: next(iter(s["networks"]["G_ab"].values())).fill_(float("nan")), r"G_ab\..* not finite"),
    (lambda s: s.update(step=10**6), r"step 1000000 is outside the run's 0\.\.\d+"),
    (lambda s: s.update(step=-3), r"step -3 is outside"),
    (lambda s: s.update(seed="abc"), r"seed 'abc' is not a whole number"),
    (lambda s: s.update(config=[1, 2]), r"config is not a table of settings"),
    (lambda s: s.update(pools=5), r"pools is not a table"),
])
def test_a_damaged_checkpoint_is_one_line_naming_it(trained, unpaired, tmp_path, edit, problem):
    """Translating with, or resuming from, a hand-edited checkpoint names the file and the problem (were tracebacks,
    a multi-line state-dict message, or a resume that trained nothing or trained past its steps)."""
    from spotlessgs.io.errors import InputError

    root, _ = unpaired
    bad = _edited(trained, tmp_path / "checkpoint.safetensors", edit)
    with pytest.raises(InputError, match=rf"checkpoint\.safetensors: .*{problem}") as info:
        translate_folder(bad, root / "uneven", tmp_path / "out")
    assert "\n" not in str(info.value)
    run = tmp_path / "run"
    run.mkdir()
    bad.rename(run / "checkpoint.safetensors")
    with pytest.raises(InputError, match=rf"checkpoint\.safetensors: .*{problem}"):
        train_cyclegan(root / "uneven", root / "even", run, preset("tiny"), seed=0, progress=False)


def test_a_damaged_metrics_log_or_a_foreign_out_folder_is_refused_before_training(trained, unpaired, tmp_path):
    import shutil

    from spotlessgs.io.errors import InputError

    root, _ = unpaired
    run = shutil.copytree(trained.parent, tmp_path / "run")
    for line, problem in (("5", "line 1 is not a record with a whole-number step"),
                          ('{"step": "x"}', "line 1 is not a record with a whole-number step"),
                          ('{"step": 1, "loss_G": NaN}', "line 1 holds a value that is not finite")):
        (run / "metrics.jsonl").write_text(line + "\n")
        stamp = (run / "checkpoint.safetensors").stat().st_mtime_ns
        with pytest.raises(InputError, match=rf"metrics\.jsonl: {problem}"):
            train_cyclegan(root / "uneven", root / "even", run, preset("tiny"), seed=0, progress=False)
        assert (run / "checkpoint.safetensors").stat().st_mtime_ns == stamp

    other = tmp_path / "other"
    other.mkdir()
    (other / "metrics.jsonl").write_text('{"step": 1}\n')  # another tool's run
    with pytest.raises(InputError, match=r"other: holds files but no checkpoint\.safetensors or checkpoint\.pt or "
                                         r"provenance\.json \(metrics\.jsonl\): not a Cycle-GAN run"):
        train_cyclegan(root / "uneven", root / "even", other, preset("tiny"), seed=0, progress=False)
    assert (other / "metrics.jsonl").read_text() == '{"step": 1}\n'


@pytest.mark.parametrize("command", [["enhance", "cyclegan", "IN", "OUT", "--checkpoint", "CKPT"],
                                     ["train-cyclegan", "--uneven", "IN", "--even", "IN", "--out", "OUT"]])
def test_a_thread_count_beyond_the_limit_is_a_usage_error(trained, unpaired, tmp_path, command):
    """torch crashed (enhance) or hung (train) when asked for 100,000 threads."""
    root, _ = unpaired
    paths = {"IN": str(root / "uneven"), "OUT": str(tmp_path / "out"), "CKPT": str(trained)}
    result = CliRunner().invoke(baseline2d, [paths.get(a, a) for a in command] + ["--threads", "100000"])
    assert result.exit_code == 2 and "100000 is not in the range 1<=x<=1024" in result.output, result.output
    assert not (tmp_path / "out").exists()
