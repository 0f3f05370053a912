"""Where a SpotlessGS run's shading time goes: forward + backward of `shade` over all its Gaussians, one thread.

    python3 scripts/shading_cost.py RUN [--views 8] [--repeats 6] [--parts [--compile]]

Loads the finished run RUN (a SpotlessGS model: an SH light and the learned BRDF) and times, per training view, one
spotlit `shading.shade` of every Gaussian and the backward pass of its sum (its normals held if the run held them),
with the run's own modules and with parts taken away (:func:`variants`): the learned BRDF's network without its
gradient to the directions it reads (``brdf_network_input_gradients=false``), the Disney factor without the network,
a Lambertian BRDF with the SH light, and a Lambertian BRDF with DarkGS's constant ambient. Prints a Markdown table
of the median ms per view over ``--repeats`` passes through the first ``--views`` training views. The rasteriser, the loss and the optimiser are not
in it, and training shades only the Gaussians that can touch the view: scripts/step_cost_ab.py measures whole steps.
docs/results.md ("The learned BRDF's network without its gradient to the directions") quotes it.

``--parts`` prints a second table, the learned BRDF's own parts on the first training view's inputs
(:func:`brdf_parts`): the analytic Disney factor (with ``--compile`` also under ``torch.compile``, its first call
timed apart), the network with and without its gradient to the directions, the sinusoidal encoding, the network's
first-layer input-gradient product and the whole BRDF. docs/results.md ("Where a SpotlessGS step's time goes")
quotes it.
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import time
from pathlib import Path

import torch

from spotlessgs.io.seeding import torch_generator
from spotlessgs.models.brdf import LambertianBRDF, LearnedBRDF, disney_brdf
from spotlessgs.models.light import ConstantAmbient
from spotlessgs.models.nets import sinusoidal_encoding
from spotlessgs.models.shading import ModelConfig, shade, shading_normals, view_directions
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


def brdf_inputs(scene, c2w: torch.Tensor) -> tuple[list[torch.Tensor], torch.Tensor]:
    """The learned BRDF's inputs as `shade` computes them for the camera ``c2w`` (4, 4), detached: [albedo (N, 3),
    roughness (N, 1), metalness (N, 1), normals, view directions, light directions (N, 3)], and the spotlight's
    radiance (N, 1)."""
    gaussians, light = scene.gaussians, scene.appearance.light
    center = c2w[:3, 3]
    with torch.no_grad():
        view_dirs = view_directions(gaussians.means, center)
        normals = shading_normals(scene.config, gaussians, view_dirs, center)
        spot, light_dirs = light.incident(gaussians.means, c2w)
        inputs = [gaussians.albedo, gaussians.roughness, gaussians.metalness, normals, view_dirs, light_dirs]
    return [x.detach().clone() for x in inputs], spot.detach()


def _median_ms(fn, repeats: int) -> float:
    fn()  # warm-up
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(1000.0 * (time.perf_counter() - start))
    return statistics.median(times)


def brdf_parts(run_dir: str | Path, repeats: int = 20, compile_disney: bool = False) -> tuple[int, list[tuple[str, float]]]:
    """(number of Gaussians, [(part, median ms of its forward + backward)]) of the learned BRDF of the run ``run_dir``
    on the first training view's inputs (:func:`brdf_inputs`), over ``repeats`` passes after one warm-up (module
    docstring). The encoding and the first layer's product are fed a fixed random gradient of their output's shape."""
    scene, views, _, _ = load_run(run_dir, device="cpu")
    brdf = scene.appearance.brdf
    if not isinstance(brdf, LearnedBRDF):
        raise ValueError(f"shading_cost --parts needs a run with the learned BRDF, not {scene.config.name!r}")
    inputs, _ = brdf_inputs(scene, views.cameras.c2w[views.train[0]])
    detached = LearnedBRDF(hidden=scene.config.brdf_hidden, upper_clamp=brdf.upper_clamp, burley=brdf.burley,
                           input_gradients=False)
    detached.load_state_dict(brdf.state_dict())

    def forward_backward(fn):
        def run() -> None:
            leaves = [x.clone().requires_grad_(True) for x in inputs]
            fn(*leaves).sum().backward()
        return run

    def disney(a, r, m, n, v, l):
        return disney_brdf(a, r, m, n, v, l, brdf.burley)

    gen = torch_generator(0, "shading-cost-parts")
    normals, view_dirs, light_dirs = inputs[3:]
    directions = torch.cat([view_dirs, light_dirs, normals], dim=1)  # as the network reads them
    encoding_grad = torch.randn(len(directions), brdf.input_size, generator=gen)
    first_layer = brdf.mlp[0].weight.detach()
    hidden_grad = torch.randn(len(directions), first_layer.shape[0], generator=gen)

    def encoding() -> None:
        sinusoidal_encoding(directions.clone().requires_grad_(True), brdf.num_frequencies).backward(encoding_grad)

    rows = [("Disney factor", _median_ms(forward_backward(disney), repeats))]
    if compile_disney:
        compiled = torch.compile(disney, dynamic=True)
        start = time.perf_counter()
        forward_backward(compiled)()
        first = time.perf_counter() - start
        rows.append((f"Disney factor under torch.compile (first call {first:.0f} s)",
                     _median_ms(forward_backward(compiled), repeats)))
    rows += [
        ("network, with its gradient to the directions",
         _median_ms(forward_backward(lambda a, r, m, n, v, l: brdf.modulation(n, v, l)), repeats)),
        ("network, without it", _median_ms(forward_backward(lambda a, r, m, n, v, l: detached.modulation(n, v, l)),
                                           repeats)),
        (f"sinusoidal encoding (N, 9) -> (N, {brdf.input_size})", _median_ms(encoding, repeats)),
        (f"first layer's input gradient (N, {first_layer.shape[0]}) x ({first_layer.shape[0]}, {brdf.input_size})",
         _median_ms(lambda: hidden_grad @ first_layer, repeats)),
        ("the whole learned BRDF", _median_ms(forward_backward(brdf), repeats)),
    ]
    return len(inputs[0]), rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=Path)
    parser.add_argument("--views", type=int, default=8)
    parser.add_argument("--repeats", type=int, default=6)
    parser.add_argument("--parts", action="store_true", help="also time the learned BRDF's parts")
    parser.add_argument("--compile", action="store_true", help="with --parts: also the Disney factor under torch.compile")
    args = parser.parse_args()
    torch.set_num_threads(1)
    count, rows = shading_cost(args.run, args.views, args.repeats)
    print(f"{count:,} Gaussians; ms per view, forward + backward, median of {args.repeats} passes x {args.views} views")
    print("| shading | ms per view |\n|---|---|")
    for name, ms in rows:
        print(f"| {name} | {ms:.1f} |")
    if args.parts:
        count, rows = brdf_parts(args.run, compile_disney=args.compile)
        print(f"\nthe learned BRDF's parts on the first training view's {count:,} Gaussians; forward + backward, "
              "median ms of 20 passes")
        print("| part | ms |\n|---|---|")
        for name, ms in rows:
            print(f"| {name} | {ms:.2f} |")


if __name__ == "__main__":
    main()
