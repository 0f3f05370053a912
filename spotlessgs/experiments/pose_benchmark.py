"""What camera pose refinement costs and buys, on a dataset and a copy of it whose poses are perturbed by a known
amount (as poses from VIO or SfM are a few cm / tenths of a degree off).

    spotless benchmark poses --data DATA --out bench/poses --translation-cm 3 --rotation-deg 0.3 --threads 1

Rows (each a run of one model, the same preset and seed):

* ``clean``: the dataset's poses, no refinement; ``clean+refine``: the same with ``refine_poses`` (it must not make a
  correct dataset worse by much);
* ``perturbed``: the perturbed copy, no refinement; ``perturbed+refine``: the same with ``refine_poses``.

Each row: training ms/step; the training views' pose error against the true poses (the clean dataset's) before
(the poses the run was given) and after refinement: RMSE of the camera centres after a Sim(3) (Umeyama) alignment of
all training views, and the mean rotation angle after that alignment; the test views' pose error at the dataset's
poses and after test-view alignment (in the training views' alignment frame); relit test PSNR / SSIM after one
exposure gain, with the test views aligned before rendering (the default of a run that refined its poses) and not
aligned (at the dataset's poses). Rows are resumable: a finished row is read back from ``OUT/<row>/row.json``.

Two error models (``--error-model``):

* ``independent``: every frame's centre moved by exactly the given distance in a random direction and turned by the
  given angle about a random axis (the errors of frames are unrelated, as SfM's noise);
* ``drift``: the errors of a visual-inertial odometry, a random walk along the frames' order (each frame's error is the
  previous frame's plus a small random step, the first frame exact), scaled so that the RMS over frames of the
  centre's offset and of the rotation's angle are the given distance and angle. Neighbouring frames then share most of
  their error, so the drift is smooth, and a good part of it is a similarity of the whole trajectory that refinement
  need not remove (the pose errors are measured after a Sim(3) alignment).

Points (``--points``): ``kept`` leaves the dataset's point cloud (the simulator's, in the true frame), so the start
knows the true geometry; ``triangulated`` replaces it, in the clean and the perturbed datasets alike, by points
triangulated on the training frames with each dataset's own poses (``spotless prepare --points``), so the perturbed
start shares the poses' errors, as an SfM or VIO cloud does.
"""

from __future__ import annotations

import logging
import math
import shutil
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from spotlessgs.io.atomic import write_json, write_text
from spotlessgs.io.cameras import axis_angle_to_matrix, opengl_to_opencv_c2w
from spotlessgs.io.dataset_fingerprint import dataset_fingerprint
from spotlessgs.io.json_files import read_json
from spotlessgs.io.paths import refuse_overlap
from spotlessgs.io.provenance import provenance
from spotlessgs.io.seeding import numpy_rng

log = logging.getLogger(__name__)

#: Row name -> (dataset: "clean" / "perturbed", refine_poses).
ROWS: dict[str, tuple[str, bool]] = {
    "clean": ("clean", False),
    "clean+refine": ("clean", True),
    "perturbed": ("perturbed", False),
    "perturbed+refine": ("perturbed", True),
}
RESULTS_JSON, RESULTS_MD = "pose_refinement.json", "pose_refinement.md"
#: Pose error models of the perturbed copy (see the module docstring).
ERROR_MODELS = ("independent", "drift")
#: Where the datasets' initial points come from (see the module docstring).
POINT_SOURCES = ("kept", "triangulated")


def moved_pose(c2w_opengl: np.ndarray, offset: np.ndarray, rotvec: np.ndarray) -> np.ndarray:
    """(4, 4) a camera-to-world pose whose centre is moved by ``offset`` (3,) (world axes, metres) and which is turned
    by the rotation vector ``rotvec`` (3,) (radians, world axes) about its centre."""
    out = np.array(c2w_opengl, dtype=np.float64)
    out[:3, 3] += offset
    out[:3, :3] = axis_angle_to_matrix(rotvec) @ out[:3, :3]
    return out


def perturb_pose(c2w_opengl: np.ndarray, translation_m: float, rotation_deg: float,
                 rng: np.random.Generator) -> np.ndarray:
    """(4, 4) a camera-to-world pose moved by ``translation_m`` in a random direction and turned by ``rotation_deg``
    about a random axis through its centre (both uniform on the sphere)."""
    direction = rng.normal(size=3)
    axis = rng.normal(size=3)
    return moved_pose(c2w_opengl, translation_m * direction / np.linalg.norm(direction),
                      math.radians(rotation_deg) * axis / np.linalg.norm(axis))


def drift_offsets(count: int, translation_m: float, rotation_deg: float,
                  rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """A random walk of ``count`` pose errors (the ``drift`` model): centre offsets (count, 3) in metres and rotation
    vectors (count, 3) in radians, both zero at the first frame, each the previous plus an independent Gaussian step,
    scaled so that the RMS of the offsets' lengths is ``translation_m`` and that of the rotation angles is
    ``rotation_deg`` (both zero for a single frame)."""
    def walk(target: float) -> np.ndarray:
        steps = rng.normal(size=(count, 3))
        steps[0] = 0.0
        path = np.cumsum(steps, axis=0)
        rms = float(np.sqrt((np.linalg.norm(path, axis=1) ** 2).mean()))
        return path * (target / rms) if rms > 0 else path

    return walk(translation_m), walk(math.radians(rotation_deg))


def perturbed_poses(c2w_opengl: Sequence[np.ndarray], translation_m: float, rotation_deg: float, model: str,
                    rng: np.random.Generator) -> list[np.ndarray]:
    """The poses (each (4, 4) camera-to-world, in the frames' order) with errors of ``model`` (see the module
    docstring): ``independent`` per frame, or ``drift`` along the sequence (rotations about each camera's centre)."""
    if model == "independent":
        return [perturb_pose(np.asarray(m), translation_m, rotation_deg, rng) for m in c2w_opengl]
    if model != "drift":
        raise ValueError(f"unknown pose error model {model!r}; choose from {list(ERROR_MODELS)}")
    offsets, rotations = drift_offsets(len(c2w_opengl), translation_m, rotation_deg, rng)
    return [moved_pose(m, offset, rotvec) for m, offset, rotvec in zip(c2w_opengl, offsets, rotations)]


def perturbed_copy(data: Path, out: Path, translation_m: float, rotation_deg: float, seed: int = 0,
                   model: str = "independent", points: str = "kept") -> Path:
    """A copy of the dataset ``data`` whose frames' poses (``transforms.json``) carry errors of ``model`` of size
    ``translation_m`` and ``rotation_deg`` (random directions seeded by ``seed``; both zero: the poses unchanged), and
    whose point cloud is ``points`` (``kept`` or ``triangulated`` with the copy's poses); made once, atomically (an
    interrupted copy is redone). The perturbation is recorded in the copy's ``spotless`` block as
    ``pose_perturbation``.

    Raises:
        ValueError: an unknown point source, or ``out`` holds a copy made with other settings (each named).
    """
    if points not in POINT_SOURCES:
        raise ValueError(f"unknown point source {points!r}; choose from {list(POINT_SOURCES)}")
    wanted = {"translation_m": translation_m, "rotation_deg": rotation_deg, "model": model, "points": points,
              "seed": seed}
    from spotlessgs.io.dataset import read_dataset

    source = dataset_fingerprint(read_dataset(data, check_files=True))  # also checks --data (one line naming it)
    if (out / "transforms.json").is_file():
        block = read_json(out / "transforms.json", "perturbed copy").get("spotless")
        made = block.get("pose_perturbation") if isinstance(block, dict) else None
        made = made if isinstance(made, dict) else {}
        differ = [f"{k}: copy {made.get(k)!r}, now {v!r}" for k, v in wanted.items() if made.get(k) != v]
        if made.get("source_fingerprint", source) != source:  # copies made before 2026-12-07 record none
            differ.append(f"source: made from other files than {data} holds")
        if differ:
            raise ValueError(f"{out}: the perturbed copy was made with other settings ({'; '.join(differ)}); use a "
                             f"new --out")
        return out
    partial = out.with_name(out.name + ".partial")
    shutil.rmtree(partial, ignore_errors=True)
    ignored = ["sparse", ".lock", "sfm", "prepare.json"]  # sparse/: the true poses; sfm/: an earlier triangulation
    transforms = read_json(data / "transforms.json", "dataset description", ("frames",))
    if points == "triangulated" and transforms.get("ply_file_path"):
        ignored.append(Path(transforms.pop("ply_file_path")).name)
    shutil.copytree(data, partial, ignore=shutil.ignore_patterns(*ignored))
    rng = numpy_rng(seed, "pose-perturbation")
    moved = perturbed_poses([np.asarray(f["transform_matrix"]) for f in transforms["frames"]], translation_m,
                            rotation_deg, model, rng)
    for frame, pose in zip(transforms["frames"], moved):
        frame["transform_matrix"] = pose.tolist()
    transforms.setdefault("spotless", {})["pose_perturbation"] = {**wanted, "source": str(data),
                                                                  "source_fingerprint": source}
    write_json(partial / "transforms.json", transforms)
    if points == "triangulated":
        from spotlessgs.prepare.points import add_sfm_points

        add_sfm_points(partial, seed=seed)
    partial.rename(out)
    return out


def pose_errors(est_c2w: np.ndarray, true_c2w: np.ndarray, fit: Sequence[int]) -> dict[str, dict[str, float]]:
    """Errors of estimated against true camera-to-world poses (V, 4, 4), OpenCV axes, after the Sim(3) (Umeyama)
    alignment of the camera centres of the views ``fit``: for ``fit`` and for the other views (in that frame), the
    RMSE of the centres (cm) and the mean rotation angle (degrees)."""
    from evaluation.trajectory import rotation_angle_deg, umeyama

    fit = list(fit)
    sim = umeyama(est_c2w[fit, :3, 3], true_c2w[fit, :3, 3])
    centres = sim.apply(est_c2w[:, :3, 3])
    rotations = sim.rotation @ est_c2w[:, :3, :3]
    rest = [k for k in range(len(est_c2w)) if k not in set(fit)]
    out = {}
    for label, idx in (("fit", fit), ("other", rest)):
        if not idx:
            continue
        err = np.linalg.norm(centres[idx] - true_c2w[idx, :3, 3], axis=1)
        rot = rotation_angle_deg(np.swapaxes(true_c2w[idx, :3, :3], 1, 2) @ rotations[idx])
        out[label] = {"ate_cm": 100.0 * float(np.sqrt((err ** 2).mean())), "rotation_deg": float(rot.mean())}
    return out


def row_spec(name: str, data: Path, model: str, preset: str, threads: int, seed: int, iterations: int | None,
             overrides: tuple[tuple[str, Any], ...] = ()):
    """The :class:`~spotlessgs.run.RunSpec` row ``name`` trains on ``data`` (``overrides``: more TrainConfig fields
    of every row; the row's pose refinement switch is set before them)."""
    from spotlessgs.run import RunSpec

    overrides = (("num_threads", threads), ("refine_poses", ROWS[name][1]), *overrides)
    if iterations is not None:
        overrides += (("iterations", iterations),)
    return RunSpec(data=data, model=model, preset=preset, seed=seed, overrides=overrides)


def run_row(name: str, data: Path, truth: Path, out: Path, spec, threads: int) -> dict[str, Any]:
    """Train row ``name`` (its :func:`row_spec` ``spec``) on ``data`` into ``out/name`` (resumed when interrupted),
    measure its poses against the dataset ``truth`` and score its relit test views with ``threads``; the row's
    result, also kept in ``out/name/row.json`` (a rerun under the same settings reuses it)."""
    from spotlessgs.experiments.run_settings import check_finished_row
    from spotlessgs.io.dataset import read_dataset
    from spotlessgs.run import train

    row_file, run_dir = out / name / "row.json", out / name / "run"
    if row_file.is_file():
        check_finished_row(out / name, spec)
        return read_json(row_file, "benchmark row")
    refine = ROWS[name][1]
    run = train(spec, run_dir, resume=(run_dir / "run.json").is_file(), progress=False)
    given = read_dataset(data)
    true = read_dataset(truth).c2w_opencv
    train_views = list(given.split.train)
    row: dict[str, Any] = {"row": name, "data": str(data), "refine_poses": refine,
                           "ms_per_step": run.summary["ms_per_step"], "gaussians": run.summary["num_gaussians"],
                           "test_psnr_reconstruction": run.summary["test_psnr_reconstruction"],
                           "poses_given": pose_errors(given.c2w_opencv, true, train_views)}
    scores = run.score_views(out / name / "relit", "test", threads)
    row["relit"] = {k: scores[k] for k in ("psnr", "ssim", "psnr_aligned", "ssim_aligned")}
    row["relit_test_views_aligned"] = scores["pose_alignment"] is not None and bool(
        scores["pose_alignment"]["aligned_views"])
    if refine:
        poses = run.poses
        refined = np.stack([opengl_to_opencv_c2w(m) for m in poses.c2w_opengl])
        row["poses_refined"] = pose_errors(refined, true, train_views)
        row["alignment_seconds"] = scores["relight"]["pose_alignment"]["seconds"]
        plain = run.score_views(out / name / "relit_not_aligned", "test", threads, align_poses=False)
        row["relit_not_aligned"] = {k: plain[k] for k in ("psnr", "ssim", "psnr_aligned", "ssim_aligned")}
    write_json(row_file, row)
    return row


def run_pose_benchmark(data: Path, out: Path, translation_m: float, rotation_deg: float,
                       rows: Sequence[str] = tuple(ROWS), model: str = "spotless", preset: str = "quick",
                       threads: int = 1, seed: int = 0, iterations: int | None = None,
                       overrides: tuple[tuple[str, Any], ...] = (), error_model: str = "independent",
                       points: str = "kept") -> list[dict[str, Any]]:
    """Every row of :data:`ROWS` named in ``rows`` (``overrides``: TrainConfig fields of every row, e.g. the pose
    refinement's settings; ``error_model`` and ``points``: see the module docstring); writes
    ``OUT/pose_refinement.json`` and ``.md``."""
    from evaluation.runner import require_ground_truth
    from spotlessgs.experiments.run_settings import check_finished_row

    unknown = sorted(set(rows) - set(ROWS))
    if unknown:
        raise ValueError(f"unknown rows {unknown}; choose from {list(ROWS)}")
    if error_model not in ERROR_MODELS:
        raise ValueError(f"unknown pose error model {error_model!r}; choose from {list(ERROR_MODELS)}")
    if not (0.0 <= translation_m <= 100.0 and 0.0 <= rotation_deg <= 180.0):
        raise ValueError(f"pose errors must be 0..100 m and 0..180 deg, got {translation_m} m and {rotation_deg} deg")
    refuse_overlap(out, {"--data": data}, "--out")  # the copies of --data go into --out
    require_ground_truth(data, "--data")  # before a row trains
    out.mkdir(parents=True, exist_ok=True)
    perturbed = perturbed_copy(data, out / "perturbed_data", translation_m, rotation_deg, seed, error_model, points)
    clean = data if points == "kept" else perturbed_copy(data, out / "clean_data", 0.0, 0.0, seed, error_model,
                                                         points)
    datasets = {"clean": clean, "perturbed": perturbed}
    specs = {name: row_spec(name, datasets[ROWS[name][0]], model, preset, threads, seed, iterations, overrides)
             for name in rows}
    for name, spec in specs.items():  # every finished row checked before any trains
        check_finished_row(out / name, spec)
    results = [run_row(name, datasets[ROWS[name][0]], data, out, specs[name], threads) for name in rows]
    write_json(out / RESULTS_JSON, {"rows": results, "translation_m": translation_m, "rotation_deg": rotation_deg,
                                    "error_model": error_model, "points": points,
                                    "model": model, "preset": preset, "iterations": iterations, "threads": threads,
                                    "seed": seed, "overrides": dict(overrides), "provenance": provenance(seed=seed)})
    write_text(out / RESULTS_MD, markdown_table(results))
    return results


def markdown_table(rows: Sequence[dict[str, Any]]) -> str:
    """One line per row: ms/step, training views' pose error given -> refined, test views' given -> aligned, relit
    PSNR / SSIM (exposure aligned) with and without test-view alignment."""

    def err(block: dict | None, part: str) -> str:
        e = (block or {}).get(part)
        return "—" if e is None else f"{e['ate_cm']:.2f} cm / {e['rotation_deg']:.3f}°"

    def score(block: dict | None) -> str:
        return "—" if block is None else f"{block['psnr_aligned']:.2f} / {block['ssim_aligned']:.4f}"

    lines = ["| row | ms/step | train poses given | train poses refined | test poses given | test poses aligned | "
             "relit PSNR / SSIM al. | same, test views not aligned |",
             "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        refined = r.get("poses_refined")
        lines.append(f"| {r['row']} | {r['ms_per_step']:.1f} | {err(r['poses_given'], 'fit')} | "
                     f"{err(refined, 'fit')} | {err(r['poses_given'], 'other')} | {err(refined, 'other')} | "
                     f"{score(r['relit'])} | {score(r.get('relit_not_aligned'))} |")
    return "\n".join(lines) + "\n"
