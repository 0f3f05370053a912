"""The relighting ceiling (``spotless ceiling``): the renderer's albedo scored against the ground truth like a method."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from spotlessgs.cli import main
from spotlessgs.io.cameras import Intrinsics
from spotlessgs.io.colorspace import linear_to_srgb
from spotlessgs.io.errors import InputError
from spotlessgs.io.exr import FrameEXR, write_frame_exr
from spotlessgs.io.images import read_image, write_png
from spotlessgs.io.transforms import DatasetMeta, FrameRecord, write_transforms


def _dataset(root, with_albedo=True, frames=12, light_per_normal=False, uniform=False, glossy=None):
    """``frames`` views of 16 x 12 pixels (test views 0 and 11) with random unit normals: each frame's ground truth is
    its albedo (random colours) times 0.5, or with ``light_per_normal`` times a light that depends on the normal,
    (0.5 + 0.3 n_z, 0.4, 0.6 - 0.2 n_x) per channel; the input is a dimmer copy. With ``uniform`` the dataset also
    has the uniform ground truth, the albedo itself (gt_uniform/, the EXRs' gt_uniform channels). ``glossy``
    (True / False): the surfaces' reflectance is split into a diffuse colour (the albedo pass) and a glossy colour of
    random share, stored as the glossy pass (True) or left out of the EXR (False, a dataset from before the pass)."""
    rng = np.random.default_rng(1)
    records = []
    for k in range(frames):
        name = f"frame_{k:05d}"
        albedo = rng.uniform(0.05, 0.95, (12, 16, 3)).astype(np.float32)
        normal = rng.normal(size=(12, 16, 3))
        normal = (normal / np.linalg.norm(normal, axis=-1, keepdims=True)).astype(np.float32)
        light = np.stack([0.5 + 0.3 * normal[..., 2], np.full((12, 16), 0.4), 0.6 - 0.2 * normal[..., 0]], -1)
        gt = (albedo * (light if light_per_normal else 0.5)).astype(np.float32)
        share = rng.uniform(0.0, 1.0, (12, 16, 1)).astype(np.float32) if glossy is not None else 0.0
        write_frame_exr(root / "exr" / f"{name}.exr", FrameEXR(
            uneven=0.2 * gt, gt=gt, depth=np.ones((12, 16), np.float32), normal=normal,
            albedo=(1 - share) * albedo if with_albedo else None, gt_uniform=albedo if uniform else None,
            glossy=share * albedo if glossy else None))
        if uniform:
            write_png(root / "gt_uniform" / f"{name}.png", linear_to_srgb(albedo))
        write_png(root / "images" / f"{name}.png", linear_to_srgb(0.2 * gt))
        write_png(root / "gt" / f"{name}.png", linear_to_srgb(gt))
        records.append(FrameRecord(f"images/{name}.png", np.eye(4), gt_file_path=f"gt/{name}.png",
                                   exr_file_path=f"exr/{name}.exr"))
    renderer = {"ground_truths": {"lamps": "gt", "uniform": "gt_uniform"}} if uniform else {}
    write_transforms(root / "transforms.json", Intrinsics.from_fov(60.0, 16, 12), records,
                     DatasetMeta(scene_id="ceiling", test_every=11, renderer=renderer))
    return root


def test_albedo_times_one_gain_is_scored_on_the_test_views(tmp_path):
    """The ground truth is exactly albedo x 0.5: the albedo oracle's aligned gain is 0.5 and its aligned PSNR is
    limited only by the 8-bit images; without the gain (plain PSNR) it is far lower."""
    data = _dataset(tmp_path / "data")
    result = CliRunner().invoke(main, ["ceiling", str(data), "--out", str(tmp_path / "ceiling"), "--no-lpips",
                                       "--quiet"])
    assert result.exit_code == 0, result.output + repr(result.exception)
    scores = json.loads((tmp_path / "ceiling" / "eval-albedo" / "results.json").read_text())
    assert sorted(p.name for p in (tmp_path / "ceiling" / "albedo").iterdir()) == ["frame_00000.png",
                                                                                   "frame_00011.png"]
    assert scores["exposure_gain"] == pytest.approx(0.5, rel=0.01)
    assert scores["psnr_aligned"] > 40.0 and scores["psnr"] < scores["psnr_aligned"] - 10.0
    np.testing.assert_array_equal(read_image(tmp_path / "ceiling" / "gt" / "frame_00011.png"),
                                  read_image(data / "gt" / "frame_00011.png"))


def test_the_oracles_reflect_with_the_diffuse_and_the_glossy_colour(tmp_path):
    """Surfaces whose reflectance is part diffuse, part glossy colour (a metal's is all glossy): with the glossy pass
    the oracle is their sum and exact; a dataset rendered before the pass has only the diffuse colour, which the
    oracle then uses (and says so), far below."""
    runs = {}
    for glossy in (True, False):
        data = _dataset(tmp_path / f"data-{glossy}", glossy=glossy)
        result = CliRunner().invoke(main, ["ceiling", str(data), "--out", str(tmp_path / f"ceiling-{glossy}"),
                                           "--no-lpips", "--quiet"])
        assert result.exit_code == 0, result.output + repr(result.exception)
        runs[glossy] = json.loads((tmp_path / f"ceiling-{glossy}" / "eval-albedo" / "results.json").read_text())
    assert runs[True]["reflectance"] == "diffuse + glossy colour" and runs[True]["psnr_aligned"] > 40.0
    assert runs[False]["reflectance"] == "diffuse colour (no glossy pass)"
    assert runs[False]["psnr_aligned"] < runs[True]["psnr_aligned"] - 15.0


def test_the_light_per_normal_is_fitted_and_explains_a_normal_dependent_ground_truth(tmp_path):
    """A light linear in the normal (SH degree 1) lies in the oracle's SH-3 span: its coefficients come back exactly
    and the albedo-sh oracle reproduces the ground truth, while albedo x one gain cannot."""
    from evaluation.ceiling import ceiling, fit_light_per_normal, normal_basis
    from evaluation.runner import EvalConfig
    from spotlessgs.io.exr import read_frame_exr

    data = _dataset(tmp_path / "data", light_per_normal=True)
    frames = [read_frame_exr(data / "exr" / f"frame_{k:05d}.exr") for k in (0, 11)]
    c = fit_light_per_normal(frames, [normal_basis(f) for f in frames])
    y00, y1 = 0.28209479177387814, 0.4886025119029199  # SH constants: Y_0^0, and Y_1^m = -/+ y1 * (y, z, x)
    np.testing.assert_allclose(c[:, 0], np.array([0.5, 0.4, 0.6]) / y00, atol=1e-4)
    np.testing.assert_allclose(c[0, 2], 0.3 / y1, atol=1e-4)  # n_z in the red channel
    np.testing.assert_allclose(c[2, 3], 0.2 / y1, atol=1e-4)  # -0.2 n_x in the blue channel (Y_1^1 = -y1 x)
    np.testing.assert_allclose(c[:, 4:], 0.0, atol=1e-4)
    scores = ceiling(data, tmp_path / "ceiling", EvalConfig(lpips=False, progress=False))
    assert scores["albedo-sh"]["psnr_aligned"] > 40.0
    assert scores["albedo"]["psnr_aligned"] < scores["albedo-sh"]["psnr_aligned"] - 10.0


def test_the_ceiling_against_the_uniform_ground_truth(tmp_path):
    """The uniform ground truth is the albedo itself: the albedo oracle needs a gain of 1 and is exact; the scored
    ground truth is gt_uniform/; a dataset without it is refused in one line naming its transforms.json."""
    from spotlessgs.io.dataset import ground_truth_paths, read_dataset

    data = _dataset(tmp_path / "data", light_per_normal=True, uniform=True)
    assert ground_truth_paths(read_dataset(data), "uniform")[3] == data / "gt_uniform" / "frame_00003.png"
    result = CliRunner().invoke(main, ["ceiling", str(data), "--out", str(tmp_path / "ceiling"), "--ground-truth",
                                       "uniform", "--no-lpips", "--quiet"])
    assert result.exit_code == 0, result.output + repr(result.exception)
    scores = json.loads((tmp_path / "ceiling" / "eval-albedo" / "results.json").read_text())
    assert scores["ground_truth"] == "uniform"
    # the oracle's PNGs are the ground truth's bytes: an infinite PSNR (JSON null) and an SSIM of 1
    assert scores["exposure_gain"] == pytest.approx(1.0, rel=0.01)
    assert scores["psnr"] is None and scores["ssim"] == pytest.approx(1.0)
    np.testing.assert_array_equal(read_image(tmp_path / "ceiling" / "gt" / "frame_00011.png"),
                                  read_image(data / "gt_uniform" / "frame_00011.png"))
    plain = _dataset(tmp_path / "plain")
    result = CliRunner().invoke(main, ["ceiling", str(plain), "--out", str(tmp_path / "c2"), "--ground-truth",
                                       "uniform", "--quiet"])
    assert result.exit_code != 0
    assert f"{plain / 'transforms.json'}: the dataset has no 'uniform' ground truth" in result.output
    assert "spotless-sim render --gt uniform" in result.output and not (tmp_path / "c2").exists()


def test_a_dataset_without_the_albedo_pass_is_refused_naming_the_file(tmp_path):
    from evaluation.ceiling import write_oracles

    data = _dataset(tmp_path / "old", with_albedo=False)
    with pytest.raises(InputError, match=r"frame_00000.exr: no albedo pass .* render the dataset again"):
        write_oracles(data, tmp_path / "ceiling")
    result = CliRunner().invoke(main, ["ceiling", str(data), "--out", str(tmp_path / "c2"), "--quiet"])
    assert result.exit_code != 0 and "no albedo pass" in result.output


def test_lamp_masked_metrics_leave_out_the_pixels_that_the_emission_pass_marks(tmp_path):
    """A prediction that is exact except on the ground truth's lamp (a 4 x 4 block whose EXR emission is its whole
    radiance): the plain metrics see the error, the *_masked ones do not (PSNR inf, SSIM 1 where the window avoids
    the lamp, LPIPS lower); a pair without EXR gets no masked keys."""
    from evaluation.folders import ImagePair
    from evaluation.runner import EvalConfig, score_pairs

    rng = np.random.default_rng(3)
    gt_lin = rng.uniform(0.1, 0.6, (32, 48, 3)).astype(np.float32)
    emission = np.zeros_like(gt_lin)
    gt_lin[4:8, 4:8] = 0.95
    emission[4:8, 4:8] = 0.95
    pred_lin = gt_lin.copy()
    pred_lin[4:8, 4:8] = 0.05  # the relit image has no glowing lamp
    write_frame_exr(tmp_path / "f.exr", FrameEXR(uneven=gt_lin, gt=gt_lin, depth=np.ones((32, 48), np.float32),
                                                 normal=np.zeros((32, 48, 3), np.float32), emission=emission))
    write_png(tmp_path / "pred.png", linear_to_srgb(pred_lin))
    write_png(tmp_path / "gt.png", linear_to_srgb(gt_lin))
    config = EvalConfig(temporal=False, progress=False)
    scores = score_pairs([ImagePair("f.png", tmp_path / "pred.png", tmp_path / "gt.png", tmp_path / "f.exr")], config)
    assert scores["psnr"] < 25.0 and scores["psnr_masked"] == float("inf")
    assert scores["ssim_masked"] == pytest.approx(1.0) and scores["ssim"] < 0.99
    # LPIPS's deep layers see the lamp from every cell of these small images: masked, it drops only a little
    assert scores["lpips_masked"] < scores["lpips"]
    assert scores["exposure_gain_masked"] == pytest.approx(1.0, abs=1e-6)
    assert scores["psnr_aligned_masked"] == float("inf")
    plain = score_pairs([ImagePair("f.png", tmp_path / "pred.png", tmp_path / "gt.png")], config)
    assert not any(k.endswith("_masked") for k in plain) and plain["psnr"] == scores["psnr"]


def test_the_ceiling_never_writes_into_another_folder_or_another_datasets_ceiling(tmp_path):
    """--out holding another dataset (its gt/ would be overwritten) or another dataset's ceiling is refused, each file
    left as it was; the same dataset's ceiling is written again in place."""
    data, other = _dataset(tmp_path / "data"), _dataset(tmp_path / "other")
    before = {p: p.read_bytes() for p in other.rglob("*") if p.is_file()}
    result = CliRunner().invoke(main, ["ceiling", str(data), "--out", str(other), "--no-lpips", "--quiet"])
    assert result.exit_code == 2 and "holds files but no ceiling.json" in result.output
    assert {p: p.read_bytes() for p in other.rglob("*") if p.is_file()} == before

    from evaluation.ceiling import EvalConfig, ceiling

    config = EvalConfig(lpips=False, temporal=False, progress=False, num_threads=1)
    first = ceiling(data, tmp_path / "ceiling", config)["albedo"]["psnr_aligned"]
    assert ceiling(data, tmp_path / "ceiling", config)["albedo"]["psnr_aligned"] == first
    record = json.loads((tmp_path / "ceiling" / "ceiling.json").read_text())
    assert record["data"] == str(data.resolve()) and record["ground_truth"] == "lamps"
    with pytest.raises(InputError, match=r"ceiling: holds the ceiling of .*data \(lamps ground truth\), not of this "
                                         r"dataset"):
        ceiling(other, tmp_path / "ceiling", config)
