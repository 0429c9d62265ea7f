"""Fisheye lens projections ρ(θ) in float64: the standard four and calibrated polynomials.

ρ = r / R is the image radius relative to the image circle's radius R, θ the angle from
the optical axis in radians.  The four standard projections are normalised so that the
circle's edge (ρ = 1) is θ = 90°:

=============== ======================= =========================================
equidistant      ρ = θ / (π/2)           r = f·θ (polar; most DHP software's default)
equisolid        ρ = sin(θ/2) / sin(π/4) r = 2f·sin(θ/2) (equal-area)
orthographic     ρ = sin θ               r = f·sin θ
stereographic    ρ = tan(θ/2)            r = 2f·tan(θ/2)
polynomial       ρ = Σ_i k_i θ^i         a calibrated lens, i = 1 … n
=============== ======================= =========================================

The polynomial follows hemispheR's and Hemisfer's convention (ρ relative to the image
circle, θ in radians).  Named lenses (:data:`LENSES`) carry the coefficients as published;
where a source gives ρ in terms of θ/90° (Pekin & Macfarlane 2009) they are converted to
radians here (k_i / (π/2)^i), which changes no value.

Inverse projections use closed forms where they exist, written so that sin θ and cos θ
come straight from ρ (no cos of a rounded π/2 at the horizon, no 1 − cos at the zenith);
a polynomial is inverted by Newton steps from a monotone table.  A polynomial must rise
monotonically up to ρ = 1, else :class:`~simlidar_mi.errors.ConfigError`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..errors import ConfigError

__all__ = ["PROJECTIONS", "LENSES", "LENS_SOURCES", "Lens", "lens", "closed_sin_cos"]

PROJECTIONS = ("equidistant", "equisolid", "orthographic", "stereographic", "polynomial")
_HALF_PI = 0.5 * math.pi
_SQRT2 = math.sqrt(2.0)


def _per_radian(coeffs_per_90deg: tuple[float, ...]) -> tuple[float, ...]:
    """Coefficients of ρ(x), x = θ/90°, as coefficients of ρ(θ), θ in radians."""
    return tuple(c / _HALF_PI ** (i + 1) for i, c in enumerate(coeffs_per_90deg))


# ρ(θ) = Σ k_i θ^i, θ in radians.  Sources: hemispheR 1.1.7 (Chianucci & Macek), R/gapfrac_fisheye.R,
# which takes FC-E8, Nikkor-10.5 and Sigma-4.5 from Pekin & Macfarlane 2009, Remote Sens. 1:1298,
# doi:10.3390/rs1041298 (given in θ/90°), and Sigma-8, FC-E9, Nikkor-8 from Hemisfer's lens files
# (P. Schleppi, https://www.schleppi.ch/patrick/hemisfer/, given in radians).
LENSES: dict[str, tuple[float, ...]] = {
    "FC-E8": _per_radian((1.06, 0.00498, -0.0639)),
    "Nikkor-10.5": _per_radian((1.13, 0.00798, -0.138)),
    "Sigma-4.5": _per_radian((1.12, 0.00598, -0.178)),
    "Sigma-8": (0.75276, -0.073937),
    "FC-E9": (0.6427, 0.0346, -0.024491),
    "Nikkor-8": (0.9192, -0.1792, -0.000443),
}
LENS_SOURCES = {
    "FC-E8": "Pekin & Macfarlane 2009 (doi:10.3390/rs1041298) via hemispheR 1.1.7",
    "Nikkor-10.5": "Pekin & Macfarlane 2009 (doi:10.3390/rs1041298) via hemispheR 1.1.7",
    "Sigma-4.5": "Pekin & Macfarlane 2009 (doi:10.3390/rs1041298) via hemispheR 1.1.7",
    "Sigma-8": "Hemisfer lens file via hemispheR 1.1.7",
    "FC-E9": "Hemisfer lens file via hemispheR 1.1.7",
    "Nikkor-8": "Hemisfer lens file via hemispheR 1.1.7",
}
_TABLE_N = 4097  # samples of a polynomial's monotone table (initial guess for Newton)


@dataclass(frozen=True)
class Lens:
    """A lens projection ρ(θ) (module docstring).  Build it with :func:`lens`."""

    projection: str = "equidistant"
    coeffs: tuple[float, ...] = ()
    name: str = ""
    # polynomial only: θ at ρ = 1 and a (θ, ρ) table for the inverse's first guess
    theta_edge_rad: float = _HALF_PI
    _table: tuple = field(default=(), repr=False, compare=False)

    def rho(self, theta_rad) -> np.ndarray:
        """Relative radius ρ of zenith ``theta_rad`` (radians)."""
        t = np.asarray(theta_rad, np.float64)
        p = self.projection
        if p == "equidistant":
            return t / _HALF_PI
        if p == "equisolid":
            return _SQRT2 * np.sin(0.5 * t)
        if p == "orthographic":
            return np.sin(t)
        if p == "stereographic":
            return np.tan(0.5 * t)
        return np.polynomial.polynomial.polyval(t, (0.0,) + self.coeffs)

    def drho_dtheta(self, theta_rad) -> np.ndarray:
        """dρ/dθ per radian."""
        t = np.asarray(theta_rad, np.float64)
        p = self.projection
        if p == "equidistant":
            return np.full_like(t, 1.0 / _HALF_PI)
        if p == "equisolid":
            return np.cos(0.5 * t) / _SQRT2
        if p == "orthographic":
            return np.cos(t)
        if p == "stereographic":
            return 0.5 / np.cos(0.5 * t) ** 2
        d = [i * k for i, k in enumerate(self.coeffs, start=1)]
        return np.polynomial.polynomial.polyval(t, d)

    def sin_cos(self, rho) -> tuple[np.ndarray, np.ndarray]:
        """(sin θ, cos θ) of relative radius ``rho`` ≤ 1, exact near 0° and 90°."""
        r = np.asarray(rho, np.float64)
        closed = closed_sin_cos(self.projection, r, np.sqrt)
        if closed is not None:
            return closed
        t = self.theta(r)
        return np.sin(t), np.cos(t)

    def theta(self, rho) -> np.ndarray:
        """Inverse projection: θ (radians) of relative radius ``rho``; NaN beyond ρ = 1."""
        r = np.asarray(rho, np.float64)
        p = self.projection
        with np.errstate(invalid="ignore"):
            if p == "equidistant":
                t = r * _HALF_PI
            elif p == "equisolid":
                t = 2.0 * np.arcsin(r / _SQRT2)
            elif p == "orthographic":
                t = np.arcsin(np.minimum(r, 1.0))
            elif p == "stereographic":
                t = 2.0 * np.arctan(r)
            else:
                t = self._poly_theta(r)
        return np.where((r >= 0) & (r <= 1.0), t, np.nan)

    def _poly_theta(self, r: np.ndarray) -> np.ndarray:
        tt, rr = self._table
        t = np.interp(np.clip(r, 0.0, 1.0), rr, tt)
        for _ in range(3):  # Newton from a table guess 1/4096 apart: converged in float64
            t = t - (self.rho(t) - r) / self.drho_dtheta(t)
        return np.clip(t, 0.0, self.theta_edge_rad)

    def table(self, n: int = 257) -> tuple[np.ndarray, np.ndarray]:
        """(ρ_j, θ_j) at n evenly spaced ρ in [0, 1], float64 (the plugin's first guess)."""
        rho = np.linspace(0.0, 1.0, n)
        return rho, self.theta(rho)

    def to_dict(self) -> dict:
        return {"projection": self.projection, "coeffs": list(self.coeffs), "name": self.name,
                "theta_edge_deg": math.degrees(self.theta_edge_rad)}


def closed_sin_cos(projection: str, rho, sqrt):
    """(sin θ, cos θ) straight from ρ for the equisolid, orthographic and stereographic lenses
    (None for the others); plain arithmetic, so numpy (float64) and Dr.Jit (the plugin, float32)
    share it with their own ``sqrt``."""
    if projection == "equisolid":
        s = rho * (1.0 / _SQRT2)  # sin(θ/2)
        return 2.0 * s * sqrt((1.0 - s) * (1.0 + s)), 1.0 - 2.0 * s * s
    if projection == "orthographic":
        return rho, sqrt((1.0 - rho) * (1.0 + rho))
    if projection == "stereographic":
        q = 1.0 + rho * rho
        return 2.0 * rho / q, (1.0 - rho) * (1.0 + rho) / q
    return None


def _polynomial(coeffs, name: str, key: str) -> Lens:
    k = tuple(float(c) for c in coeffs)
    if not k or not all(math.isfinite(c) for c in k) or k[0] <= 0:
        raise ConfigError("polynomial lens needs finite coefficients k_1 … k_n (θ in radians) "
                          "with k_1 > 0", key=key, value=list(coeffs))
    # θ at ρ = 1: the first crossing on (0, π); the lens must rise monotonically up to it.
    grid = np.linspace(0.0, math.pi, 8193)
    rho = np.polynomial.polynomial.polyval(grid, (0.0,) + k)
    above = np.nonzero(rho >= 1.0)[0]
    rising = np.all(np.diff(rho[: above[0] + 1]) > 0) if len(above) else False
    if not len(above) or not rising:
        raise ConfigError("polynomial lens must rise monotonically from ρ(0) = 0 to ρ = 1 "
                          "within θ < 180°", key=key, value=list(coeffs))
    j = above[0]
    edge = float(np.interp(1.0, rho[j - 1: j + 1], grid[j - 1: j + 1]))
    tmp = Lens("polynomial", k, name, edge)
    for _ in range(4):
        edge = edge - (float(tmp.rho(edge)) - 1.0) / float(tmp.drho_dtheta(edge))
        tmp = Lens("polynomial", k, name, edge)
    tt = np.linspace(0.0, edge, _TABLE_N)
    return Lens("polynomial", k, name, edge, (tt, tmp.rho(tt)))


def lens(spec: str | Lens = "equidistant", coeffs=None, *, key: str = "fisheye.projection",
         coeffs_key: str = "fisheye.coeffs") -> Lens:
    """A :class:`Lens` from a projection name, a named lens (:data:`LENSES`) or
    ``"polynomial"`` with ``coeffs`` (k_1 … k_n, θ in radians).  Errors name ``key`` (the
    projection's) or ``coeffs_key`` (bad coefficients)."""
    if isinstance(spec, Lens):
        return spec
    if spec == "polynomial":
        if coeffs is None:
            raise ConfigError("projection 'polynomial' needs coefficients", key=key, value=spec)
        return _polynomial(coeffs, "", coeffs_key)
    if spec in LENSES:
        return _polynomial(LENSES[spec], spec, key)
    if spec in PROJECTIONS:
        return Lens(spec)
    raise ConfigError(f"unknown lens; valid: {', '.join(PROJECTIONS[:-1] + tuple(LENSES))} "
                      "or 'polynomial' with coefficients", key=key, value=spec)
