"""Intensities of the forest's Poisson processes (seed 004, §III): the domain, the
squared-exponential bumps ``C·exp(−[(x − x0)²/h + (y − y0)²/l])``, one species' sum of them,
∫_D λ in closed form and λ on a grid. Placement is :mod:`simlidar_mi.forest.placement`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence, overload

import numpy as np
from scipy.special import erf, erfc

from ..config.checks import real
from ..errors import ConfigError

__all__ = ["Bump", "Domain", "SpeciesIntensity", "expected_count", "intensity_grid"]

@dataclass(frozen=True)
class Domain:
    """Axis-aligned rectangle ``[x_min_m, x_max_m] × [y_min_m, y_max_m]`` in metres."""

    x_min_m: float
    x_max_m: float
    y_min_m: float
    y_max_m: float

    def __post_init__(self) -> None:
        for name in ("x_min_m", "x_max_m", "y_min_m", "y_max_m"):
            object.__setattr__(self, name, real(f"domain.{name}", getattr(self, name)))
        if not self.x_max_m > self.x_min_m:
            raise ConfigError(f"must exceed x_min_m = {self.x_min_m} (empty domain)",
                              key="domain.x_max_m", value=self.x_max_m)
        if not self.y_max_m > self.y_min_m:
            raise ConfigError(f"must exceed y_min_m = {self.y_min_m} (empty domain)",
                              key="domain.y_max_m", value=self.y_max_m)

    @classmethod
    def of(cls, domain: "Domain | Sequence[float]") -> "Domain":
        """Accept a Domain or a tuple ``(x_min_m, x_max_m, y_min_m, y_max_m)``."""
        if isinstance(domain, Domain):
            return domain
        try:
            values = tuple(domain)
        except TypeError:
            raise ConfigError("must be (x_min_m, x_max_m, y_min_m, y_max_m)",
                              key="domain", value=domain) from None
        if len(values) != 4:
            raise ConfigError("must be (x_min_m, x_max_m, y_min_m, y_max_m)",
                              key="domain", value=domain)
        return cls(*values)

    @property
    def area_m2(self) -> float:
        return (self.x_max_m - self.x_min_m) * (self.y_max_m - self.y_min_m)


@dataclass(frozen=True)
class Bump:
    """One squared-exponential term ``C·exp(−[(x−x0)²/h + (y−y0)²/l])`` (seed 004).

    Parameters
    ----------
    C_per_m2 : peak intensity in trees per m² (≥ 0).
    x0_m, y0_m : centre in metres (may lie outside the domain).
    h_m2, l_m2 : spreads along x and y in m² (> 0); the bump falls to 1/e at
        ``|x − x0| = sqrt(h)``. Note there is no factor 2: h = 2σ².
    """

    C_per_m2: float
    x0_m: float
    y0_m: float
    h_m2: float
    l_m2: float

    def __post_init__(self) -> None:
        for name in ("C_per_m2", "x0_m", "y0_m", "h_m2", "l_m2"):
            object.__setattr__(self, name, real(f"Bump.{name}", getattr(self, name)))
        if self.C_per_m2 < 0:
            raise ConfigError("peak intensity must be >= 0 trees/m²", key="Bump.C_per_m2",
                              value=self.C_per_m2)
        for name in ("h_m2", "l_m2"):
            if getattr(self, name) <= 0:
                raise ConfigError("spread must be > 0 m²", key=f"Bump.{name}",
                                  value=getattr(self, name))

    def __call__(self, x_m: np.ndarray, y_m: np.ndarray) -> np.ndarray:
        return self.C_per_m2 * np.exp(-((np.asarray(x_m) - self.x0_m) ** 2 / self.h_m2
                                        + (np.asarray(y_m) - self.y0_m) ** 2 / self.l_m2))

    def max_over(self, domain: Domain) -> float:
        """Largest value on the domain: at the point of D nearest the centre."""
        dx = min(max(self.x0_m, domain.x_min_m), domain.x_max_m) - self.x0_m
        dy = min(max(self.y0_m, domain.y_min_m), domain.y_max_m) - self.y0_m
        return self.C_per_m2 * math.exp(-(dx * dx / self.h_m2 + dy * dy / self.l_m2))

    def integral(self, domain: Domain) -> float:
        """∫_D of the bump, in trees, closed form with erf (separable Gaussian)."""
        ix = math.sqrt(math.pi * self.h_m2) / 2 * _erf_diff(
            (domain.x_min_m - self.x0_m) / math.sqrt(self.h_m2),
            (domain.x_max_m - self.x0_m) / math.sqrt(self.h_m2))
        iy = math.sqrt(math.pi * self.l_m2) / 2 * _erf_diff(
            (domain.y_min_m - self.y0_m) / math.sqrt(self.l_m2),
            (domain.y_max_m - self.y0_m) / math.sqrt(self.l_m2))
        return self.C_per_m2 * ix * iy


def _erf_diff(a: float, b: float) -> float:
    """erf(b) − erf(a) for a ≤ b without cancellation when both lie in one tail."""
    if a > 0:
        return float(erfc(a) - erfc(b))
    if b < 0:
        return float(erfc(-b) - erfc(-a))
    return float(erf(b) - erf(a))


@dataclass(frozen=True)
class SpeciesIntensity:
    """Intensity of one species: a sum of bumps plus a constant background.

    Parameters
    ----------
    name : species label.
    bumps : the squared-exponential terms (a list is converted to a tuple).
    background_per_m2 : constant intensity added everywhere, trees per m² (≥ 0).
    """

    name: str
    bumps: tuple[Bump, ...] = ()
    background_per_m2: float = 0.0

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise ConfigError("species needs a non-empty name", key="species.name",
                              value=self.name)
        bumps = tuple(self.bumps)
        for i, b in enumerate(bumps):
            if not isinstance(b, Bump):
                raise ConfigError("must be a Bump", key=f"{self.name}.bumps[{i}]", value=b)
        object.__setattr__(self, "bumps", bumps)
        bg = real(f"{self.name}.background_per_m2", self.background_per_m2)
        if bg < 0:
            raise ConfigError("must be >= 0 trees/m²", key=f"{self.name}.background_per_m2",
                              value=bg)
        object.__setattr__(self, "background_per_m2", bg)

    def intensity(self, x_m: np.ndarray, y_m: np.ndarray) -> np.ndarray:
        """λ at the given points, trees per m² (broadcasting)."""
        x_m, y_m = np.asarray(x_m, np.float64), np.asarray(y_m, np.float64)
        lam = np.full(np.broadcast_shapes(x_m.shape, y_m.shape), self.background_per_m2)
        for b in self.bumps:
            lam += b(x_m, y_m)
        return lam

    def upper_bound(self, domain: Domain | Sequence[float]) -> float:
        """λ* = background + Σ_k max_D(bump_k) ≥ max_D λ, trees per m².

        Each term is the bump's exact maximum over D (C_k when its centre lies
        in D, so λ* = background + Σ C_k then). A sum of maxima bounds the
        maximum of the sum, which is all thinning needs; it is tight for one
        bump centred in D and wastes candidates only where bumps overlap little.
        """
        d = Domain.of(domain)
        return self.background_per_m2 + sum(b.max_over(d) for b in self.bumps)


@overload
def expected_count(species: SpeciesIntensity, domain: Domain | Sequence[float]) -> float: ...
@overload
def expected_count(species: Sequence[SpeciesIntensity],
                   domain: Domain | Sequence[float]) -> np.ndarray: ...


def expected_count(species, domain):
    """∫_D λ ds: the mean number of trees before the minimum-distance step.

    Parameters
    ----------
    species : SpeciesIntensity or sequence of them.
    domain : Domain or ``(x_min_m, x_max_m, y_min_m, y_max_m)``; any
        sub-rectangle works, e.g. a histogram bin.

    Returns
    -------
    float for one species, else an array with one value per species.
    """
    d = Domain.of(domain)
    if isinstance(species, SpeciesIntensity):
        return species.background_per_m2 * d.area_m2 + sum(b.integral(d) for b in species.bumps)
    return np.array([expected_count(s, d) for s in species], dtype=np.float64)


def intensity_grid(species: Sequence[SpeciesIntensity], domain: Domain | Sequence[float],
                   nx: int, ny: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """λ of every species on a regular grid, for contour plots.

    Returns
    -------
    x_m : (nx,) grid abscissae, from x_min_m to x_max_m inclusive.
    y_m : (ny,) grid ordinates.
    lam_per_m2 : (n_species, ny, nx) intensities (row index = y, as matplotlib expects).
    """
    d = Domain.of(domain)
    if int(nx) < 2 or int(ny) < 2:
        raise ConfigError("grid needs at least 2 points per axis", key="nx, ny",
                          value=(nx, ny))
    x = np.linspace(d.x_min_m, d.x_max_m, int(nx))
    y = np.linspace(d.y_min_m, d.y_max_m, int(ny))
    xx, yy = np.meshgrid(x, y)
    lam = np.stack([s.intensity(xx, yy) for s in species]) if len(species) else \
        np.zeros((0, int(ny), int(nx)))
    return x, y, lam
