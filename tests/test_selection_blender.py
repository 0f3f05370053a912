"""Model selection on the Blender-rendered bedroom with and without bounce light (the spotlight is its only light).

Without bounce light the low-frequency light has nothing to model (what the spotlight misses is black), so the lowest
SH degree (0) must win; with bounce light the highest (3) must, although on these tiny images the proxies' light is
busy either way (its share of the rendered radiance is ~20% in both), which is why the images' dark level decides
too. The decision lists every candidate."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
import torch

ROOT = Path(__file__).resolve().parents[1]


def _render_bedroom(tmp_path_factory, max_bounces: int) -> Path:
    pytest.importorskip("bpy")
    from simulator.render_pipeline import ExecutionOptions, RenderConfig, render_dataset

    out = tmp_path_factory.mktemp("selection-blender") / f"bedroom-b{max_bounces}"
    config = RenderConfig.from_preset("uneven", frames=12, width=64, height=48, samples=6, seed=1,
                                      max_bounces=max_bounces)
    render_dataset(ROOT / "scenes" / "bedroom" / "house.json", out, config, execution=ExecutionOptions(progress=False))
    return out


@pytest.mark.blender
@pytest.mark.slow
@pytest.mark.parametrize("max_bounces, degree", [(0, 0), (4, 3)])
def test_sh_degree_follows_the_bounce_light(tmp_path_factory, tmp_path, max_bounces, degree):
    from spotlessgs.training.config import preset
    from spotlessgs.training.selection import SELECTION_FILE, SelectionConfig, select_model

    data = _render_bedroom(tmp_path_factory, max_bounces)
    old = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        decision = select_model(data, tmp_path / "run", preset("tiny", iterations=1000, num_threads=1), 0,
                                SelectionConfig())
    finally:
        torch.set_num_threads(old)
    assert decision == json.loads((tmp_path / "run" / SELECTION_FILE).read_text())
    light = [c for c in decision["candidates"] if c["phase"] == "light"]
    assert [c["sh_degree"] for c in light] == [0, 3]
    assert len(decision["candidates"]) == 4 and all(math.isfinite(c["validation_psnr"])
                                                    for c in decision["candidates"])
    need = decision["low_frequency_light"]
    if max_bounces == 0:  # nothing for a low-frequency light to light: what the spotlight misses is black
        assert need["dark_level"] < SelectionConfig().min_dark_level and not need["needed"]
    else:
        assert need["dark_level"] > 2 * SelectionConfig().min_dark_level and need["needed"]
    assert decision["chosen_model"]["sh_degree"] == degree
