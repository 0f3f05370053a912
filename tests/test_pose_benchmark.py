"""``spotless benchmark poses``: the perturbed copies of a dataset (independent errors, VIO-like drift, a cloud
triangulated with the perturbed poses)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from evaluation.synthetic import render_room_sequence, write_dataset_folder
from spotlessgs.experiments.pose_benchmark import drift_offsets, perturbed_copy, perturbed_poses
from spotlessgs.io.cameras import axis_angle_to_matrix
from spotlessgs.io.dataset import read_dataset
from spotlessgs.io.seeding import numpy_rng
from spotlessgs.prepare import POINTS_FILE


def _poses(count: int) -> list[np.ndarray]:
    """Camera-to-world poses along a line, each turned differently, so that a rotation composed on the wrong side of
    the pose would show."""
    out = []
    for k in range(count):
        m = np.eye(4)
        m[:3, :3] = axis_angle_to_matrix(np.array([0.3, 0.1 * k, -0.2]))
        m[:3, 3] = [0.1 * k, 1.0, -0.5]
        out.append(m)
    return out


def _errors(moved: list[np.ndarray], true: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Per frame: the centre's offset (3,) and the rotation angle (degrees) of moved · true⁻¹ about the centre."""
    offsets = np.stack([m[:3, 3] - t[:3, 3] for m, t in zip(moved, true)])
    angles = []
    for m, t in zip(moved, true):
        delta = m[:3, :3] @ t[:3, :3].T
        angles.append(math.degrees(math.acos(np.clip((np.trace(delta) - 1.0) / 2.0, -1.0, 1.0))))
    return offsets, np.array(angles)


def test_independent_errors_have_exactly_the_given_size_on_every_frame():
    true = _poses(12)
    moved = perturbed_poses(true, 0.03, 0.3, "independent", numpy_rng(0, "test"))
    offsets, angles = _errors(moved, true)
    np.testing.assert_allclose(np.linalg.norm(offsets, axis=1), 0.03, rtol=1e-9)
    np.testing.assert_allclose(angles, 0.3, rtol=1e-6)


def test_drift_is_a_smooth_random_walk_with_the_given_rms():
    true = _poses(60)
    moved = perturbed_poses(true, 0.03, 0.3, "drift", numpy_rng(0, "test"))
    offsets, angles = _errors(moved, true)
    assert np.linalg.norm(offsets[0]) == 0.0 and angles[0] == pytest.approx(0.0, abs=1e-6)  # VIO starts exact
    assert math.sqrt((np.linalg.norm(offsets, axis=1) ** 2).mean()) == pytest.approx(0.03, rel=1e-9)
    assert math.sqrt((angles ** 2).mean()) == pytest.approx(0.3, rel=1e-4)
    # neighbours share most of their error: a step between frames is far smaller than the error itself (independent
    # errors of the same RMS would differ by about sqrt(2) times the RMS between neighbours)
    steps = np.linalg.norm(np.diff(offsets, axis=0), axis=1)
    assert steps.mean() < 0.3 * 0.03
    offsets_walk, rotvecs = drift_offsets(60, 0.03, 0.3, numpy_rng(0, "test"))
    np.testing.assert_allclose(offsets, offsets_walk, atol=1e-12)  # the offsets are the walk, in the world's axes
    np.testing.assert_allclose(angles, np.degrees(np.linalg.norm(rotvecs, axis=1)), atol=1e-5)


def test_unknown_error_model_is_refused():
    with pytest.raises(ValueError, match="unknown pose error model 'vio'"):
        perturbed_poses(_poses(3), 0.03, 0.3, "vio", numpy_rng(0, "test"))


@pytest.fixture(scope="module")
def room(tmp_path_factory):
    """14 spotlit frames of the ray-cast room (240 x 180), posed, without a point cloud."""
    seq = render_room_sequence(num_frames=14, width=240, height=180, seed=0)
    root = tmp_path_factory.mktemp("pose-bench") / "room"
    write_dataset_folder(seq, root, with_depth=False)
    return root


def test_a_triangulated_copy_gets_its_own_points_from_its_own_poses(room, tmp_path):
    source = (room / "transforms.json").read_bytes()
    clean = perturbed_copy(room, tmp_path / "clean", 0.0, 0.0, seed=0, model="drift", points="triangulated")
    drifted = perturbed_copy(room, tmp_path / "drift", 0.05, 0.5, seed=0, model="drift", points="triangulated")
    assert (room / "transforms.json").read_bytes() == source and not (room / POINTS_FILE).exists()
    assert not list(tmp_path.glob("*.partial"))
    truth, zero, moved = (read_dataset(d).c2w_opencv for d in (room, clean, drifted))
    np.testing.assert_allclose(zero, truth, atol=1e-12)
    centre_error = np.linalg.norm(moved[:, :3, 3] - truth[:, :3, 3], axis=1)
    assert math.sqrt((centre_error ** 2).mean()) == pytest.approx(0.05, rel=1e-6)
    record = json.loads((drifted / "transforms.json").read_text())["spotless"]["pose_perturbation"]
    assert record["model"] == "drift" and record["points"] == "triangulated"
    for data in (clean, drifted):
        assert read_dataset(data).ply_path == data / POINTS_FILE
        assert json.loads((data / "prepare.json").read_text())["points"]["points"] >= 100
    # triangulated with the copy's own (drifted) poses, not the source's: the clouds differ
    assert (drifted / POINTS_FILE).read_bytes() != (clean / POINTS_FILE).read_bytes()
    # made once: a second call returns the finished copy without redoing it
    stamp = (drifted / POINTS_FILE).stat().st_mtime_ns
    assert perturbed_copy(room, tmp_path / "drift", 0.05, 0.5, seed=0, model="drift", points="triangulated") == drifted
    assert (drifted / POINTS_FILE).stat().st_mtime_ns == stamp
    # ... and asked for with other settings, refused by name instead of returned as if it were that copy
    with pytest.raises(ValueError, match=r"drift: the perturbed copy was made with other settings \(translation_m: "
                                         r"copy 0.05, now 0.03; seed: copy 0, now 1\); use a new --out"):
        perturbed_copy(room, tmp_path / "drift", 0.03, 0.5, seed=1, model="drift", points="triangulated")
    assert (drifted / POINTS_FILE).stat().st_mtime_ns == stamp
