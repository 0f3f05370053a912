"""The reproduction's component rooms: the residual-light variant, extra test datasets, extra training seeds, the
seed table and its targets (``spotless reproduce --preset components``)."""

from __future__ import annotations

import json

import pytest

from spotlessgs.experiments.reproduce import tasks
from spotlessgs.experiments.reproduce.config import NEUTRAL_NEW_FIELDS, ReproduceConfig, preset, train_stage
from spotlessgs.experiments.reproduce.pipeline import build_graph, check_or_record_config
from spotlessgs.experiments.reproduce.report import collect
from spotlessgs.experiments.reproduce.tables import (
    all_tables, seed_agreement, seed_gains, seed_spread, seed_table,
)
from spotlessgs.io.atomic import write_json
from spotlessgs.jobs.graph import write_marker


def test_components_preset_datasets_seeds_and_stages(tmp_path):
    config = preset("components")
    assert config.datasets() == [("storage_room", "uneven"), ("white_room", "uneven"), ("bedroom", "residual")]
    assert config.seeds() == (0, 1, 2)
    graph = build_graph(config, tmp_path)
    # 3 renders, 4 methods x 3 seeds x 3 datasets, one inputs' evaluation and one ceiling per dataset, the report
    assert len(graph.stages) == 3 + 36 + 3 + 3 + 1
    residual = graph["render/bedroom-residual"].kwargs
    assert (residual["variant"], residual["residual_light"], residual["uniform_gt"]) == ("residual", 0.1, True)
    assert graph["render/storage_room-uneven"].kwargs["residual_light"] == 0.0
    extra = graph["train/white_room-uneven/seed-2/darkgs+brdf"]
    assert extra.kwargs["seed"] == 2 and extra.kwargs["variant"] == "darkgs+brdf"
    assert extra.output == tmp_path / "runs" / "white_room-uneven" / "seed-2" / "darkgs+brdf"
    assert extra.deps == ("render/white_room-uneven",) and not extra.clean_on_retry
    first = graph["train/white_room-uneven/darkgs+brdf"]
    assert first.kwargs["seed"] == 0 and first.output == tmp_path / "runs" / "white_room-uneven" / "darkgs+brdf"
    assert {k: v for k, v in first.kwargs.items() if k not in ("seed", "run_dir")} == {
        k: v for k, v in extra.kwargs.items() if k not in ("seed", "run_dir")}
    assert train_stage("white_room-uneven", "darkgs", 2, config) == "train/white_room-uneven/seed-2/darkgs"


def test_extra_seeds_train_the_rendered_datasets_only(tmp_path):
    """The noisy and robot copies keep one run per method; the rendered datasets get one per seed."""
    tiny = preset("tiny", extra_seeds=(7,))
    names = set(build_graph(tiny, tmp_path).stages)
    assert len(names) == len(build_graph(preset("tiny"), tmp_path).stages) + 2 * 7
    assert "train/bedroom-saturated/seed-7/auto" in names
    assert not any(n.startswith(("train/bedroom-robot/seed-", "train/bedroom-uneven-noisy/seed-")) for n in names)


def test_component_config_errors():
    with pytest.raises(ValueError, match="extra_datasets: 'kitchen-uneven' is not ROOM-VARIANT"):
        ReproduceConfig(extra_datasets=("kitchen-uneven",))
    with pytest.raises(ValueError, match="extra_datasets: 'bedroom-noisy' is not ROOM-VARIANT"):
        ReproduceConfig(extra_datasets=("bedroom-noisy",))
    with pytest.raises(ValueError, match="extra_datasets repeats a test dataset"):
        ReproduceConfig(extra_datasets=("bedroom-uneven",))
    with pytest.raises(ValueError, match="residual_light must lie in"):
        ReproduceConfig(residual_light=0.0)
    with pytest.raises(ValueError, match="extra_seeds must differ"):
        ReproduceConfig(extra_seeds=(0,))
    with pytest.raises(ValueError, match="extra_seeds must differ"):
        ReproduceConfig(extra_seeds=(1, 1))
    assert ReproduceConfig(extra_datasets=("white_room-residual",)).datasets()[-1] == ("white_room", "residual")


def test_folder_from_before_the_new_fields_resumes(tmp_path):
    """A reproduce.json written before extra_datasets, residual_light and extra_seeds existed is the same settings
    with their defaults; any other value of them is still refused."""
    recorded = {k: v for k, v in json.loads(json.dumps(preset("tiny").to_dict())).items()
                if k not in NEUTRAL_NEW_FIELDS}
    write_json(tmp_path / "reproduce.json", recorded)
    check_or_record_config(preset("tiny"), tmp_path)
    with pytest.raises(ValueError, match=r"\(extra_seeds: not recorded then, \[1\] now\)"):
        check_or_record_config(preset("tiny", extra_seeds=(1,)), tmp_path)
    with pytest.raises(ValueError, match=r"\(seed: 0 then, 2 now\)"):
        check_or_record_config(preset("tiny", seed=2), tmp_path)


def test_render_room_asks_for_the_residual_light(tmp_path, monkeypatch):
    """A residual dataset is the uneven spotlight with the lamps on at the given power; other variants have none."""
    seen = []
    monkeypatch.setattr(tasks, "render_dataset", lambda scene, out, config, execution: seen.append(config) or {
        "complete": True})
    common = dict(scene_file="house.json", out_dir=str(tmp_path), frames=4, width=16, height=12, samples=1, seed=0,
                  threads=1)
    tasks.render_room(variant="residual", residual_light=0.25, **common)
    tasks.render_room(variant="saturated", residual_light=0.25, **common)
    assert (seen[0].preset, seen[0].residual_light) == ("uneven", 0.25)
    assert (seen[1].preset, seen[1].residual_light) == ("saturated", 0.0)


def _run(seed: float, lamps: float, uniform: float, ms: float = 50.0) -> dict:
    return {"seed": seed, "metrics": {"psnr_aligned": lamps, "uniform": {"psnr_aligned": uniform}},
            "train": {"ms_per_step": ms}}


def _seeded() -> dict:
    """Hand-made seed results: on the residual room SpotlessGS gains +1.5/+0.5/+1.3 dB (lamps-on, mean 1.1) and
    +0.2/+0.3/+0.4 dB (uniform, mean 0.3) over DarkGS seed by seed; on the storage room the MLP BRDF +0.5/+0.7/+0.6
    (lamps-on, mean 0.6) and a missing uniform score."""
    residual = {"darkgs": [_run(0, 20.0, 22.0), _run(1, 20.5, 22.5), _run(2, 19.5, 22.0)],
                "spotless": [_run(0, 21.5, 22.2, 80.0), _run(1, 21.0, 22.8, 90.0), _run(2, 20.8, 22.4, 70.0)]}
    storage = {"darkgs": [_run(0, 18.0, 20.0), _run(1, 18.0, 20.0), _run(2, 18.0, 20.0)],
               "darkgs+brdf": [_run(0, 18.5, 20.5), _run(1, 18.7, None), _run(2, 18.6, 20.6)]}
    return {"datasets": {"bedroom-residual": {"room": "bedroom", "variant": "residual", "seeds": residual},
                         "storage_room-uneven": {"room": "storage_room", "variant": "uneven", "seeds": storage}}}


def test_seed_spread_and_gains():
    assert seed_spread([1.0, 3.0, 2.0]) == (2.0, 1.0, 3.0)
    assert seed_spread([1.0, None]) is None and seed_spread([]) is None
    residual = _seeded()["datasets"]["bedroom-residual"]
    mean, low, high = seed_gains(residual, "spotless", ("psnr_aligned",))
    assert (mean, low, high) == pytest.approx((1.1, 0.5, 1.5))
    assert seed_gains(residual, "spotless", ("uniform", "psnr_aligned")) == pytest.approx((0.3, 0.2, 0.4))
    assert seed_gains(residual, "darkgs+brdf", ("psnr_aligned",)) is None  # not trained there


def test_seed_table_and_targets():
    table = seed_table(_seeded())
    rows = {(r[0], r[1]): r for r in table.rows}
    spotless = rows[("bedroom-residual", "SpotlessGS (ours)")]
    assert spotless[2:] == ["0, 1, 2", "21.10 [20.80, 21.50]", "22.47 [22.20, 22.80]", "+1.10 [+0.50, +1.50]",
                            "+0.30 [+0.20, +0.40]", pytest.approx(80.0)]
    assert rows[("bedroom-residual", "DarkGS")][5:7] == [None, None]  # no gain over itself
    assert rows[("storage_room-uneven", "DarkGS + MLP BRDF")][4] is None  # a seed without a uniform score
    notes = {n.claim: n for n in seed_agreement(_seeded())}
    assert notes["SpotlessGS (ours) ≥ DarkGS + 1.0 dB on bedroom-residual (lamps-on GT, mean over seeds)"].status \
        == "agrees"
    uniform = notes["SpotlessGS (ours) ≥ DarkGS + 1.0 dB on bedroom-residual (uniform GT, mean over seeds)"]
    assert uniform.status == "disagrees" and "+0.30 [+0.20, +0.40] dB over 3 seeds" in uniform.text
    brdf = "DarkGS + MLP BRDF ≥ DarkGS + 0.5 dB on storage_room-uneven"
    assert notes[f"{brdf} (lamps-on GT, mean over seeds)"].status == "agrees"
    assert notes[f"{brdf} (uniform GT, mean over seeds)"].status == "unknown"
    assert len(notes) == 4  # no BRDF target on the residual room, no SpotlessGS one on the storage room


def test_collect_reads_every_seed(tmp_path):
    config = preset("components", methods=("darkgs", "spotless"), extra_datasets=(), scenes=("storage_room",),
                    extra_seeds=(3,))
    check_or_record_config(config, tmp_path)
    ds = "storage_room-uneven"
    write_marker(tmp_path, f"eval-inputs/{ds}", {"result": {"metrics": {"psnr_aligned": 10.0}}, "seconds": 1.0,
                                                  "peak_rss_mb": 1.0})
    write_marker(tmp_path, f"ceiling/{ds}", {"result": {"skipped": "no albedo pass"}, "seconds": 1.0,
                                             "peak_rss_mb": 1.0})
    for seed, offset in ((0, 0.0), (3, 1.0)):
        for method, psnr in (("darkgs", 18.0), ("spotless", 19.0)):
            result = {"metrics": {"psnr_aligned": psnr + offset, "uniform": {"psnr_aligned": psnr + 2 + offset}},
                      "train": {"ms_per_step": 40.0}, "relight": {}, "curve": []}
            write_marker(tmp_path, train_stage(ds, method, seed, config), {"result": result, "seconds": 1.0,
                                                                            "peak_rss_mb": 1.0})
            run = tmp_path / "runs" / ds / (method if seed == 0 else f"seed-{seed}/{method}")
            write_json(run / "run.json", {"model": method})
    collected = collect(tmp_path, config)
    seeds = collected["datasets"][ds]["seeds"]
    assert [r["seed"] for r in seeds["spotless"]] == [0, 3]
    assert [r["metrics"]["psnr_aligned"] for r in seeds["spotless"]] == [19.0, 20.0]
    assert collected["datasets"][ds]["methods"]["spotless"]["metrics"]["psnr_aligned"] == 19.0  # the command seed
    assert "seeds" in [t.key for t in all_tables(collected)]


@pytest.mark.slow
def test_components_reproduction_end_to_end(tmp_path):
    """The components preset at the tiny size (two rooms, two methods, two seeds): a residual-light dataset whose
    renderer record says so, both ground truths, the seed table and its targets in the report (about 3 min on 2
    cores)."""
    from spotlessgs.experiments.reproduce.pipeline import reproduce
    from spotlessgs.jobs import ExecutorSpec

    config = preset("components", scenes=("white_room",), frames=12, width=96, height=72, samples=4,
                    train_preset="tiny", train_iterations=150, train_width=64, curve_fractions=(0.5,),
                    extra_seeds=(1,), methods=("darkgs", "spotless"))
    reproduce(config, tmp_path, executor=ExecutorSpec(jobs=2, threads=1))
    assert meta_of(tmp_path / "datasets" / "bedroom-residual")["renderer"]["residual_light"] == pytest.approx(0.1)
    assert "residual_light" not in meta_of(tmp_path / "datasets" / "white_room-uneven")["renderer"]
    results = json.loads((tmp_path / "results.json").read_text())
    seeds = results["tables"]["seeds"]
    assert [row[:3] for row in seeds["rows"]] == [
        ["white_room-uneven", "DarkGS", "0, 1"], ["white_room-uneven", "SpotlessGS (ours)", "0, 1"],
        ["bedroom-residual", "DarkGS", "0, 1"], ["bedroom-residual", "SpotlessGS (ours)", "0, 1"]]
    assert all(cell is not None for row in seeds["rows"] if row[1] != "DarkGS" for cell in row)
    report = (tmp_path / "REPORT.md").read_text()
    assert "SpotlessGS (ours) ≥ DarkGS + 1.0 dB on bedroom-residual (uniform GT, mean over seeds)" in report
    assert (tmp_path / "figures" / "qualitative_bedroom-residual.png").is_file()


def meta_of(dataset) -> dict:
    """The simulator's record in a dataset's transforms.json."""
    return json.loads((dataset / "transforms.json").read_text())["spotless"]
