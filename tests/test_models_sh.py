"""Real SH basis: 3DGS constants, scipy's complex harmonics, orthonormality by quadrature, error paths."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy.special import sph_harm_y

from spotlessgs.models.sh import eval_sh, num_sh_bases, sh_basis

# Coefficients printed in the public 3DGS reference implementation (utils/sh_utils.py), to 16 digits.
GS_CONSTANTS = {
    0: 0.28209479177387814,
    1: 0.4886025119029199,
    "c2": [1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792, 0.5462742152960396],
    "c3": [-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154, -0.4570457994644658,
           1.445305721320277, -0.5900435899266435],
}


def _random_dirs(n: int, seed: int = 0) -> np.ndarray:
    v = np.random.default_rng(seed).normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _real_sh_scipy(l: int, m: int, dirs: np.ndarray) -> np.ndarray:
    """3DGS real SH from scipy's complex ones (Condon-Shortley phase kept): √2 Re Y_l^m, Y_l^0, √2 Im Y_l^|m|."""
    theta = np.arccos(np.clip(dirs[:, 2], -1, 1))
    phi = np.arctan2(dirs[:, 1], dirs[:, 0])
    y = sph_harm_y(l, abs(m), theta, phi)
    if m > 0:
        return math.sqrt(2) * y.real
    if m < 0:
        return math.sqrt(2) * y.imag
    return y.real


def test_basis_matches_3dgs_polynomials_by_hand():
    d = torch.tensor([[0.48, 0.6, 0.64]], dtype=torch.float64)  # unit: .2304+.36+.4096 = 1
    x, y, z = 0.48, 0.6, 0.64
    c2, c3 = GS_CONSTANTS["c2"], GS_CONSTANTS["c3"]
    expected = [
        GS_CONSTANTS[0],
        -GS_CONSTANTS[1] * y, GS_CONSTANTS[1] * z, -GS_CONSTANTS[1] * x,
        c2[0] * x * y, c2[1] * y * z, c2[2] * (2 * z * z - x * x - y * y), c2[3] * x * z, c2[4] * (x * x - y * y),
        c3[0] * y * (3 * x * x - y * y), c3[1] * x * y * z, c3[2] * y * (4 * z * z - x * x - y * y),
        c3[3] * z * (2 * z * z - 3 * x * x - 3 * y * y), c3[4] * x * (4 * z * z - x * x - y * y),
        c3[5] * z * (x * x - y * y), c3[6] * x * (x * x - 3 * y * y),
    ]
    np.testing.assert_allclose(sh_basis(d, 3)[0].numpy(), expected, rtol=1e-12, atol=1e-14)


def test_basis_matches_scipy_complex_harmonics():
    dirs = _random_dirs(200)
    got = sh_basis(torch.from_numpy(dirs), 3).numpy()
    for l in range(4):
        for m in range(-l, l + 1):
            np.testing.assert_allclose(got[:, l * l + l + m], _real_sh_scipy(l, m, dirs), atol=1e-12, err_msg=f"l={l} m={m}")


def test_orthonormal_by_gauss_legendre_quadrature():
    # Gauss-Legendre in cos θ (exact for polynomial degree ≤ 2·12-1) × uniform φ (exact for frequencies < 24).
    mu, w_mu = np.polynomial.legendre.leggauss(12)
    phi = np.arange(24) * (2 * math.pi / 24)
    mu_g, phi_g = np.meshgrid(mu, phi, indexing="ij")
    s = np.sqrt(1 - mu_g**2)
    dirs = np.stack([s * np.cos(phi_g), s * np.sin(phi_g), mu_g], -1).reshape(-1, 3)
    weights = (w_mu[:, None] * np.full(24, 2 * math.pi / 24)[None, :]).reshape(-1)
    y = sh_basis(torch.from_numpy(dirs), 3).numpy()
    gram = (y * weights[:, None]).T @ y
    np.testing.assert_allclose(gram, np.eye(16), atol=1e-12)


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_degree_sizes_and_prefix(degree):
    d = torch.from_numpy(_random_dirs(5))
    assert sh_basis(d, degree).shape == (5, num_sh_bases(degree)) == (5, (degree + 1) ** 2)
    np.testing.assert_array_equal(sh_basis(d, degree), sh_basis(d, 3)[:, : (degree + 1) ** 2])


def test_eval_sh_sums_coefficients_and_ignores_extra_rows():
    d = torch.from_numpy(_random_dirs(7))
    coeffs = torch.randn(7, 16, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(1))
    expected = torch.einsum("nk,nkc->nc", sh_basis(d, 2), coeffs[:, :9])
    torch.testing.assert_close(eval_sh(coeffs, d, 2), expected)
    shared = coeffs[0]  # (16, 3) shared by all directions
    torch.testing.assert_close(eval_sh(shared, d, 3), sh_basis(d, 3) @ shared)


def test_errors():
    d = torch.zeros(2, 3)
    with pytest.raises(ValueError, match="SH degree must be an integer in \\[0, 3\\], got 4"):
        sh_basis(d, 4)
    with pytest.raises(ValueError, match="got True"):
        sh_basis(d, True)
    with pytest.raises(ValueError, match=r"shape \(\.\.\., 3\), got \(2, 2\)"):
        sh_basis(torch.zeros(2, 2), 1)
    with pytest.raises(ValueError, match="degree 3 needs 16 coefficient rows"):
        eval_sh(torch.zeros(2, 9, 3), d, 3)
