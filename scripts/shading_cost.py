"""Where a SpotlessGS run's shading time goes: forward + backward of `shade` over all its Gaussians, one thread.

    python3 scripts/shading_cost.py RUN [--views 8] [--repeats 6]

Loads the finished run RUN (a SpotlessGS model: an SH light and the learned BRDF) and times, per training view, one
spotlit `shading.shade` of every Gaussian and the backward pass of its sum (its normals held if the run held them),
with the run's own modules and with parts taken away (:func:`variants`): the learned BRDF's network without its
gradient to the directions it reads (``brdf_network_input_gradients=false``), the Disney factor without the network,
a Lambertian BRDF with the SH light, and a Lambertian BRDF with DarkGS's constant ambient. Prints a Markdown table
of the median ms per view over ``--repeats`` passes through the first ``--views`` training views. The rasteriser, the loss and the optimiser are not
in it, and training shades only the Gaussians that can touch the view: scripts/step_cost_ab.py measures whole steps.
docs/results.md ("The learned BRDF's network without its gradient to the directions") quotes it.
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import time
from pathlib import Path

import torch

from spotlessgs.models.brdf import LambertianBRDF, LearnedBRDF
from spotlessgs.models.light import ConstantAmbient
from spotlessgs.models.shading import ModelConfig, shade
from spotlessgs.training.trainer import load_run


class DisneyOnlyBRDF(LearnedBRDF):
    """The learned BRDF with its network left out: the modulation is 1 (the zero-initialised network's value)."""

    def modulation(self, normals: torch.Tensor, view_dirs: torch.Tensor, light_dirs: torch.Tensor) -> torch.Tensor:
        return torch.ones_like(normals[:, :1])


def variants(config: ModelConfig, brdf: LearnedBRDF, lf_light, bounce_light) -> list[tuple]:
    """(name, model config, BRDF, low-frequency light, bounce light) of the run's shading (``config``, ``brdf``,
    ``lf_light``, ``bounce_light``) and of the same with parts taken away, in the order of the printed table (DarkGS's
    constant ambient has no bounce light)."""
    if not isinstance(brdf, LearnedBRDF) or config.ambient != "sh":
        raise ValueError(f"shading_cost needs a SpotlessGS run (an SH light and the learned BRDF), not {config.name!r}")
    detached = LearnedBRDF(hidden=config.brdf_hidden, upper_clamp=brdf.upper_clamp, burley=brdf.burley,
                           input_gradients=False)
    detached.load_state_dict(brdf.state_dict())
    disney = DisneyOnlyBRDF(hidden=config.brdf_hidden, upper_clamp=brdf.upper_clamp, burley=brdf.burley)
    lambert = dataclasses.replace(config, brdf="lambert")
    darkgs = dataclasses.replace(config, brdf="lambert", ambient="constant", low_frequency_shading="spot_cosine")
    return [("the run's shading (SH light, learned BRDF)", config, brdf, lf_light, bounce_light),
            ("network without its gradient to the directions", config, detached, lf_light, bounce_light),
            ("Disney factor alone (no network)", config, disney, lf_light, bounce_light),
            ("Lambertian BRDF, SH light", lambert, LambertianBRDF(), lf_light, bounce_light),
            ("Lambertian BRDF, constant ambient (DarkGS)", darkgs, LambertianBRDF(), ConstantAmbient(0.05), None)]


def shading_cost(run_dir: str | Path, views: int = 8, repeats: int = 6) -> tuple[int, list[tuple[str, float]]]:
    """(number of Gaussians, [(variant name, median ms per view)]) for the run ``run_dir`` (module docstring)."""
    scene, train_views, run_config, _ = load_run(run_dir, device="cpu")
    app, gaussians = scene.appearance, scene.gaussians
    gaussians.params["normals_raw"].requires_grad_(run_config.lr_normals != 0)  # held as the run trained them
    c2ws = [train_views.cameras.c2w[k] for k in train_views.train[:views]]
    rows = []
    for name, config, brdf, lf_light, bounce_light in variants(scene.config, app.brdf, app.lf_light,
                                                                app.bounce_light):
        def one_pass() -> None:
            for c2w in c2ws:
                shade(config, gaussians, app.light, lf_light, brdf, c2w, bounce_light=bounce_light,
                      with_spot_part=True).sum().backward()
        one_pass()  # warm-up
        times = []
        for _ in range(repeats):
            start = time.perf_counter()
            one_pass()
            times.append(1000.0 * (time.perf_counter() - start) / len(c2ws))
        rows.append((name, statistics.median(times)))
    return len(gaussians), rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=Path)
    parser.add_argument("--views", type=int, default=8)
    parser.add_argument("--repeats", type=int, default=6)
    args = parser.parse_args()
    torch.set_num_threads(1)
    count, rows = shading_cost(args.run, args.views, args.repeats)
    print(f"{count:,} Gaussians; ms per view, forward + backward, median of {args.repeats} passes x {args.views} views")
    print("| shading | ms per view |\n|---|---|")
    for name, ms in rows:
        print(f"| {name} | {ms:.1f} |")


if __name__ == "__main__":
    main()
