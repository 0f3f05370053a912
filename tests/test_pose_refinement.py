"""Camera pose refinement: the per-view correction (spotlessgs.models.pose), the camera gradient through the C++
projection, test-view alignment (spotlessgs.training.pose_alignment), its texture loss, and the trainer's
checkpoints and RUN/poses.json."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np
import pytest
import torch

from conftest import synthetic_box_dataset
from spotlessgs.io.camera_batch import Cameras
from spotlessgs.io.cameras import Intrinsics, axis_angle_to_matrix
from spotlessgs.models.gaussians import GaussianParams
from spotlessgs.models.pose import (
    PoseCorrection, corrected_camera, correction_matrix, rigid_inverse, rotation_angle_deg,
)
from spotlessgs.models.relightable import RelightableScene
from spotlessgs.training.config import preset

pytestmark = pytest.mark.usefixtures("one_torch_thread")

W, H = 64, 48
CAMERA = Intrinsics(56.0, 56.0, W / 2, H / 2, W, H)


def _corner_scene(variant: str = "darkgs", seed: int = 0, pose: np.ndarray | None = None) -> RelightableScene:
    """Small Gaussians with a smooth texture on three faces of a room corner in front of a camera at ``pose`` (default
    the origin, looking along +z): a back wall, a floor and a side wall, so that every pose direction changes the
    image."""
    rng = np.random.default_rng(seed)
    n = 900
    u, v = rng.uniform(-1, 1, n), rng.uniform(-1, 1, n)
    back = np.stack([0.9 * u, 0.5 * v, np.full(n, 1.6)], 1)
    floor = np.stack([0.9 * u, np.full(n, 0.5), 1.05 + 0.55 * v], 1)
    side = np.stack([np.full(n, -0.9), 0.5 * u, 1.05 + 0.55 * v], 1)
    xyz = np.concatenate([back, floor, side])
    normals = np.concatenate([np.tile([0, 0, -1.0], (n, 1)), np.tile([0, -1.0, 0], (n, 1)),
                              np.tile([1.0, 0, 0], (n, 1))])
    # a smooth texture (waves of about 10 rad/m): its basin is wider than the errors to correct, as a real room's
    waves, phases = 10.0 * rng.normal(size=(2, 3, 3)), rng.uniform(0, 2 * np.pi, (2, 3))
    rgb = 0.5 + 0.2 * np.sin(np.einsum("wcx,nx->nwc", waves, xyz) + phases).sum(1)
    if pose is not None:
        xyz, normals = xyz @ pose[:3, :3].T + pose[:3, 3], normals @ pose[:3, :3].T
    gaussians = GaussianParams.from_point_cloud(xyz, rgb, normals)
    with torch.no_grad():
        gaussians.params["log_scales"].fill_(math.log(0.025))
        gaussians.params["opacity_logits"].fill_(3.0)
    return RelightableScene.create(variant, gaussians, seed=0)


def _camera(c2w: np.ndarray) -> Cameras:
    return Cameras(torch.tensor(c2w, dtype=torch.float32), CAMERA)


def _perturbation() -> np.ndarray:
    """A known small error of a pose, in the camera's frame: 4.5 cm and 1.5 degrees."""
    m = np.eye(4)
    m[:3, :3] = axis_angle_to_matrix(math.radians(1.5) * np.array([0.6, -0.7, 0.4]) / np.linalg.norm([0.6, -0.7, 0.4]))
    m[:3, 3] = [0.03, -0.025, 0.02]
    return m


def _true_pose() -> np.ndarray:
    """The view's true camera-to-world: far from the world axes, so that a correction composed on the wrong side of the
    pose (in the world's axes instead of the camera's) would not land on the truth."""
    m = np.eye(4)
    m[:3, :3] = axis_angle_to_matrix(math.radians(70.0) * np.array([0.3, 0.9, -0.3]) / np.linalg.norm([0.3, 0.9, -0.3]))
    m[:3, 3] = [0.8, -0.4, 0.5]
    return m


def _pose_error(c2w: np.ndarray, true: np.ndarray) -> tuple[float, float]:
    """(centre error in m, rotation error in degrees)."""
    rel = torch.tensor(true[:3, :3].T @ c2w[:3, :3])
    return float(np.linalg.norm(c2w[:3, 3] - true[:3, 3])), float(rotation_angle_deg(rel))


# ---- the correction ------------------------------------------------------------------------------------------------


def test_the_correction_is_the_identity_at_init_and_gradients_reach_its_row():
    scene = _corner_scene()
    poses = PoseCorrection(4)
    torch.testing.assert_close(poses.matrices(), torch.eye(4).expand(4, 4, 4))
    camera = _camera(np.eye(4))
    moved = poses(camera, 2)
    torch.testing.assert_close(moved.c2w, camera.c2w)
    torch.testing.assert_close(moved.viewmat, camera.viewmat)
    with torch.no_grad():
        plain = scene.render(camera).image
    out = scene.render(moved)
    torch.testing.assert_close(out.image, plain)  # the same render at the identity ...
    (out.image * torch.linspace(0, 1, W)[None, :, None]).sum().backward()
    grad = poses.delta.grad.to_dense()
    assert float(grad[2].abs().sum()) > 0  # ... and a gradient
    assert float(grad[[0, 1, 3]].abs().sum()) == 0.0  # only the rendered view's row


def test_a_correction_is_a_rigid_motion_in_the_cameras_own_frame():
    delta = torch.tensor([0.1, -0.2, 0.3, 0.01, 0.02, -0.03, 0.02, -0.01, 0.01], dtype=torch.float64)
    m = correction_matrix(delta)
    torch.testing.assert_close(m[:3, :3] @ m[:3, :3].T, torch.eye(3, dtype=torch.float64))
    assert float(torch.linalg.det(m[:3, :3])) == pytest.approx(1.0)
    torch.testing.assert_close(rigid_inverse(m) @ m, torch.eye(4, dtype=torch.float64))
    c2w = np.eye(4)
    c2w[:3, :3] = axis_angle_to_matrix(np.array([0.3, 0.2, -0.1]))
    c2w[:3, 3] = [1.0, 2.0, 3.0]
    cam = Cameras(torch.tensor(c2w), CAMERA)
    moved = corrected_camera(cam, delta)
    # the translation is along the camera's own axes: the centre moves by R_cw t
    torch.testing.assert_close(moved.c2w[:3, 3], cam.c2w[:3, 3] + cam.c2w[:3, :3] @ delta[:3])
    torch.testing.assert_close(moved.viewmat @ moved.c2w, torch.eye(4, dtype=torch.float64))


def test_the_camera_gradient_through_the_cpp_projection_equals_the_torch_projections():
    """Along rigid motions (what a pose correction moves): the same image, the same gradient of the correction and
    of the Gaussians."""
    scene = _corner_scene(variant="3dgs")
    c2w = np.eye(4)
    c2w[:3, 3] = [0.05, -0.02, 0.1]
    camera = _camera(c2w)
    weights = torch.rand(H, W, 3, generator=torch.Generator().manual_seed(1))
    results = {}
    for backend in ("cpp", "torch"):
        scene.zero_grad(set_to_none=True)
        delta = torch.zeros(9, requires_grad=True)
        out = scene.render(corrected_camera(camera, delta), backend=backend, num_threads=1)
        (out.image * weights).sum().backward()
        results[backend] = (out.image.detach(), delta.grad.clone(), scene.gaussians.params["means"].grad.clone())
    (img_c, d_c, m_c), (img_t, d_t, m_t) = results["cpp"], results["torch"]
    torch.testing.assert_close(img_c, img_t, rtol=1e-4, atol=1e-5)
    torch.testing.assert_close(d_c, d_t, rtol=2e-3, atol=1e-3 * float(d_t.abs().max()))
    torch.testing.assert_close(m_c, m_t, rtol=2e-3, atol=1e-3 * float(m_t.abs().max()))


# ---- refinement and alignment reduce a known error -----------------------------------------------------------------


def test_alignment_reduces_a_known_pose_error_of_one_view():
    """A view rendered at its true pose, then aligned (the texture loss, the default) from a pose off by 4.4 cm and 1.5
    degrees: the aligned pose (the given pose times the correction, as every caller composes it) is much nearer the
    truth. A wrong sign or order of the composition (c2w · Δ, Δ⁻¹ · viewmat) would move it away or leave it."""
    from spotlessgs.training.pose_alignment import align_view

    true = _true_pose()
    scene = _corner_scene(pose=true)
    with torch.no_grad():
        target = scene.render(_camera(true)).image
    given = true @ _perturbation()
    config = preset("tiny", pose_align_steps=100, num_threads=1)
    assert config.pose_align_loss == "texture"
    aligned = align_view(scene, _camera(given), 0, target, torch.zeros(H, W, dtype=torch.bool), config)
    final = given @ correction_matrix(aligned.delta.double()).numpy()
    (t0, r0), (t1, r1) = _pose_error(given, true), _pose_error(final, true)
    assert t1 < 0.2 * t0 and r1 < 0.2 * r0, ((t0, r0), (t1, r1))
    assert aligned.loss_after < aligned.loss_before
    assert all(p.requires_grad for p in scene.parameters())  # the model was frozen only while aligning


def test_refinement_with_the_trainers_update_reduces_a_known_pose_error():
    """The trainer's update of one view's correction (its row through the lazy SparseAdam, the training loss plus
    the refinement's terms at the default settings), with the scene fixed: the view's pose error shrinks, and the
    other rows do not move."""
    from spotlessgs.training.losses import photometric_loss, pose_refinement_terms
    from spotlessgs.training.trainer import pose_optimizer

    true = _true_pose()
    scene = _corner_scene(pose=true)
    config = preset("quick", lr_pose=4e-3)
    poses = PoseCorrection(3)
    opt = pose_optimizer(poses, config)
    for p in scene.parameters():
        p.requires_grad_(False)
    with torch.no_grad():
        target = scene.render(_camera(true)).image
    given = true @ _perturbation()
    clipped = torch.zeros(H, W, dtype=torch.bool)
    for _ in range(80):
        row = poses.row(1)
        image = scene.render(corrected_camera(_camera(given), row)).image
        loss = photometric_loss(image, target, clipped)[0] + pose_refinement_terms(
            image, target, clipped, row, config.pose_texture_weight, config.pose_penalty)
        loss.backward()
        opt.step()
        opt.zero_grad(set_to_none=True)
    final = given @ poses.matrices()[1].double().numpy()
    (t0, r0), (t1, r1) = _pose_error(given, true), _pose_error(final, true)
    assert t1 < 0.3 * t0 and r1 < 0.3 * r0, ((t0, r0), (t1, r1))
    assert float(poses.delta.detach()[[0, 2]].abs().sum()) == 0.0


def test_the_texture_loss_ignores_a_smooth_light_and_sees_a_shift():
    from spotlessgs.training.losses import texture_loss

    gen = torch.Generator().manual_seed(0)
    texture = torch.rand(1, 3, 24, 32, generator=gen)
    image = torch.nn.functional.interpolate(texture, size=(72, 96), mode="bilinear").permute(0, 2, 3, 1)[0]
    v, u = torch.meshgrid(torch.linspace(-1, 1, 72), torch.linspace(-1, 1, 96), indexing="ij")
    hot_spot = (0.05 + torch.exp(-(u ** 2 + v ** 2) / 0.3))[..., None]  # a spotlight's hot spot and dark corners
    lit = image * hot_spot
    shifted = torch.roll(image, shifts=2, dims=1) * hot_spot
    assert float(texture_loss(lit, image)) < 0.25 * float(texture_loss(shifted, lit))
    assert float((lit - image).abs().mean()) > float((shifted - lit).abs().mean())  # brightness alone says otherwise


# ---- the trainer: checkpoints, resume, RUN/poses.json ---------------------------------------------------------------


SMALL = dict(iterations=20, image_width=32, num_threads=1, densify_from=1000, log_every=10, checkpoint_every=10,
             init_points=200, max_gaussians=300, brdf_hidden=8, refine_poses=True, pose_refine_from=4,
             lr_pose=1e-3, pose_align_steps=4)


@pytest.fixture(scope="module")
def box(tmp_path_factory):
    return synthetic_box_dataset(tmp_path_factory, "poses", seed=5)


@pytest.fixture(scope="module")
def refined_run(box, tmp_path_factory):
    from spotlessgs.training.trainer import train

    run = tmp_path_factory.mktemp("refined") / "run"
    train(box, run, "darkgs", preset("tiny", **SMALL), seed=0, progress=False)
    return run


def test_resume_keeps_the_pose_corrections(box, refined_run, tmp_path):
    from spotlessgs.training.checkpoint import load_checkpoint
    from spotlessgs.training.trainer import train

    config = preset("tiny", **SMALL)
    split = tmp_path / "split"
    train(box, split, "darkgs", config, seed=0, progress=False, stop_after=10)
    halfway = load_checkpoint(split)
    assert float(halfway["pose"]["delta"].abs().sum()) > 0  # learning since step 4, saved at step 10
    assert "pose" in halfway["optimizers"]
    train(box, split, "darkgs", config, seed=0, progress=False, resume=True)
    a, b = load_checkpoint(refined_run), load_checkpoint(split)
    assert a["step"] == b["step"] == 20
    torch.testing.assert_close(b["pose"]["delta"], a["pose"]["delta"], rtol=1e-5, atol=1e-7)
    with pytest.raises(ValueError, match="other settings"):
        train(box, split, "darkgs", config.replace(refine_poses=False), seed=0, resume=True, progress=False)


def test_the_refined_poses_file_holds_every_view_and_reads_back(box, refined_run):
    from spotlessgs.io.cameras import opengl_to_opencv_c2w
    from spotlessgs.io.dataset import read_dataset
    from spotlessgs.run import Run
    from spotlessgs.training.checkpoint import load_checkpoint

    dataset = read_dataset(box)
    poses = Run.load(refined_run).poses
    assert poses is not None and poses.step == 20 and len(poses.names) == dataset.n_frames
    assert [s == "aligned" for s in poses.sources] == [k in dataset.split.test for k in range(dataset.n_frames)]
    np.testing.assert_allclose(poses.dataset_c2w_opengl, dataset.c2w_opengl, atol=1e-12)
    delta = load_checkpoint(refined_run)["pose"]["delta"].double()
    for k in dataset.split.train:  # a training view's pose: the dataset's, corrected on the right
        expected = dataset.c2w_opencv[k] @ correction_matrix(delta[k]).numpy()
        np.testing.assert_allclose(opengl_to_opencv_c2w(poses.c2w_opengl[k]), expected, atol=1e-9)
    moved = [k for k in dataset.split.train if not np.allclose(poses.c2w_opengl[k], dataset.c2w_opengl[k])]
    assert moved  # refinement changed the training views' poses
    summary = json.loads((refined_run / "train_summary.json").read_text())
    assert summary["refine_poses"] is True and summary["test_views_aligned"] is True


def test_the_refined_poses_file_is_written_atomically(box, refined_run, tmp_path, monkeypatch):
    from spotlessgs.training.checkpoint import load_checkpoint
    from spotlessgs.training.data import load_training_views
    from spotlessgs.training.pose_file import POSES_FILE, read_refined_poses, write_refined_poses

    views = load_training_views(box, 32)
    poses = PoseCorrection(len(views.names))
    poses.load_state_dict(load_checkpoint(refined_run)["pose"])
    target = tmp_path / POSES_FILE
    target.write_text("an earlier file")
    real_replace = os.replace

    def failing(src, dst):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "replace", failing)
    with pytest.raises(OSError):
        write_refined_poses(tmp_path, views, poses, {}, 20)
    assert target.read_text() == "an earlier file"  # never half a file
    assert not list(tmp_path.glob(".poses.json.partial-*"))
    events = []

    def recording(src, dst):
        events.append((Path(src).name, Path(dst).name))
        return real_replace(src, dst)

    monkeypatch.setattr(os, "replace", recording)
    write_refined_poses(tmp_path, views, poses, {}, 20)
    assert len(events) == 1 and events[0][0].startswith(".poses.json.partial-") and events[0][1] == POSES_FILE
    back = read_refined_poses(tmp_path)
    assert back.sources == ["refined"] * len(views.names) and back.step == 20


def test_relit_test_views_are_aligned_and_the_evaluation_says_so(refined_run, tmp_path):
    from evaluation.runner import EvalConfig
    from spotlessgs.run import Run

    run = Run.load(refined_run)
    relit = run.relight(progress=False, device="cpu")
    record = relit["pose_alignment"]
    assert record["poses"] == "refined" and record["loss"] == "texture"
    assert record["aligned_views"] == ["frame_00000.png", "frame_00011.png"]  # the box's test views
    results = run.evaluate(EvalConfig(lpips=False, temporal=False, progress=False, num_threads=1),
                           out_dir=tmp_path / "eval")
    assert results["pose_alignment"]["aligned_views"] == record["aligned_views"]
    assert "were aligned to their spotlit inputs" in (tmp_path / "eval" / "results.md").read_text()
    plain = run.score_views(tmp_path / "not_aligned", "test", 1, align_poses=False)
    assert plain["pose_alignment"]["aligned_views"] == []
