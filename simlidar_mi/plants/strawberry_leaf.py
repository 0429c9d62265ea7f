"""Strawberry leaves (España Boquera et al., 2014): leaf laws, drawn traits, 12-triangle meshes.

The model follows *Modelo informático para la construcción de doseles virtuales de
fresa* (Rev. Mex. Cienc. Agríc., 2014), the "strawberry paper" of the project:

* a **leaf** is three leaflets (a central one and two equal laterals), each a rhomboid
  (kite) of four triangles, 12 triangles a leaf.

Plants and plots of these leaves are in :mod:`simlidar_mi.plants.strawberry`.

Every random quantity is a normal law from the paper's Tables 1–3, truncated to
its physically possible range by *resampling* (rejection), which keeps the shape of
the law inside the range instead of piling mass on the bounds as clipping would.

Geometry only: this module never imports Mitsuba. Lengths are metres, angles are
degrees at the API and radians inside.

Conventions and interpretations (the paper's Figure 1 is not legible in our copy, so
these are our choices; each is a parameter where it can be)
------------------------------------------------------------------------------------
Leaflet shape (Figure 1a)
    ``a`` is the leaflet width (the transverse axis), ``b`` its length along the
    midrib, ``c`` the distance from the leaflet base to the point where the two axes
    cross. The four corners are the base ``B = (0, 0)``, the tip ``T = (b, 0)`` and
    the two side corners ``(c, ±a/2)``; the four triangles share the axes' crossing
    point ``C = (c, 0)``. Its area is ``S = a·b/2``, so ``a = sqrt(2S/(b/a))``.
    Lateral leaflets use ``S' = (S'/S)·S``, ``b'/a' = ((b'/a')/(b/a))·(b/a)`` and
    ``c'/b' = ((c'/b')/(c/b))·(c/b)``.
Leaf frame
    Origin at the petiole tip, where the three leaflet bases meet; ``x`` along the
    central leaflet's midrib, ``y`` to its left, ``z`` the upper-side normal of the
    flat leaf. The laterals' midribs lie along ``±y`` (paper: "perpendicular to the
    main axis of the central leaflet").
Folds α, β, γ
    Folds are rotations of rigid triangles about edges they share, so they preserve
    area exactly. Two kite triangles on each side of a midrib form a rigid half
    leaflet; folding about both kite axes at once is impossible for rigid panels, so
    each leaflet folds about its midrib only.
    α: each half of the *central* leaflet is rotated up by α about its midrib
    (a V opening upwards; the segments ``C → side corner`` make angle α with the
    leaf plane).
    β: the same fold for each *lateral* leaflet about its own midrib.
    γ: each lateral leaflet, as a rigid whole, is lifted by γ out of the leaf plane
    by a rotation about the central midrib line (through the shared base point).
    Negative values fold downwards.
Leaf inclination λ
    The leaf is pitched about the laterals' (horizontal) axis, so the lateral axis
    stays horizontal as in the paper; ``λ > 0`` lowers the central leaflet's tip
    (the leaf dips away from the plant centre). Use a negative mean for the
    opposite convention.
Petiole (φ, θ) and length p
    The paper does not say which of φ, θ is the petiole's zenith angle, nor how
    leaves are spread in azimuth. One of them is the petiole's zenith angle
    (from the vertical), truncated to (0°, 90°) so petioles point above the ground;
    the other is the azimuthal *divergence* between consecutive leaves of a plant:
    leaf ``k`` has azimuth ``ψ0 + Σ_{i≤k} δ_i`` with ``ψ0`` uniform in [0°, 360°)
    for each plant. (Read as an absolute azimuth, either law would put every leaf
    of every plant on the same side, contradicting the paper's radial plants.)
    Default ``petiole_zenith='theta'``: θ (65° ± 45°, truncated to (0°, 90°): mean
    50.8°, SD 23.9°) is the petiole zenith and φ (45° ± 5.6°) the divergence. Source,
    the paper's discussion: "Dada la simplicidad de la estructura la planta de fresa,
    (todas las hojas parten de un único punto en el suelo), las hojas se distribuyen
    radialmente tendiendo a formar una semiesfera, con el fin de evitar los
    recubrimientos entre ellas" (given the strawberry plant's simple structure, all
    leaves starting from one point on the ground, the leaves spread radially, tending
    to form a hemisphere, so as to avoid overlapping one another). Petiole tips spread
    over a hemisphere need a wide zenith law, which only θ has (its SD of 45° spans
    vertical to horizontal); φ's SD of 5.6° puts every tip on one 45° cone, a ring.
    And "radially … to avoid overlapping" fits φ as a near-regular divergence (45°
    steps, eight leaves a turn). This reading was chosen from those sentences, not
    from the comparison: it fits the measured gap fractions *worse* (mean P0 0.18
    against the measured 0.27; bias −0.09), while it follows the field's response to
    leaf removal (−ln P0 ∝ leaf area) far better than the other (BENCHMARKS.md §2,
    "Within-plant overlap"). The earlier default, ``petiole_zenith='phi'`` (φ the
    zenith, θ the divergence: a 45° cone of petioles), stays as the option; it was
    chosen because it fitted the measured gap fractions (bias −0.03…−0.04). With
    θ, 7 % of the leaves reach partly below the ground (0.1 % with φ); they are left
    there (no collision handling, as in the paper). The central leaflet's midrib
    points along the petiole azimuth (away from the plant centre). The petiole length is ``p = (p/a)·a``; the
    petiole itself is not meshed (the paper meshes leaflets only), and leaves are
    not kept above the ground or apart from each other (no collision handling).
Truncation ranges (open intervals; draws outside are redrawn)
    ``S > 0``, ``b/a > 0``, ``p/a > 0``, ``0 < c/b < min(1, 1/((c'/b')/(c/b)))`` (the
    axes must cross inside both the central and the lateral leaflets),
    ``-90° < α, β, γ, λ < 90°``, ``0° < zenith < 90°``; the divergence is not
    truncated. Leaves per plant: a normal draw rounded to the nearest integer and
    redrawn while below 1.

Paper values (defaults)
-----------------------
Table 1: p/a 2.885 ± 0.725, c/b 0.736 ± 0.029, b/a 1.341 ± 0.169, S'/S = 0.918,
(c'/b')/(c/b) = 0.834, (b'/a')/(b/a) = 0.931.
Table 2 (radians in the paper): α π/24 ± π/48, β π/16 ± π/32, γ π/24 ± π/18,
λ π/18 ± π/15, θ π/2.769 ± π/4, φ π/4 ± π/32.
Table 3: inter-row 0.268 ± 0.03 m, intra-row 0.227 ± 0.02 m, leaves per plant
42 ± 5, central-leaflet area S 13.025 ± 5.031 cm².
"""
from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Sequence

import numpy as np

from ..config.checks import real as _real
from ..errors import ConfigError

__all__ = [
    "StrawberryLeafParams", "LeafTraits", "draw_leaf_traits", "leaf_triangles",
    "strawberry_leaf", "TRIANGLES_PER_LEAF",
]

#: Every strawberry leaf is 3 leaflets × 4 triangles.
TRIANGLES_PER_LEAF = 12

# Lowest acceptance probability of a truncated law we accept before calling the
# parameters unusable (rejection sampling would otherwise crawl).
_MIN_ACCEPTANCE = 1e-3
_MAX_REDRAWS = 10_000

# Kite corners are stored in the order B, R, T, L, C (base, right, tip, left,
# centre); the four triangles below all wind counter-clockwise seen from +z, so
# every triangle normal points to the leaf's upper side.
_KITE_TRIANGLES = np.array([[0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4]])


# ----------------------------------------------------------------------------- checks
def _non_negative(key: str, value) -> float:
    v = _real(key, value)
    if v < 0:
        raise ConfigError("must be >= 0", key=key, value=value)
    return v


def _int_at_least(key: str, value, low: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise ConfigError(f"must be an integer >= {low}", key=key, value=value)
    if value < low:
        raise ConfigError(f"must be an integer >= {low}", key=key, value=value)
    return int(value)


def _phi(x: float) -> float:
    """Standard normal CDF (math.erf keeps this module free of scipy)."""
    if x == math.inf:
        return 1.0
    if x == -math.inf:
        return 0.0
    return 0.5 * (1.0 + math.erf(x / math.sqrt(2.0)))


def _check_truncated(key: str, mean: float, sd: float, lo: float, hi: float) -> None:
    """Refuse a normal law that (almost) never falls in (lo, hi)."""
    if not lo < mean < hi:
        raise ConfigError(f"the mean must lie in the valid range ({lo}, {hi})",
                          key=key, value=mean)
    if sd == 0:
        return
    p = _phi((hi - mean) / sd) - _phi((lo - mean) / sd)
    if p < _MIN_ACCEPTANCE:
        raise ConfigError(
            f"N({mean}, {sd}) falls in the valid range ({lo}, {hi}) with probability "
            f"{p:.2e} < {_MIN_ACCEPTANCE}; reduce the SD", key=key, value=mean)


def _truncnorm(rng: np.random.Generator, mean: float, sd: float, lo: float, hi: float,
               n: int) -> np.ndarray:
    """Normal(mean, sd) draws restricted to the open interval (lo, hi) by redrawing."""
    if sd == 0:
        return np.full(n, float(mean))
    x = rng.normal(mean, sd, n)
    for _ in range(_MAX_REDRAWS):
        bad = ~((x > lo) & (x < hi))
        k = int(bad.sum())
        if k == 0:
            return x
        x[bad] = rng.normal(mean, sd, k)
    raise ConfigError(f"could not draw N({mean}, {sd}) inside ({lo}, {hi})")


# ------------------------------------------------------------------------ parameters
@dataclass(frozen=True)
class StrawberryLeafParams:
    """Laws of one strawberry leaf's shape, size and position (paper Tables 1–3).

    Every ``*_mean*``/``*_sd*`` pair is a normal law, truncated by redrawing (see the
    module docstring for the ranges). Set an SD to 0 for a fixed value.

    Parameters
    ----------
    area_mean_m2, area_sd_m2 : float
        Central-leaflet area S, m² (Table 3: 13.025 ± 5.031 cm²).
    b_over_a_mean, b_over_a_sd : float
        Central leaflet length/width ratio (Table 1: 1.341 ± 0.169).
    c_over_b_mean, c_over_b_sd : float
        Relative position of the axes' crossing point along the midrib, from the
        leaflet base (Table 1: 0.736 ± 0.029).
    p_over_a_mean, p_over_a_sd : float
        Petiole length over central-leaflet width (Table 1: 2.885 ± 0.725).
    lateral_area_ratio : float
        S'/S (Table 1: 0.918).
    lateral_b_over_a_factor : float
        (b'/a')/(b/a) (Table 1: 0.931).
    lateral_c_over_b_factor : float
        (c'/b')/(c/b) (Table 1: 0.834).
    alpha_mean_deg, alpha_sd_deg : float
        Central-leaflet midrib fold, degrees (Table 2: π/24 ± π/48 = 7.5 ± 3.75°).
    beta_mean_deg, beta_sd_deg : float
        Lateral-leaflet midrib fold, degrees (π/16 ± π/32 = 11.25 ± 5.625°).
    gamma_mean_deg, gamma_sd_deg : float
        Lift of the lateral leaflets out of the leaf plane, degrees
        (π/24 ± π/18 = 7.5 ± 10°).
    lambda_mean_deg, lambda_sd_deg : float
        Leaf-plane inclination to the horizontal, degrees (π/18 ± π/15 = 10 ± 12°).
    theta_mean_deg, theta_sd_deg : float
        Petiole angle θ, degrees (π/2.769 ± π/4 = 65.005 ± 45°).
    phi_mean_deg, phi_sd_deg : float
        Petiole angle φ, degrees (π/4 ± π/32 = 45 ± 5.625°).
    petiole_zenith : {'phi', 'theta'}
        Which of θ, φ is the petiole zenith angle; the other is the azimuthal
        divergence between consecutive leaves (default 'theta', the paper's
        hemisphere; see the module docstring for the source).
    """

    area_mean_m2: float = 13.025e-4
    area_sd_m2: float = 5.031e-4
    b_over_a_mean: float = 1.341
    b_over_a_sd: float = 0.169
    c_over_b_mean: float = 0.736
    c_over_b_sd: float = 0.029
    p_over_a_mean: float = 2.885
    p_over_a_sd: float = 0.725
    lateral_area_ratio: float = 0.918
    lateral_b_over_a_factor: float = 0.931
    lateral_c_over_b_factor: float = 0.834
    alpha_mean_deg: float = 180.0 / 24
    alpha_sd_deg: float = 180.0 / 48
    beta_mean_deg: float = 180.0 / 16
    beta_sd_deg: float = 180.0 / 32
    gamma_mean_deg: float = 180.0 / 24
    gamma_sd_deg: float = 180.0 / 18
    lambda_mean_deg: float = 180.0 / 18
    lambda_sd_deg: float = 180.0 / 15
    theta_mean_deg: float = 180.0 / 2.769
    theta_sd_deg: float = 180.0 / 4
    phi_mean_deg: float = 180.0 / 4
    phi_sd_deg: float = 180.0 / 32
    petiole_zenith: str = "theta"

    def __post_init__(self) -> None:
        for f in fields(self):
            if f.name == "petiole_zenith":
                continue
            v = getattr(self, f.name)
            if "_sd" in f.name:
                v = _non_negative(f.name, v)
            elif f.name.startswith("lateral_"):
                v = _real(f.name, v, positive=True)
            else:
                v = _real(f.name, v)
            object.__setattr__(self, f.name, v)
        if self.petiole_zenith not in ("theta", "phi"):
            raise ConfigError("must be 'theta' or 'phi'", key="petiole_zenith",
                              value=self.petiole_zenith)
        for key, lo, hi in self._ranges():
            u = _unit(key)
            _check_truncated(f"{key}_mean{u}", getattr(self, f"{key}_mean{u}"),
                             getattr(self, f"{key}_sd{u}"), lo, hi)

    def _ranges(self) -> list[tuple[str, float, float]]:
        """Open validity interval of every truncated law (degrees for angles)."""
        zen, div = ("theta", "phi") if self.petiole_zenith == "theta" else ("phi", "theta")
        out = [
            ("area", 0.0, math.inf),
            ("b_over_a", 0.0, math.inf),
            ("c_over_b", 0.0, min(1.0, 1.0 / self.lateral_c_over_b_factor)),
            ("p_over_a", 0.0, math.inf),
            ("alpha", -90.0, 90.0),
            ("beta", -90.0, 90.0),
            ("gamma", -90.0, 90.0),
            ("lambda", -90.0, 90.0),
            (zen, 0.0, 90.0),
            (div, -math.inf, math.inf),
        ]
        return out

    @property
    def leaf_area_factor(self) -> float:
        """Leaf area / central-leaflet area: 1 + 2·S'/S (2.836 with paper values)."""
        return 1.0 + 2.0 * self.lateral_area_ratio


def _unit(key: str) -> str:
    if key == "area":
        return "_m2"
    if key in ("alpha", "beta", "gamma", "lambda", "theta", "phi"):
        return "_deg"
    return ""


# --------------------------------------------------------------------------- leaves
@dataclass(frozen=True)
class LeafTraits:
    """Drawn traits of ``n`` leaves (arrays of shape ``(n,)``; angles in degrees).

    ``azimuth_deg`` is the absolute azimuth of the petiole (and central midrib),
    counter-clockwise from +x; ``zenith_deg`` the petiole's angle from the vertical.
    """

    area_m2: np.ndarray
    b_over_a: np.ndarray
    c_over_b: np.ndarray
    p_over_a: np.ndarray
    alpha_deg: np.ndarray
    beta_deg: np.ndarray
    gamma_deg: np.ndarray
    lambda_deg: np.ndarray
    zenith_deg: np.ndarray
    azimuth_deg: np.ndarray

    def __len__(self) -> int:
        return len(self.area_m2)


def draw_leaf_traits(params: StrawberryLeafParams, rng: np.random.Generator,
                     n: int) -> LeafTraits:
    """Draw the traits of the ``n`` leaves of one plant.

    Draw order is fixed (S, b/a, c/b, p/a, α, β, γ, λ, zenith, ψ0, divergences) so a
    given generator state always gives the same leaves.

    Parameters
    ----------
    params : StrawberryLeafParams
    rng : numpy.random.Generator
    n : int
        Number of leaves (≥ 0).

    Returns
    -------
    LeafTraits
    """
    n = _int_at_least("n_leaves", n, 0)
    p = params
    ranges = {k: (lo, hi) for k, lo, hi in p._ranges()}

    def law(key: str) -> np.ndarray:
        u = _unit(key)
        lo, hi = ranges[key]
        return _truncnorm(rng, getattr(p, f"{key}_mean{u}"), getattr(p, f"{key}_sd{u}"),
                          lo, hi, n)

    area = law("area")
    b_over_a = law("b_over_a")
    c_over_b = law("c_over_b")
    p_over_a = law("p_over_a")
    alpha, beta, gamma, lam = law("alpha"), law("beta"), law("gamma"), law("lambda")
    zen_key, div_key = ("theta", "phi") if p.petiole_zenith == "theta" else ("phi", "theta")
    zenith = law(zen_key)
    psi0 = rng.uniform(0.0, 360.0)
    divergence = law(div_key)
    azimuth = np.mod(psi0 + np.cumsum(divergence), 360.0)
    return LeafTraits(area, b_over_a, c_over_b, p_over_a, alpha, beta, gamma, lam,
                      zenith, azimuth)


def _kites(a: np.ndarray, b: np.ndarray, c: np.ndarray, fold: np.ndarray) -> np.ndarray:
    """Corners (n, 5, 3) of kites along +x with their halves folded up by ``fold`` rad.

    Each half (two triangles on one side of the midrib) turns rigidly about the
    midrib, so side corners move from ``(c, ±a/2, 0)`` to ``(c, ±a/2·cos f, a/2·sin f)``.
    """
    n = len(a)
    pts = np.zeros((n, 5, 3))
    h = 0.5 * a
    pts[:, 1] = np.stack([c, -h * np.cos(fold), h * np.sin(fold)], axis=1)   # R
    pts[:, 2, 0] = b                                                          # T
    pts[:, 3] = np.stack([c, h * np.cos(fold), h * np.sin(fold)], axis=1)    # L
    pts[:, 4, 0] = c                                                          # C
    return pts


def _rot_x(t: np.ndarray) -> np.ndarray:
    c, s = np.cos(t), np.sin(t)
    o, z = np.ones_like(t), np.zeros_like(t)
    return np.stack([np.stack([o, z, z], -1), np.stack([z, c, -s], -1),
                     np.stack([z, s, c], -1)], -2)


def _rot_y(t: np.ndarray) -> np.ndarray:
    c, s = np.cos(t), np.sin(t)
    o, z = np.ones_like(t), np.zeros_like(t)
    return np.stack([np.stack([c, z, s], -1), np.stack([z, o, z], -1),
                     np.stack([-s, z, c], -1)], -2)


def _rot_z(t: np.ndarray) -> np.ndarray:
    c, s = np.cos(t), np.sin(t)
    o, z = np.ones_like(t), np.zeros_like(t)
    return np.stack([np.stack([c, -s, z], -1), np.stack([s, c, z], -1),
                     np.stack([z, z, o], -1)], -2)


def _apply(m: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Rotate points (n, k, 3) by per-leaf matrices (n, 3, 3)."""
    return np.einsum("nij,nkj->nki", m, pts)


def leaf_triangles(traits: LeafTraits, params: StrawberryLeafParams | None = None,
                   base_xyz_m: Sequence[float] = (0.0, 0.0, 0.0)) -> np.ndarray:
    """Triangles of leaves with given traits (deterministic, vectorised).

    Parameters
    ----------
    traits : LeafTraits
        One entry per leaf.
    params : StrawberryLeafParams, optional
        Supplies the lateral-leaflet constants (paper values by default).
    base_xyz_m : sequence of 3 floats
        Start point of the petioles (the plant's crown), metres.

    Returns
    -------
    numpy.ndarray
        ``(n, 12, 3, 3)`` float64 triangle corners, metres: central leaflet first
        (4 triangles), then the left and right laterals. Normals (right-hand rule)
        point to the leaf's upper side.
    """
    p = params if params is not None else StrawberryLeafParams()
    S = np.asarray(traits.area_m2, float)
    r = np.asarray(traits.b_over_a, float)
    q = np.asarray(traits.c_over_b, float)
    a = np.sqrt(2.0 * S / r)
    b = r * a
    c = q * b
    S2 = p.lateral_area_ratio * S
    r2 = p.lateral_b_over_a_factor * r
    q2 = p.lateral_c_over_b_factor * q
    a2 = np.sqrt(2.0 * S2 / r2)
    b2 = r2 * a2
    c2 = q2 * b2
    rad = np.deg2rad
    central = _kites(a, b, c, rad(traits.alpha_deg))
    lateral = _kites(a2, b2, c2, rad(traits.beta_deg))
    gam = rad(traits.gamma_deg)
    quarter = np.full(len(S), 0.5 * np.pi)
    # Laterals point along ±y, then lift by γ about the central midrib (x axis).
    left = _apply(_rot_x(gam) @ _rot_z(quarter), lateral)
    right = _apply(_rot_x(-gam) @ _rot_z(-quarter), lateral)
    pts = np.concatenate([central, left, right], axis=1)          # (n, 15, 3)
    # Pitch about the horizontal lateral axis (λ > 0 lowers the tip), then turn
    # to the petiole azimuth.
    psi = rad(traits.azimuth_deg)
    pts = _apply(_rot_z(psi) @ _rot_y(rad(traits.lambda_deg)), pts)
    zen = rad(traits.zenith_deg)
    p_len = np.asarray(traits.p_over_a, float) * a
    tip = p_len[:, None] * np.stack([np.sin(zen) * np.cos(psi), np.sin(zen) * np.sin(psi),
                                     np.cos(zen)], axis=1)
    pts = pts + (tip + np.asarray(base_xyz_m, float))[:, None, :]
    idx = np.concatenate([_KITE_TRIANGLES, _KITE_TRIANGLES + 5, _KITE_TRIANGLES + 10])
    return pts[:, idx]                                            # (n, 12, 3, 3)


def strawberry_leaf(params: StrawberryLeafParams, rng: np.random.Generator) -> np.ndarray:
    """One random leaf whose petiole starts at the origin.

    Returns
    -------
    numpy.ndarray
        ``(12, 3, 3)`` float64 triangle corners, metres. Its one-sided area is
        ``S·(1 + 2·S'/S)`` for the drawn central-leaflet area ``S``.
    """
    return leaf_triangles(draw_leaf_traits(params, rng, 1), params)[0]
