"""Reflectance models: Lambertian (DarkGS), analytic Disney/GGX, and the learned BRDF of SpotlessGS.

Units. `disney_brdf` returns the physical BRDF f (1/sr). The shading modules use the π-scaled reflectance
f̃ = π f, for which a Lambertian surface of albedo a gives exactly f̃ = a; the colour of a Gaussian is then
f̃ · max(0, n̂·l̂) · L_in (see `spotlessgs.models.shading`). The albedo a enters the Disney model as its base colour and
is NOT multiplied in a second time (the research code applied softplus(albedo) on top of a Disney term that already
contained the raw albedo).

Disney/GGX, all dot products of unit vectors, h = normalize(l + v):
    α = max(ρ², α_min)                                     GGX width from roughness ρ
    D = α² / (π (cos²θ_h (α² - 1) + 1)²)                   GGX normal distribution
    k = (ρ + 1)² / 8,  G1(c) = c / (c (1 - k) + k)           Smith-Schlick shadowing (Karis' analytic-light remap)
    F = F0 + (1 - F0)(1 - l·h)⁵,  F0 = lerp(0.04, a, η)      Schlick Fresnel, metalness η
    f_spec = D F G1(n·l) G1(n·v) / (4 (n·l)(n·v)) = D F / (4 (n·l (1-k) + k)(n·v (1-k) + k))
    f_diff = (1 - η) a/π (1 + (F_D90 - 1)(1 - n·l)⁵)(1 + (F_D90 - 1)(1 - n·v)⁵),  F_D90 = ½ + 2 ρ (l·h)²   (Burley)
    or, without Burley's factor (``burley=False``), the Lambertian f_diff = (1 - η) a/π
Guards: n·l and n·v are clamped to [ε, 1] (ε = 1e-4) inside the BRDF, α ≥ 1e-3, and the G1 ratio is simplified
algebraically so that no denominator goes below k² ≥ 1/64. The model is symmetric in (l, v) (reciprocity).

Learned BRDF (the released SpotlessGS variant, written afresh):
    f̃ = clamp(π f_Disney(a, ρ, η; v, l, n) · (1 + 0.2 tanh(MLP(γ(v), γ(l), γ(n)))), 0, 1)
γ is the sinusoidal encoding with 6 frequency bands (2^k π, k = 0..5) plus the identity: 3 · (1 + 2·6) = 39 features per
unit vector, 117 for (v, l, n) together — the research code's 117-wide input. MLP 117→256→256→1 (ReLU), last layer
zero-initialised so that f̃ starts equal to the clamped analytic model. The upper clamp f̃ ≤ 1 bounds the reflected
fraction of any incident light: ∫ f cos dω = (1/π) ∫ f̃ cos dω ≤ 1 (white-furnace bound).
"""

from __future__ import annotations

import math

import torch
from torch import nn

from spotlessgs.io.seeding import torch_generator
from spotlessgs.models.geometry import safe_normalize
from spotlessgs.models.nets import encoding_size, seeded_linear, sinusoidal_encoding

# Lower clamp of n·l and n·v inside the BRDF (grazing angles).
COS_EPS = 1e-4
# Lower clamp of the GGX width α = ρ².
ALPHA_MIN = 1e-3
# Dielectric reflectance at normal incidence (index ≈ 1.5).
F0_DIELECTRIC = 0.04
# Learned-BRDF settings (see module docstring).
BRDF_FREQUENCIES = 6
BRDF_HIDDEN = 256
BRDF_RESIDUAL = 0.2


def disney_brdf(
    albedo: torch.Tensor,
    roughness: torch.Tensor,
    metalness: torch.Tensor,
    normals: torch.Tensor,
    view_dirs: torch.Tensor,
    light_dirs: torch.Tensor,
    burley: bool = True,
) -> torch.Tensor:
    """Physical Disney/GGX BRDF f (1/sr), without the cosine factor.

    Args:
        albedo: (N, 3) base colour in [0, 1].
        roughness: (N, 1) or (N,) ρ in [0, 1].
        metalness: (N, 1) or (N,) η in [0, 1].
        normals, view_dirs, light_dirs: (N, 3) unit vectors n̂, v̂ (point → camera), l̂ (point → light).
        burley: the diffuse lobe with Burley's retro-reflection factor (brighter towards grazing for rough surfaces
            lit and seen from one direction, darker for smooth ones); False: the Lambertian lobe (1 - η) a/π.
    Returns:
        (N, 3) BRDF values ≥ 0, finite for all inputs including ρ = 0, grazing and back-facing directions.
    """
    rough = _column(roughness, "roughness")
    metal = _column(metalness, "metalness")
    n_l = (normals * light_dirs).sum(-1, keepdim=True).clamp(COS_EPS, 1.0)
    n_v = (normals * view_dirs).sum(-1, keepdim=True).clamp(COS_EPS, 1.0)
    half = safe_normalize(light_dirs + view_dirs, fallback=normals)
    n_h = (normals * half).sum(-1, keepdim=True).clamp(0.0, 1.0)
    l_h = (light_dirs * half).sum(-1, keepdim=True).clamp(0.0, 1.0)

    alpha = (rough * rough).clamp_min(ALPHA_MIN)
    alpha_sq = alpha * alpha
    d_denom = n_h * n_h * (alpha_sq - 1.0) + 1.0  # ≥ α² > 0
    ndf = alpha_sq / (math.pi * d_denom * d_denom)
    k = (rough + 1.0) ** 2 / 8.0
    vis = 1.0 / (4.0 * (n_l * (1.0 - k) + k) * (n_v * (1.0 - k) + k))
    f0 = F0_DIELECTRIC * (1.0 - metal) + albedo * metal
    fresnel = f0 + (1.0 - f0) * (1.0 - l_h) ** 5
    specular = ndf * vis * fresnel

    diffuse = (1.0 - metal) * albedo / math.pi
    if burley:
        fd90 = 0.5 + 2.0 * rough * l_h * l_h
        diffuse = diffuse * (1.0 + (fd90 - 1.0) * (1.0 - n_l) ** 5) * (1.0 + (fd90 - 1.0) * (1.0 - n_v) ** 5)
    return diffuse + specular


class LambertianBRDF(nn.Module):
    """Lambertian reflectance f̃ = a (π-scaled, see module docstring); no parameters."""

    def forward(
        self,
        albedo: torch.Tensor,
        roughness: torch.Tensor | None,
        metalness: torch.Tensor | None,
        normals: torch.Tensor,
        view_dirs: torch.Tensor,
        light_dirs: torch.Tensor,
    ) -> torch.Tensor:
        """Return albedo (N, 3); the other arguments (shapes as in `disney_brdf`) are accepted for a common interface."""
        return albedo


# Roughness samples of the directional-albedo table (directional_albedo_table) and the quadrature points per entry.
ALBEDO_TABLE_SIZE = 257
ALBEDO_TABLE_SAMPLES = 4096


def directional_albedo_table(size: int = ALBEDO_TABLE_SIZE, samples: int = ALBEDO_TABLE_SAMPLES,
                             burley: bool = True) -> torch.Tensor:
    """The unclamped Disney model's directional albedo seen along the normal (v̂ = n̂), split so that it is linear in
    the material: R = (1 - η) a C(ρ) + F0 A(ρ) + B(ρ), F0 = lerp(0.04, a, η). Returns (size, 3) float64 rows
    [A, B, C] at ρ = linspace(0, 1, size).

    With v̂ = n̂ everything is symmetric about n̂, so each term is a 1-D midpoint quadrature with ``samples`` points:
    the specular one importance-samples the GGX half-vector (cos²θ_h = (1 - u) / (1 + (α² - 1) u), u uniform; then
    f cos / pdf = 4 V(n·l) n·l with l̂ the mirror of n̂ about ĥ and V the visibility term of :func:`disney_brdf`),
    exact for any roughness where a cosine-weighted quadrature misses a sharp lobe; the diffuse one integrates Burley's
    factor over μ = n·l (C = 2 ∫ F_B(μ) μ dμ, (l·h)² = (1 + μ) / 2), or is exactly 1 without it (``burley=False``).
    """
    rough = torch.linspace(0.0, 1.0, size, dtype=torch.float64)[:, None]
    u = (torch.arange(samples, dtype=torch.float64)[None] + 0.5) / samples
    alpha_sq = (rough * rough).clamp_min(ALPHA_MIN) ** 2
    cos_h = torch.sqrt((1.0 - u) / (1.0 + (alpha_sq - 1.0) * u))
    n_l = 2.0 * cos_h * cos_h - 1.0
    k = (rough + 1.0) ** 2 / 8.0
    vis = 1.0 / (4.0 * (n_l.clamp(COS_EPS, 1.0) * (1.0 - k) + k))  # the n·v factor is 1 (v̂ = n̂)
    weight = torch.where(n_l > 0, 4.0 * vis * n_l, torch.zeros_like(n_l))
    schlick = (1.0 - cos_h) ** 5
    spec_a = (weight * (1.0 - schlick)).mean(1)
    spec_b = (weight * schlick).mean(1)
    if burley:
        mu = u
        fd90 = 0.5 + 2.0 * rough * (1.0 + mu) / 2.0
        diffuse = 2.0 * ((1.0 + (fd90 - 1.0) * (1.0 - mu) ** 5) * mu).mean(1)
    else:
        diffuse = torch.ones_like(spec_a)
    return torch.stack([spec_a, spec_b, diffuse], dim=1)


# The tables of directional_albedo_table, by whether the diffuse lobe has Burley's factor; built once per process.
_ALBEDO_TABLES: dict[bool, torch.Tensor] = {}


def disney_directional_albedo(albedo: torch.Tensor, roughness: torch.Tensor, metalness: torch.Tensor,
                              burley: bool = True) -> torch.Tensor:
    """The unclamped Disney model's directional albedo under uniform light seen along the normal,
    R = (1/π) ∫ π f cos dω, (N, 3), from :func:`directional_albedo_table` (linear in ρ between its rows, so
    differentiable in a, ρ and η). Shapes and ``burley`` as in :func:`disney_brdf`."""
    if burley not in _ALBEDO_TABLES:  # 257 x 4096 quadrature, about 0.3 s
        _ALBEDO_TABLES[burley] = directional_albedo_table(burley=burley)
    rough = _column(roughness, "roughness").clamp(0.0, 1.0)
    metal = _column(metalness, "metalness")
    table = _ALBEDO_TABLES[burley].to(device=albedo.device, dtype=albedo.dtype)
    position = rough * (table.shape[0] - 1)
    low = position.floor().clamp(max=table.shape[0] - 2).long().squeeze(1)
    frac = position - low[:, None].to(position.dtype)
    row = table[low] * (1.0 - frac) + table[low + 1] * frac  # (N, 3): A, B, C
    f0 = F0_DIELECTRIC * (1.0 - metal) + albedo * metal
    return (1.0 - metal) * albedo * row[:, 2:3] + f0 * row[:, 0:1] + row[:, 1:2]


class LearnedBRDF(nn.Module):
    """SpotlessGS learned BRDF: clamp(π f_Disney · (1 + 0.2 tanh(MLP(γ(v), γ(l), γ(n)))), 0, 1), shared by all Gaussians.

    Args:
        num_frequencies: bands of the sinusoidal encoding γ (input width 9 · (1 + 2F), 117 for F = 6).
        hidden: hidden width.
        residual: modulation strength (0.2: the learned factor stays in [0.8, 1.2]).
        seed: seed of the hidden-layer initialisation (stage "brdf_mlp").
        upper_clamp: clamp f̃ at 1 (the research code's bound). It is no white-furnace bound: a glossy lobe's peak is
            far above 1, so the clamp flattens glossy and metallic surfaces (a metal of ρ = 0.1 and a = 0.7 reflects
            3 % of uniform light instead of 70 %). False: f̃ = π f_Disney · modulation, only kept ≥ 0.
        burley: the Disney diffuse lobe with Burley's retro-reflection factor (the paper's); False: Lambertian
            (see :func:`disney_brdf`).
        input_gradients: the network passes its gradient on to the directions it reads (the paper's: through v̂ and
            l̂ to the Gaussians' positions and the lamp's pose, through n̂ to the normals). False: the network reads
            them detached, so that it learns the reflectance's residual without moving geometry or the lamp (the
            analytic Disney factor still does), and training skips the encoding's backward pass and the first
            layer's input gradient (modulation values unchanged).
    """

    def __init__(
        self,
        num_frequencies: int = BRDF_FREQUENCIES,
        hidden: int = BRDF_HIDDEN,
        residual: float = BRDF_RESIDUAL,
        seed: int = 0,
        upper_clamp: bool = True,
        burley: bool = True,
        input_gradients: bool = True,
    ) -> None:
        super().__init__()
        self.upper_clamp = upper_clamp
        self.burley = burley
        self.input_gradients = input_gradients
        if not 0.0 <= residual < 1.0:
            raise ValueError(f"LearnedBRDF residual must be in [0, 1) to keep the factor positive, got {residual}")
        self.num_frequencies = num_frequencies
        self.residual = residual
        self.input_size = encoding_size(9, num_frequencies)
        gen = torch_generator(seed, "brdf_mlp")
        last = nn.Linear(hidden, 1)
        nn.init.zeros_(last.weight)
        nn.init.zeros_(last.bias)
        self.mlp = nn.Sequential(
            seeded_linear(self.input_size, hidden, gen), nn.ReLU(),
            seeded_linear(hidden, hidden, gen), nn.ReLU(),
            last,
        )

    def modulation(self, normals: torch.Tensor, view_dirs: torch.Tensor, light_dirs: torch.Tensor) -> torch.Tensor:
        """Learned factor 1 + r tanh(MLP(γ(v), γ(l), γ(n))) for unit vectors (N, 3) each → (N, 1) in [1-r, 1+r]
        (with ``input_gradients`` False, no gradient to the three directions)."""
        dirs = torch.cat([view_dirs, light_dirs, normals], dim=-1)
        if not self.input_gradients:
            dirs = dirs.detach()
        return 1.0 + self.residual * torch.tanh(self.mlp(sinusoidal_encoding(dirs, self.num_frequencies)))

    def forward(
        self,
        albedo: torch.Tensor,
        roughness: torch.Tensor,
        metalness: torch.Tensor,
        normals: torch.Tensor,
        view_dirs: torch.Tensor,
        light_dirs: torch.Tensor,
    ) -> torch.Tensor:
        """π-scaled reflectance f̃ (N, 3) in [0, 1]; argument shapes as in `disney_brdf`."""
        analytic = math.pi * disney_brdf(albedo, roughness, metalness, normals, view_dirs, light_dirs, self.burley)
        reflectance = analytic * self.modulation(normals, view_dirs, light_dirs)
        return reflectance.clamp(0.0, 1.0) if self.upper_clamp else reflectance


def _column(x: torch.Tensor, name: str) -> torch.Tensor:
    """(N,) or (N, 1) → (N, 1)."""
    if x.ndim == 1:
        return x.unsqueeze(-1)
    if x.ndim == 2 and x.shape[1] == 1:
        return x
    raise ValueError(f"{name} must have shape (N,) or (N, 1), got {tuple(x.shape)}")
