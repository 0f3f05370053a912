"""``spotless prepare --points``: sparse points triangulated with a posed dataset's own poses (a robot's VIO)."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from click.testing import CliRunner

from evaluation.synthetic import render_room_sequence, write_dataset_folder
from spotlessgs.cli import main
from spotlessgs.io.cameras import opengl_to_opencv_c2w
from spotlessgs.io.dataset import read_dataset
from spotlessgs.io.errors import InputError
from spotlessgs.io.images import write_png
from spotlessgs.io.ply import read_point_cloud
from spotlessgs.prepare import POINTS_FILE, SUMMARY_FILE, add_sfm_points


@pytest.fixture(scope="module")
def room(tmp_path_factory):
    """14 spotlit frames of the ray-cast room (240 x 180), posed, without a point cloud; and the sequence (depth)."""
    seq = render_room_sequence(num_frames=14, width=240, height=180, seed=0)
    root = tmp_path_factory.mktemp("points") / "room"
    write_dataset_folder(seq, root, with_depth=False)
    return root, seq


def _depth_error(xyz: np.ndarray, seq) -> np.ndarray:
    """Relative error of each point's depth against the true depth map of the first frame that sees it (NaN when
    no frame does)."""
    intr = seq.intrinsics
    errors = np.full(len(xyz), np.nan)
    for c2w, depth in zip(opengl_to_opencv_c2w(seq.c2w_opengl), seq.depth):
        cam = (xyz - c2w[:3, 3]) @ c2w[:3, :3]  # world -> camera (OpenCV axes)
        z = cam[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            u = np.floor(intr.fx * cam[:, 0] / z + intr.cx).astype(int)
            v = np.floor(intr.fy * cam[:, 1] / z + intr.cy).astype(int)
        seen = np.isnan(errors) & (z > 0.05) & (u >= 0) & (u < intr.width) & (v >= 0) & (v < intr.height)
        errors[seen] = np.abs(z[seen] - depth[v[seen], u[seen]]) / depth[v[seen], u[seen]]
    return errors


def test_points_are_triangulated_on_the_surfaces_and_become_the_start(room, tmp_path):
    root, seq = room
    data = tmp_path / "data"
    shutil.copytree(root, data)
    before = json.loads((data / "transforms.json").read_text())
    result = CliRunner().invoke(main, ["prepare", "--points", str(data), "-q"])
    assert result.exit_code == 0, result.output + repr(result.exception)
    summary = json.loads((data / SUMMARY_FILE).read_text())["points"]
    assert summary["frames"] == len(read_dataset(data).split.train)  # the training frames only
    cloud = read_point_cloud(data / POINTS_FILE)
    assert len(cloud.xyz) == summary["points"] >= 200
    assert cloud.normals is None or not np.any(cloud.normals)  # the trainer estimates them
    errors = _depth_error(np.asarray(cloud.xyz, np.float64), seq)
    assert np.isfinite(errors).mean() > 0.95
    assert np.nanmedian(errors) < 0.012  # on the walls, by the true depth maps (measured 0.006)
    after = json.loads((data / "transforms.json").read_text())
    assert after.pop("ply_file_path") == POINTS_FILE and after == before  # nothing else of the dataset changed
    assert read_dataset(data).ply_path == data / POINTS_FILE


def test_a_dataset_with_a_cloud_or_without_poses_is_refused(room, tmp_path):
    root, _seq = room
    data = tmp_path / "data"
    shutil.copytree(root, data)
    add_sfm_points(data)
    cloud = (data / POINTS_FILE).read_bytes()
    with pytest.raises(InputError, match=r"transforms\.json: already names a point cloud \(sfm_points\.ply\)"):
        add_sfm_points(data)
    assert (data / POINTS_FILE).read_bytes() == cloud
    (tmp_path / "empty").mkdir()
    result = CliRunner().invoke(main, ["prepare", "--points", str(tmp_path / "empty")])
    assert result.exit_code != 0 and "needs a posed dataset with transforms.json" in result.output
    result = CliRunner().invoke(main, ["prepare", "--points", str(data), "--out", str(tmp_path / "x")])
    assert result.exit_code == 2 and "takes no --out" in result.output


def test_frames_that_share_no_feature_give_a_clear_error_and_leave_the_dataset(room, tmp_path):
    root, _seq = room
    data = tmp_path / "data"
    shutil.copytree(root, data)
    rng = np.random.default_rng(0)
    for path in (data / "images").iterdir():  # independent noise: no feature matches across frames
        write_png(path, rng.uniform(0, 1, (180, 240, 3)))
    before = (data / "transforms.json").read_bytes()
    with pytest.raises(InputError, match="no point could be triangulated"):
        add_sfm_points(data)
    assert (data / "transforms.json").read_bytes() == before and not (data / POINTS_FILE).exists()


def test_a_sparse_start_densifies_from_the_first_densification_step(room, tmp_path):
    from spotlessgs.training.config import preset
    from spotlessgs.training.data import load_training_views
    from spotlessgs.training.trainer import SPARSE_START_SHARE, sparse_start_schedule

    root, _seq = room
    data = tmp_path / "data"
    shutil.copytree(root, data)
    quick = preset("quick")
    assert sparse_start_schedule(quick, load_training_views(data)) == quick  # no cloud: the random start is dense
    points = add_sfm_points(data)["points"]
    assert points < SPARSE_START_SHARE * quick.init_points
    adjusted = sparse_start_schedule(quick, load_training_views(data))
    assert adjusted.densify_from == quick.densify_every == 100 < quick.densify_from
    assert adjusted.replace(densify_from=quick.densify_from) == quick  # nothing else changes
    dense = quick.replace(init_points=points, max_gaussians=points)  # the same cloud is dense for a smaller limit
    assert sparse_start_schedule(dense, load_training_views(data)) == dense
    switched_off = quick.replace(sparse_start=False)  # the benchmark's row without it
    assert sparse_start_schedule(switched_off, load_training_views(data)) == switched_off


def test_the_gaussian_budget_judges_a_sparse_start_from_the_presets_densify_from(room, tmp_path):
    """A sparse start densifies from step 30 (the tiny preset's densify_every) while the budget's first validation
    check is at the preset's densify_from, 60: the early growth is not judged (judged, the budget stopped a robot
    camera's sparse start at 424 Gaussians)."""
    from spotlessgs.training.config import preset
    from spotlessgs.training.trainer import train

    root, _seq = room
    data = tmp_path / "data"
    shutil.copytree(root, data)
    add_sfm_points(data)
    cfg = preset("tiny").replace(iterations=90, image_width=64, num_threads=1, gaussian_budget=True,
                                 validation_every=4, validation_rejoin=True)
    train(data, tmp_path / "run", "darkgs", cfg, seed=0, progress=False)
    report = json.loads((tmp_path / "run" / "gaussian_budget.json").read_text())
    assert report["settings"]["judge_from"] == cfg.densify_from == 60
    assert [c["step"] for c in report["checks"]] == [60, 90]
    grown = [json.loads(line) for line in (tmp_path / "run" / "metrics.jsonl").read_text().splitlines()]
    assert any(r.get("split", 0) + r.get("cloned", 0) > 0 for r in grown if r.get("step") == 30)


def test_normals_of_sfm_points_are_estimated_unless_switched_off(room, tmp_path):
    from spotlessgs.training.data import initial_point_cloud, load_training_views

    root, _seq = room
    data = tmp_path / "data"
    shutil.copytree(root, data)
    add_sfm_points(data)
    views = load_training_views(data)
    estimated = initial_point_cloud(views, np.random.default_rng(0))
    assert estimated.normals is not None and np.allclose(np.linalg.norm(estimated.normals, axis=1), 1.0)
    kept = initial_point_cloud(views, np.random.default_rng(0), estimate=False)
    assert (kept.normals is None or not kept.normals.any()) and np.array_equal(kept.xyz, estimated.xyz)


def test_only_a_dense_start_with_normals_is_trusted_with_its_geometry(room, tmp_path):
    from spotlessgs.training.config import preset
    from spotlessgs.training.data import load_training_views
    from spotlessgs.training.trainer import start_geometry_settings

    root, _seq = room
    data = tmp_path / "data"
    shutil.copytree(root, data)
    auto = preset("quick").replace(trust_start_geometry="auto")
    trusted = auto.replace(lr_normals=0.0, lamp_bounce=True, brdf_upper_clamp=False, bounce_light_degree=-1,
                           rid_model="monotone", low_frequency_shading="irradiance")
    assert start_geometry_settings(auto, load_training_views(data), "spotless") == auto  # no cloud: a random start
    points = add_sfm_points(data)["points"]
    views = load_training_views(data)
    assert start_geometry_settings(auto, views, "spotless") == auto  # a sparse SfM start: normals learned, no bounce
    on = auto.replace(trust_start_geometry="on")
    assert start_geometry_settings(on, views, "spotless") == trusted.replace(trust_start_geometry="on")
    small = auto.replace(init_points=points, max_gaussians=points)  # the same cloud is dense for a smaller limit
    assert start_geometry_settings(small, views, "spotless") == trusted.replace(init_points=points,
                                                                                max_gaussians=points)
    # ... unless it has no normals and gets none estimated
    assert start_geometry_settings(small.replace(estimate_normals=False), views, "spotless").lamp_bounce is False
    assert start_geometry_settings(trusted, views, "spotless") == trusted  # applying it twice changes nothing more
    # only a model with an SH light and a learned BRDF trusts it (a Lambertian albedo paints a metal's glint in)
    for variant in ("darkgs", "darkgs-calibrated", "darkgs+brdf", "darkgs+sh", "3dgs"):
        assert start_geometry_settings(small, views, variant) == small
    off = small.replace(trust_start_geometry="off", lamp_bounce=True)  # off: the settings as given
    assert start_geometry_settings(off, views, "spotless") == off
