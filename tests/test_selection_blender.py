"""Model selection on a Blender-rendered room without any ambient or bounce light: the low-frequency light has
nothing to model, so the cheapest SH degree (0) must win, and the decision lists every candidate."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
import torch

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def dark_bedroom(tmp_path_factory):
    pytest.importorskip("bpy")
    from simulator.render_pipeline import ExecutionOptions, RenderConfig, render_dataset

    out = tmp_path_factory.mktemp("selection-blender") / "bedroom-b0"
    config = RenderConfig.from_preset("uneven", frames=12, width=64, height=48, samples=6, seed=1, max_bounces=0)
    render_dataset(ROOT / "scenes" / "bedroom" / "house.json", out, config, execution=ExecutionOptions(progress=False))
    return out


@pytest.mark.blender
@pytest.mark.slow
def test_no_ambient_room_gets_sh_degree_0(dark_bedroom, tmp_path):
    from spotlessgs.training.config import preset
    from spotlessgs.training.selection import SELECTION_FILE, SelectionConfig, select_model

    old = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        decision = select_model(dark_bedroom, tmp_path / "run", preset("tiny", iterations=1000, num_threads=1), 0,
                                SelectionConfig())
    finally:
        torch.set_num_threads(old)
    assert decision == json.loads((tmp_path / "run" / SELECTION_FILE).read_text())
    light = [c for c in decision["candidates"] if c["phase"] == "light"]
    assert [c["sh_degree"] for c in light] == [0, 1, 2, 3]
    assert len(decision["candidates"]) == 6 and all(math.isfinite(c["validation_psnr"])
                                                    for c in decision["candidates"])
    assert decision["chosen_model"]["sh_degree"] == 0
