"""The Gaussian budget: held-out view split, per-Gaussian contributions (against a one-hot reference), the pruning
rule, the growth stop, the cap, and a tiny end-to-end run on a synthetic dataset (no Blender)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch

from conftest import synthetic_box_dataset
from spotlessgs.io.camera_batch import Cameras
from spotlessgs.io.cameras import Intrinsics
from spotlessgs.models.gaussians import GaussianParams
from spotlessgs.training.budget import BudgetConfig, BudgetStrategy, negligible_mask
from spotlessgs.training.config import TrainConfig, preset
from spotlessgs.training.strategy import DensifyConfig, DensifyStrategy
from spotlessgs.training.validation import evenly_spaced, gaussian_contributions, split_training_views


pytestmark = pytest.mark.usefixtures("one_torch_thread")


# ---- held-out views ---------------------------------------------------------------------------------------------


def test_every_kth_training_view_is_held_out_and_never_a_test_view():
    train = [1, 2, 3, 4, 5, 6, 7, 8, 9, 10]  # 0 and 11 are test views
    split = split_training_views(train, 4)
    assert split.validation == [4, 8]
    assert split.fit == [1, 2, 3, 5, 6, 7, 9, 10]
    assert split_training_views(train, 0).fit == train and split_training_views(train, 0).validation == []


@pytest.mark.parametrize("every, match", [(1, "0 \\(off\\) or >= 2"), (-3, "0 \\(off\\) or >= 2"),
                                          (20, "holds out no view")])
def test_bad_validation_split_is_rejected(every, match):
    with pytest.raises(ValueError, match=match):
        split_training_views(list(range(10)), every)


def test_evenly_spaced_subset():
    assert evenly_spaced([5, 6, 7, 8, 9, 10], 3) == [5, 7, 9]
    assert evenly_spaced([1, 2], 5) == [1, 2]


# ---- contributions ----------------------------------------------------------------------------------------------


def _cameras(width=24, height=18):
    """One view at the origin looking along +z, f = 20 px."""
    return Cameras(torch.eye(4)[None], Intrinsics(20.0, 20.0, width / 2, height / 2, width, height))


def test_contributions_equal_the_one_hot_channel_sums_of_a_plain_render():
    from spotlessgs.rasterizer import rasterize

    g = torch.Generator().manual_seed(3)
    n = 5
    means = torch.cat([torch.rand(n, 2, generator=g) * 0.6 - 0.3, 2.0 + torch.rand(n, 1, generator=g)], 1)
    quats = torch.nn.functional.normalize(torch.randn(n, 4, generator=g), dim=1)
    scales = 0.05 + 0.1 * torch.rand(n, 3, generator=g)
    opacities = torch.tensor([0.9, 0.5, 0.2, 0.05, 0.7])
    cams = _cameras()
    got = gaussian_contributions(means, quats, scales, opacities, cams, [0, 0], backend="torch")
    # reference: channel i of a render with one-hot features is Σ_px α_i T_i; two identical views double it
    K = torch.tensor([[20.0, 0, 12.0], [0, 20.0, 9.0], [0, 0, 1]])
    ref = rasterize(means, quats, scales, opacities, torch.eye(n), torch.eye(4), K, 24, 18, backend="torch")
    expected = 2.0 * ref.image.sum(dim=(0, 1))
    torch.testing.assert_close(got, expected, rtol=1e-4, atol=1e-5)
    assert float(got.min()) > 0.0


def test_negligible_mask_removes_the_smallest_within_the_fraction_and_keeps_the_largest():
    c = torch.tensor([50.0, 0.0, 1.0, 2.0, 47.0])  # total 100
    # 3 % of 100: 0 + 1 + 2 = 3 fits, the next (47) does not
    assert negligible_mask(c, 0.03).tolist() == [False, True, True, True, False]
    assert negligible_mask(c, 0.02).tolist() == [False, True, True, False, False]
    assert negligible_mask(c, 0.0).tolist() == [False, True, False, False, False]  # zero weight never shows
    assert negligible_mask(torch.zeros(3), 0.5).tolist() == [True, False, True] or \
        int(negligible_mask(torch.zeros(3), 0.5).sum()) == 2  # all zero: one is kept


@pytest.mark.parametrize("contrib, fraction, match", [(torch.ones(2, 2), 0.1, "must be \\(N,\\)"),
                                                      (torch.ones(3), 1.0, "in \\[0, 1\\)")])
def test_negligible_mask_rejects_bad_input(contrib, fraction, match):
    with pytest.raises(ValueError, match=match):
        negligible_mask(contrib, fraction)


@pytest.mark.parametrize("kwargs, match", [({"patience": 0}, "patience"), ({"min_gain_db": -1.0}, "min_gain_db"),
                                           ({"prune_fraction": 1.0}, "prune_fraction"),
                                           ({"judge_from": -1}, "judge_from")])
def test_budget_config_rejects_bad_values(kwargs, match):
    with pytest.raises(ValueError, match=match):
        BudgetConfig(**kwargs)


@pytest.mark.parametrize("kwargs, match", [
    ({"gaussian_budget": True}, "needs held-out validation views"),
    ({"validation_every": 1}, "validation_every"),
    ({"budget_patience": 0}, "budget_patience"),
    ({"budget_prune_fraction": -0.1}, "budget_prune_fraction"),
    ({"budget_contribution_views": 0}, "budget_contribution_views"),
])
def test_train_config_rejects_bad_budget_settings(kwargs, match):
    with pytest.raises(ValueError, match=match):
        TrainConfig(**kwargs)


# ---- the strategy -----------------------------------------------------------------------------------------------


def _gaussians(n=8):
    xyz = np.stack([np.linspace(-0.3, 0.3, n), np.zeros(n), np.full(n, 2.0)], 1)
    g = GaussianParams.from_point_cloud(xyz, np.full((n, 3), 128, np.uint8))
    with torch.no_grad():
        g.params["log_scales"].fill_(math.log(0.001))
        g.params["opacity_logits"].fill_(2.0)
    return g


def _optimizers(g):
    return {name: torch.optim.Adam([p], lr=1e-3) for name, p in g.params.items()}


def _drive(strategy, g, opts, steps):
    """Every Gaussian has a large screen gradient at every step (all would be cloned)."""
    log = []
    for step in range(steps):
        n = len(g)
        grad = torch.full((n, 2), 1.0)
        log.append(strategy.step_post_backward(step, g, opts, grad, torch.ones(n, dtype=torch.int32), 32, 32))
    return log


def test_growth_stops_after_patience_checks_without_gain_and_cap_holds():
    cfg = DensifyConfig(densify_from=10, densify_until=100, densify_every=10, grad_threshold=1e-4,
                        opacity_reset_every=0, max_gaussians=200, prune_opacity=0.0)
    psnrs = iter([20.0, 21.0, 21.02, 21.01, 20.9, 25.0, 25.0, 25.0, 25.0])
    seen = []

    def validate(g):
        seen.append(len(g))
        return next(psnrs)

    g = _gaussians()
    strategy = BudgetStrategy(cfg, BudgetConfig(patience=3, min_gain_db=0.05, prune_fraction=0.0), 1.0,
                              torch.Generator().manual_seed(0), validate, lambda gg: torch.ones(len(gg)))
    log = _drive(strategy, g, _optimizers(g), 100)
    # checks at 10, 20, 30, 40, 50: after 50 the last three (21.02, 21.01, 20.9) gained < 0.05 over 21.0 -> stop
    assert strategy.growth_stopped_at == 50
    assert [c["step"] for c in strategy.checks] == [10, 20, 30, 40, 50]
    grown_after = sum(c["cloned"] + c["split"] for c in log[50:])
    assert grown_after == 0 and len(seen) == 5  # no more growth, and no more validation renders
    assert len(g) <= cfg.max_gaussians
    # the default strategy under the same gradients grows to the cap
    g2 = _gaussians()
    _drive(DensifyStrategy(cfg, 1.0, torch.Generator().manual_seed(0)), g2, _optimizers(g2), 100)
    assert len(g2) == cfg.max_gaussians and len(g) < len(g2)
    state = strategy.state_dict()
    again = BudgetStrategy(cfg, strategy.budget, 1.0, torch.Generator(), validate, lambda gg: torch.ones(len(gg)))
    again.load_state_dict(state)
    assert again.growth_stopped_at == 50 and again.checks == strategy.checks


def test_before_judge_from_the_budget_densifies_as_the_default_strategy():
    """A sparse start densifies from step 10, the budget judges from step 30: the steps before 30 are the default
    strategy's exactly (same growth, no validation render, no contribution pruning), and the checks start at 30."""
    cfg = DensifyConfig(densify_from=10, densify_until=100, densify_every=10, grad_threshold=1e-4,
                        opacity_reset_every=0, max_gaussians=200, prune_opacity=0.0)
    validated, weighed = [], []

    def validate(gg):
        validated.append(len(gg))
        return 20.0

    def contributions(gg):
        weighed.append(len(gg))
        return torch.arange(1.0, len(gg) + 1.0)

    g = _gaussians()
    strategy = BudgetStrategy(cfg, BudgetConfig(patience=2, min_gain_db=0.05, prune_fraction=0.2, judge_from=30),
                              1.0, torch.Generator().manual_seed(0), validate, contributions)
    log = _drive(strategy, g, _optimizers(g), 29)
    g2 = _gaussians()
    default_log = _drive(DensifyStrategy(cfg, 1.0, torch.Generator().manual_seed(0)), g2, _optimizers(g2), 29)
    assert log == default_log and len(g) == len(g2) == 32  # 8 -> 16 at step 10 -> 32 at step 20
    torch.testing.assert_close(g.means.detach(), g2.means.detach())
    assert validated == [] and weighed == []
    rest = [strategy.step_post_backward(step, g, _optimizers(g), torch.full((len(g), 2), 1.0),
                                        torch.ones(len(g), dtype=torch.int32), 32, 32) for step in range(29, 60)]
    assert [c["step"] for c in strategy.checks] == [30, 40, 50] and strategy.growth_stopped_at == 50
    assert "pruned_negligible" in rest[0] and validated[0] == 32


def test_no_opacity_reset_after_the_growth_stop():
    """Resets every 20 steps; growth stops at the check of step 40 (three checks without gain after the reset at 20
    restarted the history): the resets at steps 40, 60, 80 and 100 do not happen."""
    cfg = DensifyConfig(densify_from=10, densify_until=100, densify_every=10, grad_threshold=1e-4,
                        opacity_reset_every=20, reset_opacity_value=0.01, max_gaussians=200, prune_opacity=0.005)
    g = _gaussians()
    psnrs = iter([20.0, 21.0, 21.0, 21.0])  # checks at 10, 20 (gain), 30, 40 (the reset at 20 restarted the history)
    strategy = BudgetStrategy(cfg, BudgetConfig(patience=1, min_gain_db=0.05, prune_fraction=0.0), 1.0,
                              torch.Generator().manual_seed(0), lambda gg: next(psnrs), lambda gg: torch.ones(len(gg)))
    log = _drive(strategy, g, _optimizers(g), 100)
    assert strategy.growth_stopped_at == 40
    assert [s + 1 for s, c in enumerate(log) if c["reset"]] == [20]
    # the default strategy under the same schedule keeps resetting
    g2 = _gaussians()
    default_log = _drive(DensifyStrategy(cfg, 1.0, torch.Generator().manual_seed(0)), g2, _optimizers(g2), 100)
    assert [s + 1 for s, c in enumerate(default_log) if c["reset"]] == [20, 40, 60, 80, 100]


def test_after_the_growth_stop_contributions_prune_only_at_the_stop_and_at_densify_until():
    """Growth stops at the check of step 30; contribution pruning ran at every densification step before (10, 20),
    then only at the stop (30) and at densify_until (100), not at 40..90, where pruning would compound."""
    cfg = DensifyConfig(densify_from=10, densify_until=100, densify_every=10, grad_threshold=1e9,  # no growth
                        opacity_reset_every=0, max_gaussians=200, prune_opacity=0.0)
    psnrs = iter([20.0, 20.0, 20.0])
    asked = []

    def contributions(gg):
        asked.append(len(gg))
        return torch.arange(1.0, len(gg) + 1.0)

    g = _gaussians()
    strategy = BudgetStrategy(cfg, BudgetConfig(patience=2, min_gain_db=0.05, prune_fraction=0.2), 1.0,
                              torch.Generator().manual_seed(0), lambda gg: next(psnrs), contributions)
    log = _drive(strategy, g, _optimizers(g), 100)
    assert strategy.growth_stopped_at == 30
    assert [s + 1 for s, c in enumerate(log) if "pruned_negligible" in c] == [10, 20, 30, 100]
    # weights 1..n; each pruning removes the smallest within 20 % of the total: 8 -> 5 (1+2+3 <= 7.2) -> 3 -> 2 -> 2
    assert [c["pruned_negligible"] for c in log if "pruned_negligible" in c] == [3, 2, 1, 0] and len(g) == 2
    assert asked == [8, 5, 3, 2]


def test_negligible_gaussians_are_pruned_with_their_optimizer_state():
    cfg = DensifyConfig(densify_from=10, densify_until=20, densify_every=10, grad_threshold=1e9,  # no growth
                        opacity_reset_every=0, max_gaussians=100, prune_opacity=0.0)
    weights = torch.tensor([100.0, 0.2, 30.0, 0.3, 40.0, 0.1, 25.0, 0.0])  # total 195.6

    def contributions(g):
        return weights[: len(g)] if len(g) == len(weights) else torch.ones(len(g))

    g = _gaussians()
    keep_means = g.means.detach()[[0, 2, 4, 6]].clone()
    opts = _optimizers(g)
    strategy = BudgetStrategy(cfg, BudgetConfig(patience=5, prune_fraction=0.01), 1.0, torch.Generator(),
                              lambda gg: 20.0, contributions)
    log = _drive(strategy, g, opts, 10)
    assert log[9]["pruned_negligible"] == 4  # 0 + 0.1 + 0.2 + 0.3 = 0.6 ≤ 1.956; adding 25 would not fit
    torch.testing.assert_close(g.means.detach(), keep_means)
    for name, p in g.params.items():
        assert opts[name].param_groups[0]["params"][0] is p and opts[name].state.get(p) is None or \
            opts[name].state[p]["exp_avg"].shape[0] == 4


def test_at_densify_until_nothing_grows_and_the_last_pruning_precedes_the_opacity_reset():
    """A run whose validation keeps improving never stops growth; at densify_until (also a reset step) the budget
    adds nothing and prunes on the pre-reset weights, where the default strategy densifies once more."""
    cfg = DensifyConfig(densify_from=10, densify_until=40, densify_every=10, grad_threshold=1e-4,
                        opacity_reset_every=40, max_gaussians=1000, prune_opacity=0.0)
    psnrs = iter(range(20, 40))
    opacities_seen = []

    def contributions(g):  # the last pruning must see the opacities before the reset lowers them
        opacities_seen.append(float(g.opacities.detach().min()))
        return torch.arange(len(g), dtype=torch.float32)

    g = _gaussians()
    strategy = BudgetStrategy(cfg, BudgetConfig(patience=3, prune_fraction=0.001), 1.0,
                              torch.Generator().manual_seed(0), lambda gg: float(next(psnrs)), contributions)
    log = _drive(strategy, g, _optimizers(g), 40)
    assert strategy.growth_stopped_at is None and sum(c["cloned"] + c["split"] for c in log[:39]) > 0
    last = log[39]
    assert last["cloned"] == last["split"] == 0 and last["reset"] == 1 and last["pruned_negligible"] >= 1
    assert opacities_seen[-1] > 0.5  # sigmoid(2.0) = 0.88 before the reset, not the reset value
    g2 = _gaussians()
    default_log = _drive(DensifyStrategy(cfg, 1.0, torch.Generator().manual_seed(0)), g2, _optimizers(g2), 40)
    assert default_log[39]["cloned"] + default_log[39]["split"] > 0


# ---- end to end on a synthetic dataset ---------------------------------------------------------------------------


@pytest.fixture(scope="module")
def box_room(tmp_path_factory):
    return synthetic_box_dataset(tmp_path_factory, "budget-data", seed=2)


def _tiny(**overrides):
    base = dict(iterations=90, image_width=40, num_threads=1, densify_from=20, densify_until=80, densify_every=10,
                opacity_reset_every=0, log_every=10, checkpoint_every=45, init_points=600, max_gaussians=900,
                brdf_hidden=8)
    base.update(overrides)
    return preset("tiny", **base)


def test_budget_run_writes_its_decisions_respects_the_cap_and_resumes_exactly(box_room, tmp_path):
    from spotlessgs.training.checkpoint import load_checkpoint
    from spotlessgs.training.trainer import train

    cfg = _tiny(gaussian_budget=True, validation_every=4, validation_rejoin=True, max_gaussians=700,
                budget_patience=2)
    full = train(box_room, tmp_path / "full", "darkgs+sh", cfg, seed=1, progress=False)
    assert full.num_gaussians <= 700
    report = json.loads((tmp_path / "full" / "gaussian_budget.json").read_text())
    assert report["final_gaussians"] == full.num_gaussians and report["max_gaussians"] == 700
    assert [c["step"] for c in report["checks"]][:1] == [20] and all(math.isfinite(c["validation_psnr"])
                                                                     for c in report["checks"])
    summary = json.loads((tmp_path / "full" / "train_summary.json").read_text())
    assert summary["validation_views"] == [4, 8, 13] and summary["validation_psnr"] is None  # 14 frames: test 0, 11; rejoined: not held out
    # interrupted and resumed: identical parameters (the budget state is in the checkpoint)
    train(box_room, tmp_path / "split", "darkgs+sh", cfg, seed=1, progress=False, stop_after=45)
    train(box_room, tmp_path / "split", "darkgs+sh", cfg, seed=1, progress=False, resume=True)
    a, b = load_checkpoint(tmp_path / "full"), load_checkpoint(tmp_path / "split")
    for name in a["gaussians"]:
        torch.testing.assert_close(a["gaussians"][name], b["gaussians"][name])


def test_cli_gaussian_budget_flag_holds_out_views_and_respects_max_gaussians(box_room, tmp_path):
    from click.testing import CliRunner

    from spotlessgs.cli import main

    out = tmp_path / "run"
    res = CliRunner().invoke(main, ["train", "--data", str(box_room), "--out", str(out), "--model", "darkgs",
                                    "--preset", "tiny", "--iterations", "60", "--width", "32", "--threads", "1",
                                    "--max-gaussians", "350", "--gaussian-budget", "-q"])
    assert res.exit_code == 0, res.output
    train_cfg = json.loads((out / "config.json").read_text())["train"]
    assert train_cfg["gaussian_budget"] and train_cfg["validation_every"] == 8 and train_cfg["validation_rejoin"]
    assert json.loads((out / "train_summary.json").read_text())["num_gaussians"] <= 350
    assert (out / "gaussian_budget.json").is_file()


def test_budget_plot_draws_every_point_and_rejects_bad_input(tmp_path):
    from PIL import Image

    from spotlessgs.training.budget_plot import BudgetPoint, plot_budget

    points = [BudgetPoint("bedroom", "default", 20000, 18.0, 3.0), BudgetPoint("bedroom", "budget", 9000, 17.9, 6.0),
              BudgetPoint("storage_room", "default", 20000, 15.0, 2.5),
              BudgetPoint("storage_room", "budget", 12000, 14.9, 4.0)]
    path = plot_budget(points, tmp_path / "budget.png")
    with Image.open(path) as img:
        assert img.format == "PNG" and img.size[0] > 500
    assert [p.name for p in tmp_path.iterdir()] == ["budget.png"]  # atomic: no temporary file left
    with pytest.raises(ValueError, match="no points"):
        plot_budget([], tmp_path / "x.png")
    with pytest.raises(ValueError, match="gaussians must be >= 1"):
        BudgetPoint("r", "s", 0, 1.0, 1.0)
    with pytest.raises(ValueError, match="relit_fps is not finite"):
        BudgetPoint("r", "s", 5, 1.0, math.inf)
    with pytest.raises(ValueError, match="must be finite and contain relit_psnr"):
        BudgetPoint("r", "s", 5, 18.0, 1.0, psnr_range=(18.1, 18.4))  # the mean lies outside its runs' range
    ranged = [BudgetPoint("r", "default", 20000, 18.2, 3.0, psnr_range=(18.0, 18.4)),
              BudgetPoint("r", "budget", 9000, 18.0, 5.0, psnr_range=(17.9, 18.05))]
    assert plot_budget(ranged, tmp_path / "ranged.png").is_file()
