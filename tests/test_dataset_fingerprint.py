"""A dataset's fingerprint (spotlessgs.io.dataset_fingerprint) and the refusals it makes possible: a resume, a
benchmark's finished row and a model selection's decision on other files than the run trained on."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import shutil

import numpy as np
import pytest

from conftest import synthetic_box_dataset
from spotlessgs.experiments.run_settings import check_finished_row, settings_differences
from spotlessgs.io.dataset import read_dataset
from spotlessgs.io.dataset_fingerprint import dataset_fingerprint, other_dataset, training_input_files
from spotlessgs.io.errors import InputError
from spotlessgs.io.images import read_image, write_png
from spotlessgs.run import RunSpec


@pytest.fixture(scope="module")
def room(tmp_path_factory):
    return synthetic_box_dataset(tmp_path_factory, "fingerprint", seed=4)


def _copy(room, where):
    shutil.copytree(room, where)
    return where


def test_the_fingerprint_hashes_each_training_file_by_its_relative_name_and_bytes(room):
    dataset = read_dataset(room)
    files = training_input_files(dataset)
    assert files == [room / "transforms.json", *(room / "images" / f"frame_{k:05d}.png" for k in range(14))]
    record = json.loads((room / "transforms.json").read_text())  # the documented recipe, computed independently
    for frame in record["frames"]:
        del frame["gt_file_path"]
    del record["spotless"]["provenance"]
    digests = [hashlib.sha256(json.dumps(record, sort_keys=True, separators=(",", ":")).encode()).hexdigest()]
    digests += [hashlib.sha256(path.read_bytes()).hexdigest() for path in files[1:]]
    whole = hashlib.sha256()
    for path, digest in zip(files, digests):
        whole.update(f"{path.relative_to(room).as_posix()}\0{digest}\n".encode())
    assert dataset_fingerprint(dataset) == "sha256:" + whole.hexdigest()


def test_another_ground_truth_or_json_layout_keeps_the_fingerprint(room, tmp_path):
    """What training does not read: a second ground truth rendered into the dataset (its folder, the renderer's
    record of it, a new provenance), or transforms.json written with another layout."""
    original = dataset_fingerprint(read_dataset(room))
    again = _copy(room, tmp_path / "again")
    shutil.copytree(again / "gt", again / "gt_uniform")
    record = json.loads((again / "transforms.json").read_text())
    record["spotless"]["renderer"]["ground_truths"] = {"lamps": "gt", "uniform": "gt_uniform"}
    record["spotless"]["renderer"]["ground_truth_lighting"] = {"color": [1.0, 0.9, 0.8]}
    record["spotless"]["provenance"] = {"created_utc": "2026-11-27T00:00:00Z"}
    (again / "transforms.json").write_text(json.dumps(record, indent=4, sort_keys=True))
    assert dataset_fingerprint(read_dataset(again)) == original
    record["spotless"]["renderer"]["samples"] = 1  # ... but a renderer setting of the training images counts
    (again / "transforms.json").write_text(json.dumps(record))
    assert dataset_fingerprint(read_dataset(again)) != original


def test_a_colmap_folder_is_fingerprinted_by_the_model_its_reader_reads(room, tmp_path):
    pycolmap = pytest.importorskip("pycolmap")
    from spotlessgs.io.colmap_text import model_from_poses, write_colmap_text

    dataset = read_dataset(room)
    folder = tmp_path / "colmap"
    shutil.copytree(room / "images", folder / "images")
    names = [p.name for p in dataset.image_paths]
    sparse = folder / "sparse" / "0"
    write_colmap_text(sparse, model_from_poses(dataset.intrinsics, names, dataset.c2w_opengl))
    text_only = dataset_fingerprint(read_dataset(folder))
    pycolmap.Reconstruction(str(sparse)).write_binary(str(sparse))  # the binary model beside the text one
    colmap = read_dataset(folder)
    assert training_input_files(colmap)[:3] == [sparse / "cameras.bin", sparse / "images.bin", sparse / "points3D.bin"]
    both = dataset_fingerprint(colmap)
    assert both != text_only
    with open(sparse / "images.txt", "a") as f:  # the text model, which the reader leaves alone when a binary exists
        f.write("# edited\n")
    assert dataset_fingerprint(read_dataset(folder)) == both
    moved = dataset.c2w_opengl.copy()
    moved[2, 0, 3] += 0.05
    write_colmap_text(tmp_path / "moved", model_from_poses(dataset.intrinsics, names, moved))
    pycolmap.Reconstruction(str(tmp_path / "moved")).write_binary(str(sparse))  # one pose of the binary model moved
    assert dataset_fingerprint(read_dataset(folder)) not in (both, text_only)


def test_a_moved_dataset_keeps_its_fingerprint_and_any_change_to_its_training_input_changes_it(room, tmp_path):
    original = dataset_fingerprint(read_dataset(room))
    assert dataset_fingerprint(read_dataset(_copy(room, tmp_path / "moved" / "elsewhere"))) == original
    # the ground truth is not training input: another one trains the same
    truth = _copy(room, tmp_path / "truth")
    write_png(truth / "gt" / "frame_00002.png", np.zeros((30, 40, 3), np.float32))
    assert dataset_fingerprint(read_dataset(truth)) == original
    changed = {}
    pixel = _copy(room, tmp_path / "pixel")  # one pixel of one frame
    image = read_image(pixel / "images" / "frame_00003.png")
    image[5, 7] = 1.0 - image[5, 7]
    write_png(pixel / "images" / "frame_00003.png", image)
    changed["pixel"] = pixel
    pose = _copy(room, tmp_path / "pose")  # one pose
    record = json.loads((pose / "transforms.json").read_text())
    record["frames"][1]["transform_matrix"][0][3] += 0.01
    (pose / "transforms.json").write_text(json.dumps(record))
    changed["pose"] = pose
    sidecar = _copy(room, tmp_path / "sidecar")  # a frame's exposure record, which training reads
    (sidecar / "images" / "frame_00000.json").write_text(json.dumps({"exposure_time": 0.01}))
    changed["sidecar"] = sidecar
    assert training_input_files(read_dataset(sidecar))[1:3] == [sidecar / "images" / "frame_00000.png",
                                                                sidecar / "images" / "frame_00000.json"]
    fingerprints = {name: dataset_fingerprint(read_dataset(path)) for name, path in changed.items()}
    assert len({original, *fingerprints.values()}) == 4, fingerprints


def test_the_views_fingerprint_leaves_out_the_start_cloud_and_nothing_else(room, tmp_path):
    """A finished run's relighting reads the views, not the start cloud: a point cloud added (PLY and
    ply_file_path) keeps the views' fingerprint and changes the whole one; a changed pose changes both."""
    from spotlessgs.io.dataset_fingerprint import dataset_fingerprints
    from spotlessgs.io.ply import write_point_cloud

    whole, views = dataset_fingerprints(read_dataset(room))
    assert whole == dataset_fingerprint(read_dataset(room)) and views == whole  # no start cloud: the same files
    clouded = _copy(room, tmp_path / "clouded")
    write_point_cloud(clouded / "start.ply", np.zeros((3, 3)), np.zeros((3, 3), np.uint8))
    record = json.loads((clouded / "transforms.json").read_text())
    (clouded / "transforms.json").write_text(json.dumps({**record, "ply_file_path": "start.ply"}))
    clouded_whole, clouded_views = dataset_fingerprints(read_dataset(clouded))
    assert clouded_views == views and clouded_whole != whole
    record["frames"][1]["transform_matrix"][0][3] += 0.01
    (clouded / "transforms.json").write_text(json.dumps({**record, "ply_file_path": "start.ply"}))
    posed_whole, posed_views = dataset_fingerprints(read_dataset(clouded))
    assert posed_views != views and posed_whole != clouded_whole


def test_an_unreadable_file_is_named(room, tmp_path):
    broken = _copy(room, tmp_path / "broken")
    (broken / "images" / "frame_00001.png").unlink()
    (broken / "images" / "frame_00001.png").mkdir()  # a folder where an image should be: it cannot be read
    with pytest.raises(InputError, match=r"images/frame_00001\.png: cannot read the dataset file"):
        dataset_fingerprint(read_dataset(broken))


def test_a_run_without_a_fingerprint_is_not_compared():
    assert not other_dataset(None, "sha256:00")
    assert not other_dataset("sha256:00", "sha256:00")
    assert other_dataset("sha256:01", "sha256:00")


def test_a_finished_row_trained_on_other_files_is_refused_and_one_on_a_moved_copy_reused(room, tmp_path):
    spec = RunSpec(data=room, model="spotless", preset="tiny")
    run = tmp_path / "row" / "run"
    run.mkdir(parents=True)
    (run / "config.json").write_text(json.dumps({"train": dataclasses.asdict(spec.train_config()),
                                                 "run": {"model": "spotless", "seed": 0}}))
    (run / "run.json").write_text(json.dumps({"data_dir": str(room),
                                              "data_fingerprint": dataset_fingerprint(read_dataset(room))}))
    (tmp_path / "row" / "row.json").write_text("{}")
    check_finished_row(tmp_path / "row", spec)
    moved = _copy(room, tmp_path / "moved")
    check_finished_row(tmp_path / "row", RunSpec(data=moved, model="spotless", preset="tiny"))
    other = _copy(room, tmp_path / "other")
    (other / "images" / "frame_00004.png").write_bytes((room / "images" / "frame_00000.png").read_bytes())
    with pytest.raises(ValueError, match=r"row/run: the row was trained with other settings \(dataset: trained on "
                                         r"other files than .*other holds\); use a new --out"):
        check_finished_row(tmp_path / "row", RunSpec(data=other, model="spotless", preset="tiny"))
    # a run saved before fingerprints has nothing to compare: reused as before
    (run / "run.json").write_text(json.dumps({"data_dir": str(room)}))
    assert settings_differences(run, RunSpec(data=other, model="spotless", preset="tiny")) == []
