"""Full-resolution inference with a trained Cycle-GAN generator (it is fully convolutional)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from spotlessgs.baselines2d._validate import check_rgb_image
from spotlessgs.baselines2d.cyclegan.checkpoint import load_checkpoint, restore
from spotlessgs.baselines2d.cyclegan.networks import ResnetGenerator, build_generator
from spotlessgs.baselines2d.cyclegan.train import torch_threads
from spotlessgs.baselines2d.folders import refuse_name_clashes
from spotlessgs.io.images import list_image_files, read_image, write_png

# Which generator each direction uses (a = uneven, b = even).
DIRECTIONS = {"uneven_to_even": "G_ab", "even_to_uneven": "G_ba"}


def load_generator(checkpoint: str | os.PathLike, direction: str = "uneven_to_even") -> ResnetGenerator:
    """The generator of ``direction`` from a checkpoint file, in eval mode."""
    return generator_from_state(load_checkpoint(checkpoint), direction, checkpoint)


def generator_from_state(state: dict, direction: str = "uneven_to_even",
                         source: str | os.PathLike = "the checkpoint") -> ResnetGenerator:
    """The generator of ``direction`` from a checkpoint loaded (``load_checkpoint``) from ``source``, in eval mode;
    InputError naming ``source`` when its weights do not fit the generator its config builds."""
    if direction not in DIRECTIONS:
        raise ValueError(f"unknown direction {direction!r}; choose one of {sorted(DIRECTIONS)}")
    generator = build_generator(state["config"])
    name = DIRECTIONS[direction]
    restore(Path(source), f"network {name}",
            lambda: generator.load_state_dict(state["networks"][name]))
    return generator.eval()


def _pad_amounts(size: int, multiple: int, minimum: int) -> tuple[int, int]:
    target = max(-(-size // multiple) * multiple, minimum)
    extra = target - size
    return extra // 2, extra - extra // 2


def translate_image(generator: ResnetGenerator, img: np.ndarray) -> np.ndarray:
    """Translate one image at its full resolution.

    The image is padded (mirrored where the image is large enough, else edge-replicated) to a multiple of
    2**n_down of at least 2**(n_down + 2) pixels per side, translated, and cropped back.

    Args:
        img: (H, W, 3) sRGB values in [0, 1].
    Returns:
        (H, W, 3) float32 sRGB values in [0, 1].
    """
    rgb = check_rgb_image(img, "cyclegan input")
    height, width = rgb.shape[:2]
    multiple = 2**generator.n_down
    top, bottom = _pad_amounts(height, multiple, 4 * multiple)
    left, right = _pad_amounts(width, multiple, 4 * multiple)
    x = torch.from_numpy(rgb.transpose(2, 0, 1)[None].astype(np.float32)) * 2.0 - 1.0
    mirror = max(top, bottom) < height and max(left, right) < width
    x = F.pad(x, (left, right, top, bottom), mode="reflect" if mirror else "replicate")
    with torch.no_grad():
        y = generator(x)[0, :, top : top + height, left : left + width]
    return np.clip((y.numpy().transpose(1, 2, 0) + 1.0) * 0.5, 0.0, 1.0).astype(np.float32)


def translate_folder(
    checkpoint: str | os.PathLike,
    in_dir: str | os.PathLike,
    out_dir: str | os.PathLike,
    direction: str = "uneven_to_even",
    num_threads: int | None = None,
) -> list[Path]:
    """Translate every image of ``in_dir`` and write ``out_dir/<input stem>.png`` (same size as the input).

    Args:
        checkpoint: a checkpoint written by ``train_cyclegan``.
        direction: 'uneven_to_even' (default) or 'even_to_uneven'.
        num_threads: torch threads for inference (None: the checkpoint config's setting).
    Returns:
        the written paths, in input order.
    """
    state = load_checkpoint(checkpoint)
    generator = generator_from_state(state, direction, checkpoint)
    files = list_image_files(in_dir)
    refuse_name_clashes(files)
    threads = num_threads if num_threads is not None else state["config"].num_threads
    out_dir = Path(out_dir)
    written = []
    with torch_threads(threads):
        for path in files:
            out_path = out_dir / f"{path.stem}.png"
            write_png(out_path, translate_image(generator, read_image(path)))
            written.append(out_path)
    return written

