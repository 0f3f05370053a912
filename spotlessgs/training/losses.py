"""Training losses. The photometric loss: (1 - λ) L1 + λ (1 - SSIM), with clipped input pixels handled one-sidedly, in
linear light or in sRGB-encoded values; the optional terms on the Gaussians' shape (normal shape, depth spread); and
the pose refinement's texture terms."""

from __future__ import annotations

import torch

from spotlessgs.io.colorspace import linear_to_srgb
from spotlessgs.metrics import ssim
from spotlessgs.training.config import LOSS_SPACES
# Slope of the sRGB encoding at 1, continued linearly above 1 by :func:`srgb_encoded` (1.055 / 2.4).
_SRGB_SLOPE_AT_ONE = 1.055 / 2.4


def srgb_encoded(x: torch.Tensor) -> torch.Tensor:
    """The sRGB encoding of linear values ≥ 0 (any shape), continued above 1 by its tangent there, so that a render
    brighter than the sensor's range still has a gradient (the encoding itself clamps at 1). Its slope is at most
    12.92, in the darkest values."""
    return torch.where(x <= 1.0, linear_to_srgb(x), 1.0 + _SRGB_SLOPE_AT_ONE * (x - 1.0))


def normal_shape_loss(normals: torch.Tensor, axes: torch.Tensor, visible: torch.Tensor) -> torch.Tensor:
    """mean(1 - |n̂·â|) over the ``visible`` (N,) bool Gaussians: 0 when every shading normal n̂ (N, 3) lies along its
    Gaussian's shortest axis â (N, 3) (either sign; both unit vectors), 1 when perpendicular; 0 with none visible."""
    if not bool(visible.any()):
        return normals.sum() * 0.0
    return (1.0 - (normals[visible] * axes[visible]).sum(-1).abs()).mean()


def normal_gravity_loss(normals: torch.Tensor, up: torch.Tensor, visible: torch.Tensor) -> torch.Tensor:
    """mean(min(c², (1 - |c|)²)), c = n̂·û, over the ``visible`` (N,) bool Gaussians: 0 when every shading normal n̂
    (N, 3) is horizontal (a wall's) or vertical (a floor's or a ceiling's) with respect to the unit up direction û (3,),
    each pulled towards the nearer of the two; 0 with none visible."""
    if not bool(visible.any()):
        return normals.sum() * 0.0
    c = normals[visible] @ up.to(normals)
    return torch.minimum(c * c, (1.0 - c.abs()) ** 2).mean()


def camera_up(c2w: torch.Tensor) -> torch.Tensor:
    """(3,) the unit world direction that the cameras' image "up" (−y, OpenCV axes) points along on average, of
    camera-to-world poses (N, 4, 4): the gravity axis of a robot's or a person's level camera."""
    return torch.nn.functional.normalize(-c2w[:, :3, 1].mean(0), dim=0)


#: Pixels whose accumulated opacity reaches this count for the depth-spread term (a surface, not its fringe).
DEPTH_SPREAD_MIN_ALPHA = 0.5


def ray_depth_statistics(moments: torch.Tensor, alpha: torch.Tensor, where: torch.Tensor
                         ) -> tuple[torch.Tensor, torch.Tensor]:
    """The mean and variance (M,) of the Gaussians' depths along the rays of the pixels ``where`` (H, W) bool (M of
    them), from the depth moments (H, W, 2) [S1, S2] = [Σ w z, Σ w z²] and the accumulated opacity A = Σ w (H, W):
    mean = S1 / A, variance = S2 / A - mean² (kept ≥ 0 against rounding)."""
    weight = alpha[where]
    mean = moments[..., 0][where] / weight
    return mean, (moments[..., 1][where] / weight - mean * mean).clamp_min(0.0)


def depth_spread_loss(moments: torch.Tensor, alpha: torch.Tensor) -> torch.Tensor:
    """The mean, over pixels with accumulated opacity A ≥ DEPTH_SPREAD_MIN_ALPHA, of the squared coefficient of
    variation of the Gaussians' depths along the pixel's ray, var / mean² with mean = S1 / A and var = S2 / A - mean²,
    from the depth moments (H, W, 2) [S1, S2] = [Σ w z, Σ w z²] (w the compositing weights) and A (H, W). Scale-free:
    a slab of Gaussians 10 % of its depth thick costs the same near and far. 0 (with a gradient) where no pixel
    counts."""
    covered = alpha >= DEPTH_SPREAD_MIN_ALPHA
    if not bool(covered.any()):
        return moments.sum() * 0.0
    mean, variance = ray_depth_statistics(moments, alpha, covered)
    return (variance / (mean * mean).clamp_min(1e-6)).mean()


def clipped_l1(pred: torch.Tensor, target: torch.Tensor, saturated: torch.Tensor) -> torch.Tensor:
    """Mean absolute error where clipped pixels only penalise predictions darker than the observation.

    A clipped pixel says only that the true radiance is at least the observed value, so there the error is
    ``max(0, target - pred)``: the model may explain a hot spot brighter than the sensor could record, and clipping
    cannot drag the spotlight model down.

    Args:
        pred: (H, W, 3) rendered linear image.
        target: (H, W, 3) observed linear image.
        saturated: (H, W) bool mask of clipped input pixels.
    """
    diff = pred - target
    err = torch.where(saturated[..., None], torch.relu(-diff), diff.abs())
    return err.mean()


def photometric_loss(
    pred: torch.Tensor, target: torch.Tensor, saturated: torch.Tensor, ssim_lambda: float = 0.2,
    space: str = "linear",
) -> tuple[torch.Tensor, dict[str, float]]:
    """(1 - λ) clipped L1 + λ (1 - SSIM) between a render and an input view.

    SSIM compares the render clamped to the recordable range [0, 1] with the input (where the input is clipped, a
    brighter render clamps to the same value). Shapes: pred, target (H, W, 3) linear; saturated (H, W).
    ``space`` "srgb" compares both after :func:`srgb_encoded` (monotonic, so clipped pixels keep their one-sided
    error): a dim pixel then counts about as much as it shows, not about ten times less than the hot spot.

    Returns:
        the loss (scalar tensor) and its parts as floats (``l1``, ``ssim``).
    """
    if space not in LOSS_SPACES:
        raise ValueError(f"unknown loss space {space!r}; choose one of {LOSS_SPACES}")
    if space == "srgb":
        pred, target = srgb_encoded(pred), srgb_encoded(target)
    l1 = clipped_l1(pred, target, saturated)
    if ssim_lambda > 0:
        s = ssim(pred.clamp(0.0, 1.0).permute(2, 0, 1)[None], target.permute(2, 0, 1)[None])[0]
        loss = (1.0 - ssim_lambda) * l1 + ssim_lambda * (1.0 - s)
        return loss, {"l1": float(l1.detach()), "ssim": float(s.detach())}
    return l1, {"l1": float(l1.detach()), "ssim": float("nan")}


# ---- a loss that sees texture, not the camera-mounted light (pose alignment) -------------------------------------

#: Standard deviation (px) of the Gaussian window of :func:`local_contrast`.
CONTRAST_SIGMA = 1.0
#: Floors of the local contrast's denominator: a share of the local mean, and an absolute linear level (8-bit sRGB
#: quantisation in the dark, ~3e-4 per step, is no texture).
CONTRAST_RELATIVE_FLOOR = 0.05
CONTRAST_ABSOLUTE_FLOOR = 2e-3


def _blur(x: torch.Tensor, sigma: float) -> torch.Tensor:
    """(B, 1, H, W) Gaussian blur with a separable (6σ + 1)-tap kernel, reflect padding."""
    radius = max(1, int(round(3.0 * sigma)))
    taps = torch.arange(-radius, radius + 1, dtype=x.dtype, device=x.device)
    kernel = torch.exp(-0.5 * (taps / sigma) ** 2)
    kernel = kernel / kernel.sum()
    x = torch.nn.functional.pad(x, (radius, radius, radius, radius), mode="reflect")
    x = torch.nn.functional.conv2d(x, kernel.view(1, 1, 1, -1))
    return torch.nn.functional.conv2d(x, kernel.view(1, 1, -1, 1))


def local_contrast(image: torch.Tensor, sigma: float = CONTRAST_SIGMA) -> torch.Tensor:
    """(H, W) locally normalised luminance of a linear image (H, W, C): (Y − μ) / sqrt(σ_Y² + (0.05 μ)² + 0.002²),
    μ and σ_Y² the mean and variance of Y (the channel mean) in a Gaussian window of ``sigma`` px.

    A light that varies slowly across the image (a spotlight's hot spot and fall-off, an exposure) multiplies Y by a
    nearly constant factor within the window, which cancels: what is left is the texture's local pattern."""
    y = image.mean(dim=-1)[None, None]
    mean = _blur(y, sigma)
    var = (_blur(y * y, sigma) - mean * mean).clamp(min=0.0)
    scale = torch.sqrt(var + (CONTRAST_RELATIVE_FLOOR * mean) ** 2 + CONTRAST_ABSOLUTE_FLOOR ** 2)
    return ((y - mean) / scale)[0, 0]


def texture_loss(pred: torch.Tensor, target: torch.Tensor, valid: torch.Tensor | None = None,
                 sigma: float = CONTRAST_SIGMA) -> torch.Tensor:
    """Mean absolute difference of the :func:`local_contrast` of a render and an input (both (H, W, C), linear) over
    the ``valid`` (H, W) pixels (all when None): an image comparison that a camera-mounted light, which moves with a
    pose hypothesis, cannot pull towards a wrong pose by brightness alone."""
    diff = (local_contrast(pred, sigma) - local_contrast(target, sigma)).abs()
    if valid is None:
        return diff.mean()
    return (diff * valid).sum() / valid.sum().clamp(min=1)


def pose_refinement_terms(pred: torch.Tensor, target: torch.Tensor, clipped: torch.Tensor, row: torch.Tensor,
                          texture_weight: float, penalty: float) -> torch.Tensor:
    """What pose refinement adds to the training loss of a view whose correction ``row`` (9,) is learning:
    ``texture_weight`` × :func:`texture_loss` over the unclipped pixels (its gradient dominates the correction's, so the
    camera-mounted light does not bias it) + ``penalty`` × ‖row‖² (the pull towards the identity). pred, target:
    (H, W, 3) linear; clipped: (H, W) bool (clipped, held-out or unseen pixels)."""
    terms = penalty * row.square().sum()
    if texture_weight > 0:
        terms = terms + texture_weight * texture_loss(pred, target, (~clipped).to(pred.dtype))
    return terms
