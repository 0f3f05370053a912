"""Downstream SfM (pycolmap, CPU) on a ray-cast synthetic room with known poses."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from evaluation.sfm import SfmConfig, load_sfm_result, run_sfm
from evaluation.trajectory import pool_trajectory_errors
from evaluation.synthetic import render_room_sequence
from spotlessgs.io.cameras import Intrinsics, opengl_to_opencv_c2w
from spotlessgs.io.images import write_png


@pytest.fixture(scope="module")
def room_images(tmp_path_factory):
    seq = render_room_sequence(num_frames=16, width=240, height=180, seed=0)
    root = tmp_path_factory.mktemp("sfm_room")
    names = []
    for k, img in enumerate(seq.even):
        names.append(f"frame_{k:05d}.png")
        write_png(root / "even" / names[-1], img)
    true = {n: opengl_to_opencv_c2w(c) for n, c in zip(names, seq.c2w_opengl)}
    return root, names, seq.intrinsics, true


@pytest.mark.parametrize("matcher", ["sequential", pytest.param("exhaustive", marks=pytest.mark.slow)])
def test_all_images_register_with_accurate_poses(room_images, tmp_path, matcher):
    root, names, intr, true = room_images
    result = run_sfm(root / "even", names, tmp_path / "work", SfmConfig(matcher=matcher), intr)
    summary = result.summary(true, names)
    print(summary)  # shown by pytest when an assertion fails
    assert result.registered_images == result.total_images == len(names)
    assert result.reprojection_error_px < 1.0
    assert result.observations_per_image > 100 and result.points3d > 300
    assert len(result.models) == 1 and result.largest_model_images == len(names)
    model = result.models[0]
    assert model.points_xyz.shape == (result.points3d, 3) and model.points_rgb.dtype == np.uint8
    # COLMAP's own statistics of one model: mean point error, observations over registered images
    assert result.reprojection_error_px == pytest.approx(model.point_errors_px.mean())
    assert result.observations_per_image == pytest.approx(model.observations / len(names))
    # every observation, re-projected by us: one row per observation, radius = distance from the centre / half-diagonal
    obs = model.observation_errors
    assert obs.shape == (model.observations, 4) and np.isfinite(obs).all()
    assert 0.0 <= obs[:, 3].min() and obs[:, 3].max() <= 1.0
    assert np.hypot(obs[:, 0] - intr.width / 2, obs[:, 1] - intr.height / 2) == pytest.approx(
        obs[:, 3] * np.hypot(intr.width, intr.height) / 2)
    rings = result.errors_by_radius(bins=4)
    assert sum(r["observations"] for r in rings) == model.observations
    assert sum(r["observations"] * (r["mean_error_px"] or 0.0) for r in rings) / model.observations == \
        pytest.approx(obs[:, 2].mean())
    # reading the models back from the work folder gives the same statistics
    again = load_sfm_result(tmp_path / "work" / "sparse", total_images=len(names))
    assert (again.reprojection_error_px, again.observations_per_image, again.registered_images) == \
        (result.reprojection_error_px, result.observations_per_image, result.registered_images)
    np.testing.assert_allclose(again.models[0].observation_errors[:, 2].mean(), obs[:, 2].mean())
    # the ring table of `spotless sfm-rings` shows the same counts and errors
    from click.testing import CliRunner

    from evaluation.cli import sfm_rings_command as rings_main

    out = CliRunner().invoke(rings_main, [f"even={tmp_path / 'work' / 'sparse'}", "--bins", "2"])
    assert out.exit_code == 0, out.output
    halves = result.errors_by_radius(bins=2)
    row = out.output.strip().splitlines()[-1]
    assert row.startswith(f"| even | {model.observations} | {result.reprojection_error_px:.3f} | ")
    for ring in halves:
        assert f"{100.0 * ring['observations'] / model.observations:.0f}% · {ring['mean_error_px']:.3f}" in row
    # COLMAP's point error is the mean re-projection error over the point's track: weighted by the track lengths,
    # the point errors average to the mean of our per-observation errors
    import pycolmap

    rec = pycolmap.Reconstruction(str(tmp_path / "work" / "sparse" / "0"))
    points = list(rec.points3D.values())
    weighted = np.average([p.error for p in points], weights=[p.track.length() for p in points])
    assert obs[:, 2].mean() == pytest.approx(weighted, rel=1e-9)
    traj = summary["trajectory"]
    # the room is 5 m wide and the path 1.7 m long: a few millimetres after Sim3 alignment
    assert traj["ate_rmse"] < 0.02 and traj["rre_mean_deg"] < 0.5 and traj["num_poses"] == len(names)
    assert set(summary) >= {"reprojection_error_px", "observations_per_image", "registered_images", "total_images",
                            "points3d"}
    # camera-to-world poses: centres follow the true path up to the similarity
    errs = result.trajectory_errors(true, names)
    est = np.stack([result.poses_c2w[n][:3, 3] for n in names])
    aligned = errs.alignment.apply(est)
    assert np.abs(aligned - np.stack([true[n][:3, 3] for n in names])).max() < 0.05


def test_uninformative_images_register_nothing(tmp_path):
    names = []
    for k in range(3):
        names.append(f"{k}.png")
        Image.fromarray(np.full((60, 80, 3), 128, np.uint8)).save(tmp_path / names[-1])
    result = run_sfm(tmp_path, names, tmp_path / "work", SfmConfig())
    assert result.registered_images == 0 and result.total_images == 3
    assert result.reprojection_error_px is None
    assert result.summary({n: np.eye(4) for n in names})["trajectory"] is None


@pytest.mark.parametrize("verbose, level", [(False, 2), (True, 0)])
def test_colmap_logs_errors_only_unless_verbose_and_the_level_is_restored(tmp_path, monkeypatch, verbose, level):
    import pycolmap

    import evaluation.sfm as sfm

    seen = []
    real_pipeline = sfm._pipeline

    def pipeline_noting_the_level(*args, **kwargs):
        seen.append(pycolmap.logging.minloglevel)
        return real_pipeline(*args, **kwargs)

    monkeypatch.setattr(sfm, "_pipeline", pipeline_noting_the_level)
    names = []
    for k in range(2):
        names.append(f"{k}.png")
        Image.fromarray(np.full((60, 80, 3), 128, np.uint8)).save(tmp_path / names[-1])
    before = pycolmap.logging.minloglevel
    run_sfm(tmp_path, names, tmp_path / "work", SfmConfig(verbose=verbose))
    assert seen == [level] and pycolmap.logging.minloglevel == before


def test_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="no COLMAP model"):
        load_sfm_result(tmp_path)
    Image.fromarray(np.zeros((60, 80, 3), np.uint8)).save(tmp_path / "a.png")
    intr = Intrinsics(50.0, 50.0, 40.0, 30.0, 100, 30)
    with pytest.raises(ValueError, match=r"a.png: image is 80x60 but the intrinsics are for 100x30"):
        run_sfm(tmp_path, ["a.png"], tmp_path / "w", SfmConfig(), intr)
    with pytest.raises(FileNotFoundError, match="b.png: image listed for SfM does not exist"):
        run_sfm(tmp_path, ["a.png", "b.png"], tmp_path / "w")
    with pytest.raises(ValueError, match="at least one image"):
        run_sfm(tmp_path, [], tmp_path / "w")
    with pytest.raises(ValueError, match="matcher must be 'sequential' or 'exhaustive', got 'vocab'"):
        SfmConfig(matcher="vocab")
    with pytest.raises(ValueError, match="SfmConfig.num_threads must be at least 1, got 0"):
        SfmConfig(num_threads=0)


def test_single_thread_runs_are_reproducible(room_images, tmp_path):
    root, names, intr, _ = room_images
    a = run_sfm(root / "even", names[::2], tmp_path / "a", SfmConfig(seed=3), intr)
    b = run_sfm(root / "even", names[::2], tmp_path / "b", SfmConfig(seed=3), intr)
    assert a.summary() == b.summary() and a.registered_images == 8
    np.testing.assert_array_equal(a.models[0].points_xyz, b.models[0].points_xyz)


def test_a_sequence_that_breaks_in_two_pools_both_sub_models(tmp_path):
    """Two rooms with unrelated textures seen along the same path, one after the other: no match links them, so the
    mapper builds two sub-models; the pooled statistics count both, the largest-only ones one."""
    names, true = [], {}
    for seed in (0, 1):
        seq = render_room_sequence(num_frames=8, width=240, height=180, seed=seed)
        for k, img in enumerate(seq.even):
            names.append(f"frame_{seed}{k:04d}.png")
            write_png(tmp_path / "seq" / names[-1], img)
            true[names[-1]] = opengl_to_opencv_c2w(seq.c2w_opengl[k])
    pooled = run_sfm(tmp_path / "seq", names, tmp_path / "a", SfmConfig(), seq.intrinsics)
    largest = run_sfm(tmp_path / "seq", names, tmp_path / "b", SfmConfig(all_models=False), seq.intrinsics)
    assert len(pooled.models) == 2 and pooled.registered_images == 16 and pooled.largest_model_images == 8
    assert len(largest.models) == 1 and largest.registered_images == 8
    assert pooled.points3d == sum(len(m.point_errors_px) for m in pooled.models) > largest.points3d
    all_errors = np.concatenate([m.point_errors_px for m in pooled.models])
    assert pooled.reprojection_error_px == pytest.approx(all_errors.mean())
    assert pooled.observations_per_image == pytest.approx(sum(m.observations for m in pooled.models) / 16)
    # each sub-model has its own frame: aligned separately, both follow the true path to millimetres
    parts = pooled.model_alignments(true, names)
    assert [len(common) for _m, common, _e in parts] == [8, 8]
    assert {common[0][6] for _m, common, _e in parts} == {"0", "1"}  # one sub-model per room
    traj = pooled.summary(true, names)["trajectory"]
    assert traj["num_poses"] == 16 and traj["ate_rmse"] < 0.02


def _errors(rmse, mean, rre, n):
    from evaluation.trajectory import Sim3, TrajectoryErrors

    return TrajectoryErrors(rmse, mean, rre, n, Sim3(float(n), np.eye(3), np.zeros(3)))


def test_pooled_trajectory_errors_weight_poses_and_pairs():
    a, b = _errors(0.1, 0.08, 1.0, 4), _errors(0.4, 0.3, 3.0, 2)
    pooled = pool_trajectory_errors([a, b])
    # RMSE over all 6 poses: sqrt((4 * 0.01 + 2 * 0.16) / 6); RRE over 3 + 1 consecutive pairs
    assert pooled.ate_rmse == pytest.approx(np.sqrt(0.36 / 6))
    assert pooled.ate_mean == pytest.approx((4 * 0.08 + 2 * 0.3) / 6)
    assert pooled.rre_mean_deg == pytest.approx((3 * 1.0 + 1 * 3.0) / 4)
    assert pooled.num_poses == 6 and pooled.alignment.scale == 4.0  # the alignment of the larger part
    assert pool_trajectory_errors([b]) == b
    with pytest.raises(ValueError, match="no trajectories"):
        pool_trajectory_errors([])


def test_a_damaged_colmap_model_is_one_line_naming_its_folder(tmp_path):
    """sfm-rings on a model whose images.bin is damaged: pycolmap's IndexError was reported as a bug, with a
    traceback."""
    from click.testing import CliRunner

    from spotlessgs.cli import main

    model = tmp_path / "sparse" / "0"
    model.mkdir(parents=True)
    (model / "images.bin").write_bytes(b"garbage")
    (model / "cameras.bin").write_bytes(b"")
    (model / "points3D.bin").write_bytes(b"")
    result = CliRunner().invoke(main, ["sfm-rings", f"a={tmp_path / 'sparse'}"])
    assert result.exit_code == 2, result.output
    assert f"{model}: unreadable COLMAP model" in result.output and "Traceback" not in result.output
