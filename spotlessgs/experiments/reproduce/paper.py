"""The paper's own numbers (synthetic dataset), as data, to print beside ours.

Source: ``paper/spotlessgs-paper.tex`` (SpotlessGS). Keys of each row are our method names; values are the paper's.
"""

from __future__ import annotations

SOURCE = "SpotlessGS paper (paper/spotlessgs-paper.tex), synthetic dataset"
# Table III is the one table of the paper measured on its self-collected real-world sequence.
TABLE3_SOURCE = "SpotlessGS paper (paper/spotlessgs-paper.tex), self-collected real-world sequence"

# Table I (tab:quantitative_results), Synthetic Dataset: PSNR / SSIM / LPIPS on the relit test views.
TABLE1 = {
    "3dgs": {"psnr": 6.04, "ssim": 0.391, "lpips": 0.424},
    "darkgs": {"psnr": 10.66, "ssim": 0.685, "lpips": 0.460},
    "spotless": {"psnr": 12.67, "ssim": 0.727, "lpips": 0.381},
}

# Table II (tab:ablation_study), Syn. Dataset.
TABLE2 = {
    "darkgs": {"psnr": 10.66, "ssim": 0.685, "lpips": 0.460},
    "darkgs+sh": {"psnr": 12.62, "ssim": 0.724, "lpips": 0.381},
    "darkgs+brdf": {"psnr": 10.85, "ssim": 0.721, "lpips": 0.403},
    "spotless": {"psnr": 12.67, "ssim": 0.727, "lpips": 0.381},
}

# Table III (tab:sfm_results): COLMAP mean reprojection error (px) and observations per image.
TABLE3 = {
    "input": {"reprojection_error_px": 1.164, "observations_per_image": 480.75},
    "3dgs": {"reprojection_error_px": 0.733, "observations_per_image": 290.76},
    "darkgs": {"reprojection_error_px": 0.611, "observations_per_image": 881.78},
    "spotless": {"reprojection_error_px": 0.463, "observations_per_image": 960.28},
}

# Table IV ("Effect of multi-view rendering on synthetic dataset"): PSNR / SSIM / temporal PSNR / temporal SSIM.
TABLE4 = {
    "cyclegan": {"psnr": 28.97, "ssim": 0.580, "tmp_psnr": 14.92, "tmp_ssim": 0.615},
    "spotless": {"psnr": 32.05, "ssim": 0.887, "tmp_psnr": 15.65, "tmp_ssim": 0.664},
}

# Runtime paragraph (Vessel dataset, NVIDIA RTX 3070): relit frames per second and memory (GB).
RUNTIME = {
    "spotless": {"fps": 101.4, "memory_gb": 1.38},
    "3dgs": {"fps": 228.1, "memory_gb": None},
    "darkgs": {"fps": 369.6, "memory_gb": 1.26},
}
RUNTIME_SOURCE = "SpotlessGS paper, runtime paragraph (Vessel dataset, NVIDIA GeForce RTX 3070)"
