"""The `paper` preset's code path (L-shaped living room, the trainer's and the Cycle-GAN's paper presets at native
resolution, SfM) on the CPU at a reduced size: fewer frames, smaller images, a handful of steps.

The paper preset itself needs a GPU (316 frames at 640x480, 30k steps); this checks that every one of its stages runs
and reports, so a GPU user does not find a configuration error hours in. Marked slow (about 10-12 minutes on 2
cores, past the suite's 600 s per-test timeout, so it has its own):
``python3 -m pytest -q -m slow tests/test_reproduce_paper.py``.
"""

from __future__ import annotations

import json
import math

import pytest

from spotlessgs.experiments.reproduce.config import preset
from spotlessgs.experiments.reproduce.pipeline import reproduce

pytestmark = [pytest.mark.blender, pytest.mark.slow]


@pytest.mark.timeout(1800)
def test_paper_preset_runs_every_stage_at_a_reduced_size(tmp_path):
    # 256x256 at least: the paper Cycle-GAN trains on 256x256 crops
    config = preset("paper", frames=12, width=256, height=256, samples=2, train_iterations=40,
                    gan_frames=4, gan_width=256, gan_height=256, gan_samples=2, cyclegan_steps=2,
                    selection_min_proxy_iterations=10)
    out = tmp_path / "paper"
    report = reproduce(config, out, jobs=2)
    assert report.ran and not report.skipped and not report.failed and not report.blocked
    results = json.loads((out / "results.json").read_text())
    assert results["preset"] == "paper" and results["cyclegan"]["steps"] == 2
    # the paper trainer preset at the dataset's native resolution, its schedule scaled to the 40 steps
    for variant in ("uneven", "saturated"):
        run_config = json.loads((out / "runs" / f"living_room-{variant}" / "spotless" / "config.json").read_text())
        train = run_config["train"]
        assert (train["preset"], train["image_width"], train["iterations"]) == ("paper", None, 40)
        assert train["max_gaussians"] == 1_000_000 and train["densify_until"] < 40
    rows = [r for r in results["tables"]["table1"]["rows"] if str(r[0]).startswith("living_room")]
    methods = {r[1] for r in rows}
    assert {"Input (spotlight-lit)", "3DGS", "SpotlessGS (ours)"} <= methods and len(rows) >= 8
    aligned = results["tables"]["table1"]["columns"].index("PSNR (aligned)")
    assert all(math.isfinite(r[aligned]) for r in rows)
    text = (out / "REPORT.md").read_text()
    assert "Preset `paper`: rooms living_room" in text and "| living_room-uneven | Cycle-GAN" in text
    # the sensor-noise copy for Table III: SpotlessGS trained on it, SfM rows
    assert set(results["datasets"]["living_room-uneven-noisy"]["methods"]) == {"spotless"}
    assert "| living_room-uneven-noisy | Original (spotlight-lit) |" in text
