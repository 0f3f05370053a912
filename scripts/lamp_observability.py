"""How well a rendered dataset's views pin down where its camera-mounted lamp sits, from the true geometry alone.

    python3 scripts/lamp_observability.py DATA

DATA is a dataset of ``spotless-sim render`` (its EXRs hold the true depth and world normals; transforms.json the
true lamp). Prints two cues (spotlessgs.models.light_observability):

- shadows: over every depth edge of every view (neighbouring pixels whose depths differ by 10 % or more), how many
  pixels the lamp's shadow moves per centimetre of the lamp's sideways offset (median, quartiles, 90th percentile),
  and the shadow's width for the true lamp's offset from the optical axis;
- shading: over the pixels within 12° of the lamp's axis that face it (cos ≥ 0.3), the RMS change of the direct
  light's log (cos θ / r², the lamp's power being free) when the lamp moves 1 cm along the camera's x, y, z, per view
  and then the median over the views. The shading sees the lamp move only through this spread, and with every
  surface's albedo learned, only where one surface is seen from several distances.

The figures of docs/results.md ("What limits the learned lamp's position") came from this command.
"""

from __future__ import annotations

import argparse

import numpy as np

from spotlessgs.io.dataset import read_dataset
from spotlessgs.io.exr import read_frame_exr
from spotlessgs.io.lens import camera_points
from spotlessgs.models.light_observability import edge_parallax, shading_sensitivity

#: Pixels within this angle of the lamp's axis count for the shading cue (inside the cone's flat part).
AXIS_ANGLE_DEG = 12.0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data", help="a rendered dataset folder (with EXRs and the true lamp)")
    args = parser.parse_args()
    dataset = read_dataset(args.data)
    if dataset.light is None:
        raise SystemExit(f"{dataset.source}: no true lamp (not a spotless-sim render)")
    lamp = dataset.light.position_in_camera
    axis = dataset.light.rotation_in_camera[:, 2]
    parallax, shading = [], []
    for index in range(dataset.n_frames):
        if dataset.exr_paths[index] is None:
            raise SystemExit(f"{dataset.source}: frame {index} has no EXR (no true depth)")
        frame = read_frame_exr(dataset.exr_paths[index])
        camera = dataset.cameras[index]
        parallax.append(edge_parallax(frame.depth, camera.fx))
        points = camera_points(camera, frame.depth)
        # world normals -> OpenCV camera frame: n_c = R_cw^T n_w, R_cw = R_gl diag(1, -1, -1)
        rotation = dataset.c2w_opencv[index][:3, :3]
        normals = frame.normal @ rotation
        rays = points - lamp
        angle = np.degrees(np.arccos(np.clip((rays @ axis) / np.linalg.norm(rays, axis=-1), -1.0, 1.0)))
        keep = np.isfinite(frame.depth) & (angle < AXIS_ANGLE_DEG)
        if keep.sum() >= 100:
            shading.append(shading_sensitivity(points[keep], normals[keep], lamp, step=0.01))
    values = np.concatenate(parallax) / 100.0
    camera = dataset.cameras[0]
    print(f"{args.data}: {dataset.n_frames} views, {camera.width}x{camera.height}, lamp at "
          f"{np.round(100 * lamp, 1).tolist()} cm in the camera frame")
    if values.size:
        q25, q50, q75, q90 = np.percentile(values, [25, 50, 75, 90])
        offset_cm = 100.0 * float(np.hypot(lamp[0], lamp[1]))
        print(f"shadows: {values.size} depth-edge pairs; shift per cm of lamp offset (px): median {q50:.3f}, "
              f"quartiles {q25:.3f} / {q75:.3f}, 90th percentile {q90:.3f}; width for the lamp's {offset_cm:.1f} cm "
              f"offset (px): median {q50 * offset_cm:.2f}, 90th percentile {q90 * offset_cm:.2f}")
    else:
        print("shadows: no view has a depth edge")
    if shading:
        x, y, z = 100.0 * np.median(np.stack(shading), axis=0)
        print(f"shading: {len(shading)} views; RMS change of the direct light per cm of lamp motion (%, median over "
              f"the views): x {x:.2f}, y {y:.2f}, z {z:.2f}")
    else:
        print(f"shading: no view has 100 pixels within {AXIS_ANGLE_DEG:g} degrees of the lamp's axis")


if __name__ == "__main__":
    main()
