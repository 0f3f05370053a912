"""Does a scene need a low-frequency (ambient and bounce) light? Two measurements without ground truth.

* :func:`dark_level`, from the input images alone: how bright the darkest parts of the views are, relative to their
  brightest. With the onboard spotlight as the only light, whatever its beam misses is black (on the quick bedroom
  rendered without bounce light a third of the image blocks are exactly 0); ambient or bounce light lifts those parts
  (the same bedroom with bounce light: its 20th-percentile block at 5% of the 99th).
* :func:`low_frequency_share`, from a fitted model: the share of its spotlight-lit rendered radiance that its
  low-frequency light carries. It also says whether a fitted model uses that light. On its own it is not enough: a
  short run on tiny images lets the low-frequency light make up for a spotlight not fitted yet (a 64-px bedroom
  without bounce light: 22% share, its dark level 0).

Model selection (:mod:`spotlessgs.training.selection`) wants both before it gives the scene a higher SH degree.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import torch
import torch.nn.functional as F

from spotlessgs.io.camera_batch import Cameras
from spotlessgs.models.relightable import RelightableScene

#: The dark level is this quantile of a view's block brightness ...
DARK_QUANTILE = 0.2
#: ... over this quantile (the view's bright end, robust to a few clipped pixels).
BRIGHT_QUANTILE = 0.99


def dark_level(images: torch.Tensor, block: int, dark_quantile: float = DARK_QUANTILE,
               bright_quantile: float = BRIGHT_QUANTILE) -> float:
    """Median over views of (dark_quantile / bright_quantile) of the brightness of ``block``×``block`` blocks.

    A block's brightness is the mean over the colour channels of each channel's median over the block's pixels. The
    median, not the mean: sensor noise on a black surface is clipped at 0, so its mean is positive (~0.4 σ) while
    its median stays 0 (on the bedroom without bounce light, with read noise σ = 0.012: 0.0014 instead of 0.009 with
    block means, the threshold being 0.01); per channel, so that a strongly coloured surface counts with its full
    brightness. Views whose bright end is 0 (black frames) or whose ratio is not finite say nothing and are skipped;
    with no view left the level is 0. One view at a time, so memory stays at one image.

    Args:
        images: (V, H, W, 3) linear input images in [0, 1], NaN where a pixel has no sample (skipped); block: block
            side in pixels (>= 1; blocks at the right/bottom edge are cut to the image).
    Returns:
        the level in [0, 1]: 0 when a fifth of every view is black.
    """
    if images.ndim != 4 or images.shape[-1] != 3 or len(images) == 0:
        raise ValueError(f"dark_level: images must be (V, H, W, 3) with V >= 1, got {tuple(images.shape)}")
    if block < 1:
        raise ValueError(f"dark_level: block must be >= 1, got {block}")
    if not 0.0 <= dark_quantile < bright_quantile <= 1.0:
        raise ValueError(f"dark_level: need 0 <= dark_quantile < bright_quantile <= 1, got {dark_quantile}, "
                         f"{bright_quantile}")
    _views, height, width, _ = images.shape
    ratios = []
    for image in images:
        channels = image.float().permute(2, 0, 1)[None]  # (1, 3, H, W)
        channels = F.pad(channels, (0, (-width) % block, 0, (-height) % block), value=float("nan"))
        pixels = F.unfold(channels, block, stride=block).reshape(3, block * block, -1)  # (3, px, blocks)
        blocks = pixels.nanmedian(dim=1).values.mean(dim=0)  # (blocks,)
        low, high = torch.nanquantile(blocks, dark_quantile), torch.nanquantile(blocks, bright_quantile)
        ratio = float(low / high) if float(high) > 0 else math.nan
        if math.isfinite(ratio):
            ratios.append(ratio)
    if not ratios:
        return 0.0
    return min(max(float(torch.tensor(ratios, dtype=torch.float64).quantile(0.5)), 0.0), 1.0)


@torch.no_grad()
def low_frequency_share(
    scene: RelightableScene, cameras: Cameras, indices: Sequence[int], backend: str = "auto",
    num_threads: int | None = None,
) -> float:
    """The share of the spotlight-lit rendered radiance that the low-frequency light carries, in [0, 1].

    Every view is rendered with the two lights apart (``RelightableScene.render(..., split_lights=True)``, six
    channels composited together): share = Σ I_lf / Σ (I_spot + I_lf) over all pixels, channels and ``indices``. No
    ground truth: it says how much of what the model explains of the input images it attributes to ambient and bounce
    light. Without any such light in the scene the learned low-frequency light fades to ~0 and so does the share.

    Args:
        scene: a spotlight model (not "3dgs"); cameras: V views; indices: views to render (non-empty).
    """
    if len(indices) == 0:
        raise ValueError("low_frequency_share: no views given")
    spot_total = low_total = 0.0
    for k in indices:
        image = scene.render(cameras[k], backend=backend, num_threads=num_threads, split_lights=True).image.double()
        spot_total += float(image[..., :3].sum())
        low_total += float(image[..., 3:].sum())
    total = spot_total + low_total
    return 0.0 if total <= 0 else low_total / total


def light_note(need: dict[str, Any]) -> str:
    """``; low-frequency light needed (dark level 0.054, share 8.3%)`` for a decision's light measurements."""
    return (f"; low-frequency light {'needed' if need['needed'] else 'not needed'} (dark level "
            f"{need['dark_level']:.3f}, share {100 * need['low_frequency_share']:.1f}%)")
