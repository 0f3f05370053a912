"""End to end: ``spotless reproduce --preset tiny`` (Blender renders, every model, 2D baselines, SfM, report).

About 4-5 minutes on a busy 2-core CPU; it is part of the default suite (the issue's acceptance: CI runs the tiny
preset). One module-scoped run serves every test.
"""

from __future__ import annotations

import json
import math
import re
import shutil
import time

import pytest
from click.testing import CliRunner

from spotlessgs.cli import main
from spotlessgs.experiments.reproduce.config import preset
from spotlessgs.experiments.reproduce.pipeline import reproduce
from spotlessgs.jobs.graph import marker_path

pytestmark = [pytest.mark.blender]

TABLE_KEYS = ["table1", "table2", "table3", "table4", "runtime", "robot", "ceiling", "uniform"]


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("reproduce") / "tiny"
    start = time.perf_counter()
    result = CliRunner().invoke(main, ["reproduce", "--preset", "tiny", "--out", str(out), "--jobs", "2"])
    seconds = time.perf_counter() - start
    assert result.exit_code == 0, result.output + repr(result.exception)
    return out, seconds, result.output


def _ours(table: dict) -> list[list]:
    return [r for r in table["rows"] if not str(r[0]).startswith("paper")]


def test_report_has_every_table_with_finite_numbers(tiny_run):
    out, seconds, output = tiny_run
    assert "ran 39 stage(s), skipped 0" in output
    report = (out / "REPORT.md").read_text()
    for heading in ("### Table I —", "### Table II —", "### Table III —", "### Table IV —", "### Runtime",
                    "## Agreement with the paper's ordering"):
        assert heading in report
    assert "| paper (synthetic) | SpotlessGS (ours) | 12.67 | 0.727 | 0.381 |" in report
    results = json.loads((out / "results.json").read_text())
    for key in TABLE_KEYS:
        rows = _ours(results["tables"][key])
        assert rows, key
        for row in rows:
            numbers = [v for v in row[2:] if isinstance(v, (int, float))]
            assert numbers and all(math.isfinite(v) for v in numbers), (key, row)
    # Tables I, II and IV have every metric of every row (SfM may legitimately register nothing at this size).
    for key in ("table1", "table2", "table4"):
        for row in _ours(results["tables"][key]):
            assert all(isinstance(v, float) and math.isfinite(v) for v in row[2:8]), (key, row)
    # What each 3D run needed: its model and final Gaussian count (Tables I, II and the runtime table).
    for key in ("table1", "table2", "runtime"):
        columns = results["tables"][key]["columns"]
        chosen, gaussians = columns.index("Model chosen"), columns.index("Gaussians")
        for row in _ours(results["tables"][key]):
            if row[1] in ("Input (spotlight-lit)", "CLAHE", "MSRCR (Retinex)", "Cycle-GAN"):
                continue
            assert isinstance(row[chosen], str) and isinstance(row[gaussians], int) and row[gaussians] > 0, (key, row)
    for row in _ours(results["tables"]["table3"]):
        assert isinstance(row[4], int) and 0 <= row[4] <= 12
    runtime = _ours(results["tables"]["runtime"])
    spotless = next(r for r in runtime if r[0] == "bedroom-uneven" and r[1] == "SpotlessGS (ours)")
    assert spotless[2] == "spotless (sh3+mlp)" and spotless[5] is None  # a fixed model: no selection
    assert spotless[4] > 0 and spotless[7] > 0 and spotless[8] >= spotless[9] > 0  # time, FPS, peak >= baseline
    auto = next(r for r in runtime if r[0] == "bedroom-uneven" and r[1] == "SpotlessGS auto (selection + budget)")
    assert auto[2].startswith("auto-sh") and auto[4] > auto[5] > 0 and auto[7] > 0  # time includes selection
    assert "| SpotlessGS auto (selection + budget) | auto-sh" in report


def test_results_json_structure(tiny_run):
    out, _, _ = tiny_run
    results = json.loads((out / "results.json").read_text())
    assert {"preset", "config", "datasets", "cyclegan", "tables", "agreement", "paper", "figures", "stage_seconds",
            "provenance"} <= set(results)
    assert results["preset"] == "tiny" and set(results["datasets"]) == {"bedroom-uneven", "bedroom-saturated",
                                                                        "bedroom-uneven-noisy", "bedroom-robot",
                                                                        "bedroom-rgbd"}
    ds = results["datasets"]["bedroom-uneven"]
    assert set(ds["methods"]) == {"3dgs", "darkgs", "darkgs-calibrated", "darkgs+sh", "darkgs+brdf", "spotless",
                                  "auto"}
    assert ds["methods"]["spotless"]["decisions"]["model chosen"] == "spotless"
    auto = ds["methods"]["auto"]
    assert auto["decisions"]["model chosen"] == auto["selection"]["chosen"]
    assert auto["decisions"]["Gaussians"] == auto["train"]["num_gaussians"] > 0
    assert [p["step"] for p in auto["curve"]] == [75, 150]
    assert auto["selection"]["seconds"] < auto["curve"][0]["train_seconds"]
    assert set(ds["baselines2d"]) == {"clahe", "msrcr", "cyclegan"}
    # The uneven inputs are scored once per dataset (eval-inputs stage), not in every method's evaluation.
    assert ds["input"]["num_images"] == 2 and ds["input"]["sfm"]["total_images"] == 12
    assert all("input" not in m["metrics"] for m in ds["methods"].values())
    assert json.loads((out / "inputs" / "bedroom-uneven" / "results.json").read_text())["psnr"] == ds["input"]["psnr"]
    assert not (out / "runs" / "bedroom-uneven" / "spotless" / "eval" / "sfm" / "input").exists()
    assert results["datasets"]["bedroom-saturated"]["baselines2d"] == {}
    curve = ds["methods"]["spotless"]["curve"]
    assert [p["step"] for p in curve] == [75, 150]
    assert curve[0]["train_seconds"] < curve[1]["train_seconds"]
    assert ds["methods"]["spotless"]["metrics"]["psnr_aligned"] == curve[1]["psnr_aligned"]
    assert {a["status"] for a in results["agreement"]} <= {"agrees", "disagrees", "unknown"}
    assert len(results["agreement"]) >= 10
    claims = {a["claim"]: a for a in results["agreement"]}
    for ds_name in ("bedroom-uneven", "bedroom-saturated"):
        psnr = claims[f"Auto on {ds_name}: relit PSNR (aligned) within the selection tolerance plus the budget "
                      "bound of SpotlessGS"]
        count = claims[f"Auto on {ds_name}: no more Gaussians than SpotlessGS"]
        assert psnr["status"] in ("agrees", "disagrees") and "Gaussian budget bound" in psnr["text"]
        assert count["status"] in ("agrees", "disagrees") and "Gaussians:" in count["text"]
    assert results["paper"]["table3"]["spotless"]["reprojection_error_px"] == 0.463
    # The Cycle-GAN saw other rooms only.
    assert all("bedroom" not in d for d in results["cyclegan"]["uneven_dirs"] + results["cyclegan"]["even_dirs"])


def test_sensor_noise_copy_for_table_three(tiny_run):
    """The uneven renders with camera noise: same ground truth and poses, noisy inputs, SpotlessGS only, in Table III
    and the SfM acceptance note."""
    import numpy as np

    from spotlessgs.io.images import read_image

    out, _, _ = tiny_run
    clean, noisy = out / "datasets" / "bedroom-uneven", out / "datasets" / "bedroom-uneven-noisy"
    assert (noisy / "transforms.json").read_bytes() == (clean / "transforms.json").read_bytes()
    name = sorted(p.name for p in (clean / "gt").iterdir())[0]
    assert np.array_equal(read_image(noisy / "gt" / name), read_image(clean / "gt" / name))
    frame = sorted(p.name for p in (clean / "images").iterdir())[0]
    difference = np.abs(read_image(noisy / "images" / frame) - read_image(clean / "images" / frame))
    assert 0.003 < float(difference.mean()) < 0.1  # noise, not a different image
    results = json.loads((out / "results.json").read_text())
    entry = results["datasets"]["bedroom-uneven-noisy"]
    assert set(entry["methods"]) == {"spotless"} and entry["baselines2d"] == {}
    assert entry["sensor_noise"]["shot"] == 0.002 and entry["input"]["sfm"]["total_images"] == 12
    t3 = [r for r in _ours(results["tables"]["table3"]) if r[0] == "bedroom-uneven-noisy"]
    assert [r[1] for r in t3][:2] == ["Original (spotlight-lit)", "SpotlessGS (ours)"]
    claims = {a["claim"]: a for a in results["agreement"]}
    sfm = claims["Acceptance on bedroom-uneven-noisy: SfM on SpotlessGS's relit sequence at least as good as on "
                 "the original"]
    assert sfm["status"] in ("agrees", "disagrees", "unknown") and "relit (SpotlessGS)" in sfm["text"]
    assert not [c for c in claims if c.startswith("Table I ordering on bedroom-uneven-noisy")]


def test_robot_camera_copy_starts_from_triangulated_points_and_is_set_against_the_ideal_input(tiny_run):
    """The uneven renders through a robot camera (lens, auto-exposure, vignetting, noise) without the depth cloud:
    the start is triangulated on its images; the relit views come out in the lens camera's geometry; the report
    sets SpotlessGS against the ideal input with the acceptance checks."""
    from spotlessgs.io.dataset import read_dataset
    from spotlessgs.io.images import read_image

    out, _, _ = tiny_run
    robot = out / "datasets" / "bedroom-robot"
    data = read_dataset(robot)
    assert data.intrinsics.lens == "opencv" and data.intrinsics.distortion[:2] == (-0.18, 0.03)
    assert not (robot / "points3d.ply").exists() and not (robot / "sparse").exists()  # no depth-derived points
    results = json.loads((out / "results.json").read_text())
    entry = results["datasets"]["bedroom-robot"]
    assert set(entry["methods"]) == {"spotless"} and entry["baselines2d"] == {}
    points = entry["robot_camera"]["points"]
    notes = " ".join(results["tables"]["robot"]["notes"])
    if points is None:  # 10 training frames at 96x72: too few features to triangulate; the start is random
        assert "no point could be triangulated" in entry["robot_camera"]["points_error"] and data.ply_path is None
        assert "the start is random points" in notes
    else:
        assert points["points"] > 0 and data.ply_path == robot / "sfm_points.ply"
        assert f"the start is {points['points']} points triangulated" in notes
    assert entry["robot_camera"]["camera_effects"]["sensitivity"] == 0.25
    relit = out / "runs" / "bedroom-robot" / "spotless" / "relit"
    assert read_image(relit / data.image_paths[0].name).shape == (72, 96, 3)  # the input camera's size
    rows = _ours(results["tables"]["robot"])
    columns = results["tables"]["robot"]["columns"]
    ours = next(r for r in rows if r[1] == "SpotlessGS (ours)")
    ideal = results["datasets"]["bedroom-uneven"]["methods"]["spotless"]["metrics"]["psnr_aligned"]
    assert ours[columns.index("PSNR (aligned), ideal input")] == ideal
    assert ours[columns.index("Loss (dB)")] == pytest.approx(ideal - entry["methods"]["spotless"]["metrics"][
        "psnr_aligned"])
    flicker = columns.index("Flicker")
    inputs = next(r for r in rows if r[1] == "Input (spotlight-lit)")
    truth = next(r for r in rows if r[1] == "Ground truth (evenly lit)")
    assert inputs[flicker] > 0 and truth[flicker] > 0 and inputs[flicker] != truth[flicker]
    uniform = next(r for r in rows if r[1] == "Uniform ground truth (even, shadow-free)")
    assert uniform[flicker] > 0 and uniform[flicker] != truth[flicker]
    # the relit steps beyond each truth's: at least the difference of the flickers (mean |a - b| >= |mean |a| -
    # mean |b||); the truths have none of their own
    for column, reference in (("Flicker beyond the GT", truth), ("Flicker beyond the uniform GT", uniform)):
        assert ours[columns.index(column)] >= abs(ours[flicker] - reference[flicker]) - 1e-12
        assert ours[columns.index(column)] > 0 and reference[columns.index(column)] is None
    leak = columns.index("Exposure leak")  # the camera's true gains are known: every sequence gets its slope
    assert all(isinstance(r[leak], float) and math.isfinite(r[leak]) for r in (ours, inputs))
    claims = {a["claim"]: a for a in results["agreement"]}
    for claim in ("SpotlessGS within 0.7 dB of the ideal input (PSNR aligned)",
                  "SpotlessGS at least 4.0 dB above its inputs (PSNR aligned)",
                  "the relit sequence flickers no more than the ground truth",
                  "the relit sequence flickers no more than the uniform ground truth"):
        assert claims[f"Acceptance on bedroom-robot: {claim}"]["status"] in ("agrees", "disagrees")
    excess = ours[columns.index("Flicker beyond the uniform GT")]
    assert f"beyond the uniform ground truth's steps (what enters the view) {excess:.3f}" in claims[
        "Acceptance on bedroom-robot: the relit sequence flickers no more than the ground truth"]["text"]
    assert "### Robot camera — what each method loses against the ideal input" in (out / "REPORT.md").read_text()


def test_the_rgbd_copy_starts_from_its_depth_images_and_is_trusted(tiny_run):
    """The robot copy with an RGB-D camera: the same images as the robot copy, depth images registered to them, a
    start back-projected from them with normals, which SpotlessGS trusts (its normals held, the bounce light on);
    the robot table sets it against the ideal input and says where its start came from."""
    from spotlessgs.io.dataset import read_dataset
    from spotlessgs.io.ply import read_point_cloud

    out, _, _ = tiny_run
    rgbd, robot = out / "datasets" / "bedroom-rgbd", out / "datasets" / "bedroom-robot"
    data = read_dataset(rgbd)
    assert data.depth_paths is not None and all(p.is_file() for p in data.depth_paths)
    for name in ("frame_00001.png", "frame_00007.png"):  # the robot copy's frames, byte for byte
        assert (rgbd / "images" / name).read_bytes() == (robot / "images" / name).read_bytes()
    cloud = read_point_cloud(data.ply_path)
    assert data.ply_path.name == "depth_points.ply" and len(cloud.xyz) > 1000 and cloud.normals is not None
    results = json.loads((out / "results.json").read_text())
    entry = results["datasets"]["bedroom-rgbd"]
    assert entry["robot_camera"]["depth_camera"]["noise"] == 0.0025
    assert entry["robot_camera"]["points"]["source"] == "depth images"
    model_config = json.loads((out / "runs" / "bedroom-rgbd" / "spotless" / "config.json").read_text())
    assert model_config["model_config"]["lamp_bounce"] is True  # the trusted start's bounce light
    notes = " ".join(results["tables"]["robot"]["notes"])
    assert f"the start is {len(cloud.xyz)} points back-projected from them, with normals" in notes
    assert any(r[0] == "bedroom-rgbd" and r[1] == "SpotlessGS (ours)" for r in results["tables"]["robot"]["rows"])


def test_every_dataset_is_set_against_its_relighting_ceiling(tiny_run):
    """Each dataset's ceiling oracles (the renderer's albedo × one gain and × the best light per normal) and every
    method, with and without the lamps, and each row's distance to the SH oracle; the acceptance claim per dataset."""
    out, _, _ = tiny_run
    results = json.loads((out / "results.json").read_text())
    table = results["tables"]["ceiling"]
    below = table["columns"].index("Below the ceiling (dB), no lamps")
    for ds in ("bedroom-uneven", "bedroom-saturated", "bedroom-uneven-noisy", "bedroom-robot"):
        rows = {r[1]: r for r in table["rows"] if r[0] == ds}
        sh, gain = rows["Ceiling: true albedo × best light per normal"], rows["Ceiling: true albedo × one gain"]
        assert sh[below] == 0.0 and all(isinstance(v, float) and math.isfinite(v) for v in sh[2:] + gain[2:])
        spotless = rows["SpotlessGS (ours)"]
        assert spotless[below] == pytest.approx(sh[5] - spotless[5])
        assert (out / "ceiling" / ds / "eval-albedo-sh" / "results.json").is_file()
    claims = {a["claim"]: a for a in results["agreement"]}
    claim = next(c for c in claims if c.startswith("Ceiling on bedroom-uneven: SpotlessGS within 1.5 dB"))
    assert claims[claim]["status"] in ("agrees", "disagrees") and "dB below" in claims[claim]["text"]


def test_every_row_is_also_scored_against_the_uniform_ground_truth(tiny_run):
    """The test rooms are rendered with the uniform ground truth (their copies carry it over): every row of the
    ceiling table, the 2D baselines too, is scored against it; its albedo oracle needs a gain near 1 (the uniform
    ground truth is the albedo under radiance 1, up to the specular layer) and beats every method."""
    out, _, _ = tiny_run
    results = json.loads((out / "results.json").read_text())
    table = results["tables"]["uniform"]
    col = {name: table["columns"].index(name) for name in table["columns"]}
    for ds in ("bedroom-uneven", "bedroom-saturated", "bedroom-uneven-noisy", "bedroom-robot"):
        assert (out / "datasets" / ds / "gt_uniform").is_dir()
        rows = {r[1]: r for r in table["rows"] if r[0] == ds}
        sh = rows["Ceiling: true albedo × best light per normal"]
        assert sh[col["Below the uniform ceiling (dB)"]] == 0.0
        spotless = rows["SpotlessGS (ours)"]
        assert isinstance(spotless[col["PSNR (aligned), uniform GT"]], float)
        assert spotless[col["Below the uniform ceiling (dB)"]] > 0.0
        assert (out / "runs" / ds / "spotless" / "eval-uniform" / "results.json").is_file()
        gain = json.loads((out / "ceiling" / ds / "uniform" / "eval-albedo" / "results.json").read_text())
        assert gain["ground_truth"] == "uniform" and 0.95 < gain["exposure_gain"] < 1.15
    uneven = {r[1] for r in table["rows"] if r[0] == "bedroom-uneven"}
    assert {"CLAHE", "MSRCR (Retinex)", "Cycle-GAN", "Input (spotlight-lit)"} <= uneven
    assert "### Against the uniform ground truth" in (out / "REPORT.md").read_text()


def test_figures_exist(tiny_run):
    out, _, _ = tiny_run
    from PIL import Image

    for name in ("qualitative_bedroom-uneven.png", "qualitative_bedroom-saturated.png", "speed_vs_error.png"):
        with Image.open(out / "figures" / name) as img:
            assert img.width > 200 and img.height > 100
    report = (out / "REPORT.md").read_text()
    assert "![" in report
    # the qualitative grid: input, every relighting, the ceiling and both ground truths
    assert re.search(r"Qualitative comparison, bedroom-uneven \(Input / 3DGS / DarkGS[^/]* / Ours / Ours \(auto\) / "
                     r"Ceiling \(true albedo\) / Ground truth / Uniform ground truth\)", report)


def test_rerun_skips_everything_and_redoes_an_interrupted_stage(tiny_run):
    out, _, _ = tiny_run
    config = preset("tiny")
    start = time.perf_counter()
    again = reproduce(config, out, jobs=2)
    assert again.ran == [] and len(again.skipped) == 39 and time.perf_counter() - start < 5.0

    # Interrupt one training stage after its last checkpoint: its marker is gone, its evaluation was not written and
    # a killed atomic write left a temporary file. The stage resumes from the checkpoint (it is not started again
    # from scratch) and keeps the curve points it had scored: the same numbers.
    stage = "train/bedroom-uneven/3dgs"
    marker_path(out, stage).unlink()
    run_dir = out / "runs" / "bedroom-uneven" / "3dgs"
    shutil.rmtree(run_dir / "eval")
    partial = run_dir / ".train_summary.json.partial-1234"
    partial.write_text("half")
    before = json.loads((out / "results.json").read_text())["datasets"]["bedroom-uneven"]["methods"]["3dgs"]
    redo = reproduce(config, out, jobs=2)
    assert redo.retried == [] and redo.ran == [stage, "report"]
    assert not partial.exists() and (run_dir / "eval" / "results.json").is_file()
    after = json.loads((out / "results.json").read_text())["datasets"]["bedroom-uneven"]["methods"]["3dgs"]
    assert after["train"]["resumed_from_step"] == 150 and before["train"]["resumed_from_step"] is None
    assert after["curve"][-1]["step"] == before["curve"][-1]["step"] == 150
    assert [{k: v for k, v in p.items() if k != "train_seconds"} for p in after["curve"]] == \
        [{k: v for k, v in p.items() if k != "train_seconds"} for p in before["curve"]]
    assert after["metrics"]["psnr_aligned"] == before["metrics"]["psnr_aligned"]

    # Interrupt the inputs' evaluation of one dataset: only it and the report are redone, with the same numbers.
    stage = "eval-inputs/bedroom-saturated"
    marker_path(out, stage).unlink()
    before = json.loads((out / "results.json").read_text())["datasets"]["bedroom-saturated"]["input"]
    redo = reproduce(config, out, jobs=2)
    assert redo.retried == [stage] and redo.ran == [stage, "report"]
    assert json.loads((out / "results.json").read_text())["datasets"]["bedroom-saturated"]["input"] == before

    # A deleted report is written again (it was reported as written, and stayed missing)
    report = (out / "REPORT.md").read_text()
    (out / "REPORT.md").unlink()
    redo = reproduce(config, out, jobs=2)
    assert redo.ran == ["report"] and (out / "REPORT.md").read_text().split("## Stage times")[0] == \
        report.split("## Stage times")[0]


def test_other_settings_are_refused(tiny_run):
    out, _, _ = tiny_run
    with pytest.raises(ValueError, match=r"made with other settings \(seed: 0 then, 1 now\)"):
        reproduce(preset("tiny", seed=1), out)
