"""Real spherical harmonics up to degree 3, in the convention of 3D Gaussian Splatting.

Basis index k = l² + l + m for degree l and order m ∈ [-l, l]; `sh_basis(dirs, degree)` maps unit directions (N, 3)
(x, y, z) to (N, (degree+1)²) values.

Convention and derivation. With the complex harmonics Y_l^m(θ, φ) = K_l^m P_l^m(cos θ) e^{imφ} (Condon–Shortley phase
inside P_l^m, K_l^m = sqrt((2l+1)/(4π) · (l-|m|)!/(l+|m|)!)), the real basis used here is

    y_l^m = √2 · Re Y_l^m      (m > 0),    y_l^0 = Y_l^0,    y_l^m = √2 · Im Y_l^{|m|}     (m < 0),

which keeps the Condon–Shortley sign (-1)^m. This is exactly the basis of the 3DGS reference implementation (its
degree-1 terms are -C1·y, C1·z, -C1·x), so SH colours exported from this project read correctly in 3DGS viewers.
Each function is a homogeneous polynomial in (x, y, z) on the unit sphere; the constants below are the products of
K_l^m, √2 and the polynomial's leading factor, written out as closed forms:

    C0   = 1 / (2√π)                         = 0.28209479   (l=0)
    C1   = √(3 / (4π))                       = 0.48860251   (l=1: y, z, x with signs -, +, -)
    C2_0 = ½√(15/π)                          = 1.09254843   (xy, yz, xz)
    C2_1 = ¼√(5/π)                           = 0.31539157   (2z² - x² - y²)
    C2_2 = ¼√(15/π)                          = 0.54627422   (x² - y²)
    C3_0 = ¼√(35/(2π))                       = 0.59004359   (y(3x² - y²), x(x² - 3y²))
    C3_1 = ½√(105/π)                         = 2.89061144   (xyz)
    C3_2 = ¼√(21/(2π))                       = 0.45704580   (y(4z² - x² - y²), x(4z² - x² - y²))
    C3_3 = ¼√(7/π)                           = 0.37317633   (z(2z² - 3x² - 3y²))
    C3_4 = ¼√(105/π)                         = 1.44530572   (z(x² - y²))

The basis is orthonormal on the unit sphere (∫ y_a y_b dω = δ_ab); tests check it against scipy's complex harmonics
and by quadrature.
"""

from __future__ import annotations

import math

import torch

SH_C0 = 1.0 / (2.0 * math.sqrt(math.pi))
SH_C1 = math.sqrt(3.0 / (4.0 * math.pi))
SH_C2 = (
    0.5 * math.sqrt(15.0 / math.pi),
    -0.5 * math.sqrt(15.0 / math.pi),
    0.25 * math.sqrt(5.0 / math.pi),
    -0.5 * math.sqrt(15.0 / math.pi),
    0.25 * math.sqrt(15.0 / math.pi),
)
SH_C3 = (
    -0.25 * math.sqrt(35.0 / (2.0 * math.pi)),
    0.5 * math.sqrt(105.0 / math.pi),
    -0.25 * math.sqrt(21.0 / (2.0 * math.pi)),
    0.25 * math.sqrt(7.0 / math.pi),
    -0.25 * math.sqrt(21.0 / (2.0 * math.pi)),
    0.25 * math.sqrt(105.0 / math.pi),
    -0.25 * math.sqrt(35.0 / (2.0 * math.pi)),
)
MAX_SH_DEGREE = 3


def num_sh_bases(degree: int) -> int:
    """Number of basis functions up to `degree` inclusive: (degree + 1)²."""
    check_sh_degree(degree)
    return (degree + 1) ** 2


def check_sh_degree(degree: int) -> None:
    """Raise ValueError unless `degree` is an int in [0, 3]."""
    if isinstance(degree, bool) or not isinstance(degree, int) or not 0 <= degree <= MAX_SH_DEGREE:
        raise ValueError(f"SH degree must be an integer in [0, {MAX_SH_DEGREE}], got {degree!r}")


def sh_basis(dirs: torch.Tensor, degree: int) -> torch.Tensor:
    """Real SH basis (3DGS convention) of unit directions.

    Args:
        dirs: (..., 3) unit vectors (x, y, z); they are not renormalised here.
        degree: 0..3.
    Returns:
        (..., (degree+1)²) basis values, ordered l = 0..degree, m = -l..l.
    """
    check_sh_degree(degree)
    if dirs.shape[-1] != 3:
        raise ValueError(f"sh_basis expects directions of shape (..., 3), got {tuple(dirs.shape)}")
    x, y, z = dirs.unbind(-1)
    out = [torch.full_like(x, SH_C0)]
    if degree >= 1:
        out += [-SH_C1 * y, SH_C1 * z, -SH_C1 * x]
    if degree >= 2:
        xx, yy, zz = x * x, y * y, z * z
        out += [
            SH_C2[0] * x * y,
            SH_C2[1] * y * z,
            SH_C2[2] * (2.0 * zz - xx - yy),
            SH_C2[3] * x * z,
            SH_C2[4] * (xx - yy),
        ]
    if degree >= 3:
        out += [
            SH_C3[0] * y * (3.0 * xx - yy),
            SH_C3[1] * x * y * z,
            SH_C3[2] * y * (4.0 * zz - xx - yy),
            SH_C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy),
            SH_C3[4] * x * (4.0 * zz - xx - yy),
            SH_C3[5] * z * (xx - yy),
            SH_C3[6] * x * (xx - 3.0 * yy),
        ]
    return torch.stack(out, dim=-1)


def eval_sh(coeffs: torch.Tensor, dirs: torch.Tensor, degree: int) -> torch.Tensor:
    """Evaluate an SH expansion: Σ_k coeffs[..., k, :] · y_k(dirs).

    Args:
        coeffs: (..., K, C) coefficients with K ≥ (degree+1)² (extra higher-degree rows are ignored), or (K, C) shared
            by all directions.
        dirs: (..., 3) unit vectors.
        degree: 0..3, the highest degree used.
    Returns:
        (..., C) values.
    """
    n = num_sh_bases(degree)
    if coeffs.shape[-2] < n:
        raise ValueError(f"eval_sh: degree {degree} needs {n} coefficient rows, got coeffs of shape {tuple(coeffs.shape)}")
    basis = sh_basis(dirs, degree)  # (..., n)
    if coeffs.ndim == 2:  # shared by all directions: one matrix product
        return basis @ coeffs[:n]
    return (basis.unsqueeze(-1) * coeffs[..., :n, :]).sum(dim=-2)
