"""Automatic model selection: the decision rule, the candidates, the settings' errors, the ModelConfig round trip of a
run folder, and `spotless train --model auto` end to end on a synthetic dataset (no Blender)."""

from __future__ import annotations

import dataclasses
import json

import pytest
import torch
from click.testing import CliRunner

from conftest import synthetic_box_dataset
from spotlessgs.models.shading import ModelConfig
from spotlessgs.training.config import preset
from spotlessgs.training.selection import (
    SELECTION_FILE, CandidateResult, SelectionConfig, appearance_parameters, candidate_model, choose, cost_rank,
    format_selection_table, proxy_config, run_decisions, selection_config,
)


pytestmark = pytest.mark.usefixtures("one_torch_thread")


def _result(degree, brdf, psnr):
    return CandidateResult(f"auto-sh{degree}-{brdf}", degree, brdf, psnr, 10.0, 100, 1)


# ---- the decision rule ------------------------------------------------------------------------------------------


def test_the_cheapest_candidate_within_the_tolerance_wins():
    results = [_result(0, "lambert", 20.00), _result(1, "lambert", 20.10), _result(3, "lambert", 20.20),
               _result(0, "mlp", 20.50)]
    assert choose(results, 0.25).name == "auto-sh0-mlp"  # the best Lambert is 0.30 dB behind
    assert choose(results, 0.31).name == "auto-sh3-lambert"
    assert choose(results, 0.5).name == "auto-sh0-lambert"  # exactly at the tolerance counts as within
    assert choose(results, 0.0).name == "auto-sh0-mlp"
    with pytest.raises(ValueError, match="no candidates"):
        choose([], 0.25)


def test_cost_order_puts_lambert_before_mlp_then_lower_degree_first():
    models = [candidate_model(d, b) for b in ("mlp", "lambert") for d in (3, 0, 2, 1)]
    ranked = [m.name for m in sorted(models, key=cost_rank)]
    assert ranked == ["auto-sh0-lambert", "auto-sh1-lambert", "auto-sh2-lambert", "auto-sh3-lambert",
                      "auto-sh0-mlp", "auto-sh1-mlp", "auto-sh2-mlp", "auto-sh3-mlp"]
    # and the measured parameter counts agree with that order within each BRDF: (d+1)^2 * 3 SH coefficients
    lam = [appearance_parameters(candidate_model(d, "lambert")) for d in range(4)]
    assert [b - lam[0] for b in lam] == [3 * ((d + 1) ** 2 - 1) for d in range(4)]
    assert appearance_parameters(candidate_model(0, "mlp")) > lam[3]


def test_candidates_are_spotlight_models_with_an_sh_light():
    m = candidate_model(2, "mlp")
    assert (m.light_model, m.ambient, m.sh_degree, m.brdf) == ("spotlight", "sh", 2, "mlp")
    with pytest.raises(ValueError, match="brdf must be one of"):
        candidate_model(1, "phong")
    with pytest.raises(ValueError, match="degree"):
        candidate_model(4, "lambert")


@pytest.mark.parametrize("kwargs, match", [
    ({"tolerance_db": -0.1}, "tolerance_db"), ({"proxy_fraction": 0.0}, "proxy_fraction"),
    ({"base_fraction": 2.0}, "base_fraction"),
    ({"proxy_fraction": 1.5}, "proxy_fraction"), ({"min_proxy_iterations": 0}, "min_proxy_iterations"),
    ({"validation_every": 1}, "validation_every"), ({"search": "random"}, "search"),
    ({"sh_degrees": (0, 5)}, "sh_degrees"), ({"sh_degrees": ()}, "sh_degrees"),
])
def test_selection_config_rejects_bad_values(kwargs, match):
    with pytest.raises(ValueError, match=match):
        SelectionConfig(**kwargs)


def test_proxy_schedule_is_a_fraction_without_densification():
    full = preset("quick")
    proxy = proxy_config(full, SelectionConfig(proxy_fraction=0.1, validation_every=5))
    assert proxy.iterations == 300 and proxy.validation_every == 5 and not proxy.validation_rejoin
    assert proxy_config(full, SelectionConfig()).iterations == 150  # default: 5 % of 3000 per candidate
    assert proxy_config(full, SelectionConfig(), 0.1).iterations == 300  # the shared base run
    assert proxy.densify_until == 0 and proxy.opacity_reset_every == 0 and not proxy.gaussian_budget
    assert proxy_config(preset("tiny"), SelectionConfig(min_proxy_iterations=150)).iterations == 150
    assert selection_config(0.5, None) == dataclasses.replace(SelectionConfig(), tolerance_db=0.5)


def test_table_lists_every_candidate_and_marks_the_choice():
    decision = {"chosen": "auto-sh1-lambert", "best": "auto-sh1-mlp", "tolerance_db": 0.25,
                "candidates": [dataclasses.asdict(r) for r in (_result(0, "lambert", 19.0),
                                                               _result(1, "lambert", 19.9),
                                                               _result(1, "mlp", 20.0))]}
    lines = format_selection_table(decision).splitlines()
    assert len(lines) == 5  # header, three candidates, the verdict
    assert lines[2].startswith("* auto-sh1-lambert") and "-0.10" in lines[2]
    assert lines[1].startswith("  auto-sh0-lambert") and "-1.00" in lines[1]


# ---- run folders ------------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def box_room(tmp_path_factory):
    return synthetic_box_dataset(tmp_path_factory, "selection-data", seed=4)


def _tiny(**overrides):
    base = dict(iterations=40, image_width=32, num_threads=1, densify_from=10, densify_until=30, densify_every=10,
                opacity_reset_every=0, log_every=10, checkpoint_every=40, init_points=300, max_gaussians=500,
                brdf_hidden=8)
    base.update(overrides)
    return preset("tiny", **base)


def test_a_run_of_any_model_config_is_stored_and_restored(box_room, tmp_path):
    from spotlessgs.training.trainer import load_run, train

    model = candidate_model(1, "lambert")
    result = train(box_room, tmp_path / "run", model, _tiny(validation_every=4), seed=0, progress=False)
    info = json.loads((tmp_path / "run" / "run.json").read_text())
    assert info["model"] == "auto-sh1-lambert" and info["model_config"]["sh_degree"] == 1
    scene, _views, _cfg, _info = load_run(tmp_path / "run", device="cpu")
    assert scene.config == dataclasses.replace(model, brdf_hidden=8)
    assert scene.appearance.lf_light.degree == 1
    assert result.validation_psnr is not None and result.validation_psnr > 0
    assert run_decisions(tmp_path / "run") == {"model chosen": "auto-sh1-lambert", "Gaussians": result.num_gaussians}
    with pytest.raises(FileNotFoundError, match="no run.json"):
        run_decisions(tmp_path)


def test_train_model_auto_writes_the_decision_prints_the_table_and_trains_the_choice(box_room, tmp_path):
    from spotlessgs.cli import main

    out = tmp_path / "auto"
    args = ["train", "--data", str(box_room), "--out", str(out), "--model", "auto", "--preset", "tiny",
            "--iterations", "300", "--width", "32", "--threads", "1", "--max-gaussians", "400", "-q",
            "--tolerance-db", "0.3"]
    res = CliRunner().invoke(main, args)
    assert res.exit_code == 0, res.output
    decision = json.loads((out / SELECTION_FILE).read_text())
    names = [c["name"] for c in decision["candidates"]]
    # coordinate search: the four Lambert degrees, then the MLP at the chosen degree
    assert names[:4] == [f"auto-sh{d}-lambert" for d in range(4)] and names[4].endswith("-mlp") and len(names) == 5
    assert decision["settings"]["proxy_iterations"] == 100 and decision["tolerance_db"] == 0.3
    best = max(c["validation_psnr"] for c in decision["candidates"])
    chosen = next(c for c in decision["candidates"] if c["name"] == decision["chosen"])
    assert chosen["validation_psnr"] >= best - 0.3
    cheaper = [c for c in decision["candidates"]
               if cost_rank(candidate_model(c["sh_degree"], c["brdf"])) < cost_rank(candidate_model(
                   chosen["sh_degree"], chosen["brdf"]))]
    assert all(c["validation_psnr"] < best - 0.3 for c in cheaper)
    assert decision["chosen"] in res.output and "val PSNR" in res.output
    info = json.loads((out / "run.json").read_text())
    assert info["model"] == decision["chosen"] and ModelConfig(**info["model_config"]).name == decision["chosen"]
    summary = json.loads((out / "train_summary.json").read_text())
    assert summary["steps"] == 300 and summary["num_gaussians"] <= 400
    assert not (out / "selection" / names[0] / "checkpoints").exists()  # proxies keep metrics, not checkpoints
    assert not (out / "selection" / "base" / "checkpoints").exists()
    assert decision["base"]["steps"] == 100
    for name in names:  # every candidate started from the shared base run
        assert json.loads((out / "selection" / name / "run.json").read_text())["init_from"] == \
            str((out / "selection" / "base").resolve())
    # same folder again: refused without --resume; with --resume the decision is reused
    again = CliRunner().invoke(main, args)
    assert again.exit_code != 0 and "--resume" in str(again.exception)
    resumed = CliRunner().invoke(main, [*args, "--resume"])
    assert resumed.exit_code == 0, resumed.output
    with pytest.raises(ValueError, match="other selection settings"):
        from spotlessgs.training.selection import select_model

        select_model(box_room, out, _tiny(iterations=300, image_width=32), 0, SelectionConfig(tolerance_db=0.9),
                     resume=True)


def test_selection_options_need_model_auto(box_room, tmp_path):
    from spotlessgs.cli import main

    res = CliRunner().invoke(main, ["train", "--data", str(box_room), "--out", str(tmp_path / "r"), "--model",
                                    "darkgs", "--tolerance-db", "0.5", "-q"])
    assert res.exit_code != 0 and "only apply to --model auto" in res.output


def test_warm_start_copies_gaussians_light_and_the_leading_sh_block():
    from spotlessgs.models.gaussians import GaussianParams
    from spotlessgs.models.relightable import RelightableScene
    from spotlessgs.training.warm_start import warm_start_scene

    import numpy as np

    def scene(model, n, seed):
        xyz = np.random.default_rng(seed).normal(size=(n, 3))
        return RelightableScene.create(model, GaussianParams.from_point_cloud(xyz, np.full((n, 3), 90, np.uint8)),
                                       seed=seed)

    src = scene(candidate_model(1, "lambert"), 7, 0)
    with torch.no_grad():
        src.appearance.lf_light.coeffs.copy_(torch.arange(12.0).reshape(4, 3))
        src.appearance.light.log_gamma.fill_(0.3)
    ckpt = {"gaussians": {k: v.detach() for k, v in src.gaussians.params.items()},
            "appearance": src.modules_.state_dict()}
    dst = warm_start_scene(scene(candidate_model(2, "mlp"), 3, 1), ckpt)
    assert len(dst.gaussians) == 7
    torch.testing.assert_close(dst.gaussians.means, src.gaussians.means)
    assert float(dst.appearance.light.log_gamma.detach()) == pytest.approx(0.3)
    coeffs = dst.appearance.lf_light.coeffs.detach()
    assert coeffs.shape == (9, 3)
    torch.testing.assert_close(coeffs[:4], torch.arange(12.0).reshape(4, 3))
    assert float(coeffs[4:].abs().sum()) == 0.0
    low = warm_start_scene(scene(candidate_model(0, "lambert"), 3, 2), ckpt)  # a lower degree keeps the DC row
    torch.testing.assert_close(low.appearance.lf_light.coeffs.detach(), torch.tensor([[0.0, 1.0, 2.0]]))
    with pytest.raises(ValueError, match="not a training checkpoint"):
        warm_start_scene(dst, {"gaussians": {}}, "x.pt")
    with pytest.raises(ValueError, match="needs a spotlight"):
        warm_start_scene(scene("3dgs", 3, 0), ckpt, "x.pt")
