"""How finely a rendered dataset's images resolve the lamp's position from its shadows: the pixels a shadow beside a
depth edge moves per centimetre of the lamp's sideways offset, over every view's true depth.

    python3 scripts/shadow_parallax.py DATA

DATA is a dataset of ``spotless-sim render`` (its EXRs hold the true depth). For every depth edge of every view
(neighbouring pixels whose depths differ by 10 % or more) the shadow moves f (1/d - 1/z) pixels per metre of lamp
offset (spotlessgs.models.shadow.edge_parallax); prints the median, quartiles and 90th percentile in pixels per
centimetre, and the shadow's width for the dataset's true lamp offset (its distance from the optical axis). The
figures of docs/results.md ("What limits the lamp's position") came from this command.
"""

from __future__ import annotations

import argparse

import numpy as np

from spotlessgs.io.dataset import read_dataset
from spotlessgs.io.exr import read_frame_exr
from spotlessgs.models.shadow import edge_parallax


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data", help="a rendered dataset folder (with EXRs)")
    args = parser.parse_args()
    dataset = read_dataset(args.data)
    per_metre = []
    for index in range(dataset.n_frames):
        exr = dataset.exr_paths[index]
        if exr is None:
            raise SystemExit(f"{dataset.source}: frame {index} has no EXR (no true depth)")
        per_metre.append(edge_parallax(read_frame_exr(exr).depth, dataset.cameras[index].fx))
    values = np.concatenate(per_metre)
    if values.size == 0:
        raise SystemExit(f"{args.data}: no view has a depth edge")
    cm = values / 100.0
    q25, q50, q75, q90 = np.percentile(cm, [25, 50, 75, 90])
    camera = dataset.cameras[0]
    print(f"{args.data}: {dataset.n_frames} views, {camera.width}x{camera.height}, "
          f"{values.size} depth-edge pairs")
    print(f"shadow shift per cm of lamp offset (px): median {q50:.3f}, quartiles {q25:.3f} / {q75:.3f}, "
          f"90th percentile {q90:.3f}")
    if dataset.light is not None:
        offset_cm = 100.0 * float(np.hypot(*dataset.light.position_in_camera[:2]))
        print(f"shadow width for the true lamp offset of {offset_cm:.1f} cm (px): median {q50 * offset_cm:.2f}, "
              f"90th percentile {q90 * offset_cm:.2f}")


if __name__ == "__main__":
    main()
