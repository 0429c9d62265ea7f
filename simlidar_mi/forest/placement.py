"""Tree positions from inhomogeneous Poisson processes, one per species (seed 004, §III;
the intensities are in :mod:`simlidar_mi.forest.intensity`).

Each species has an intensity (trees per m²) that is a sum of squared-exponential
bumps plus an optional constant background,

    λ(x, y) = background + Σ_k C_k · exp(−[(x − x0_k)²/h_k + (y − y0_k)²/l_k]),

on a rectangle D. Points are drawn by thinning (Lewis & Shedler 1979): uniform
proposals on D kept with probability λ(s)/λ*, λ* ≥ max_D λ. Each species' points arrive
as a Poisson process in time of rate ∫_D λ; those that arrive by t = 1 are the
inhomogeneous Poisson process of intensity λ. The points of all species are then
thinned in arrival order so trees do not overlap too much (the paper: "one is removed
if two trees are too close"): a minimum distance and, given each point's crown radius
``r``, the crown rule ``d_ij ≥ k·(r_i + r_j)``. That step is *not* a Poisson process
any more, so a species' ∫_D λ can mean two counts (``count``, :func:`place_trees`):
the Poisson points before the thinning (``"poisson"``, the paper's reading), or the
trees of the final stand (``"stand"``, ours: candidates are drawn until the stand holds
a Poisson(∫_D λ) target, i.e. C is solved after the thinning).

Randomness comes from the caller's ``numpy.random.Generator``: one child stream is
spawned for the stand targets and one per species, so appending a species leaves the
candidate points of the earlier ones unchanged.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np
from scipy.spatial import cKDTree

from ..config.checks import real
from ..errors import ConfigError
from .intensity import Bump, Domain, SpeciesIntensity, expected_count, intensity_grid  # noqa: F401 (re-exported)

__all__ = [
    "Bump", "Domain", "Placement", "SpeciesIntensity", "expected_count", "intensity_grid",
    "place_trees", "sample_ipp", "thin_min_distance", "crown_overlap_share", "candidate_points",
    "COUNT_MODES", "MAX_CANDIDATE_FACTOR",
]


def sample_ipp(species: SpeciesIntensity, domain: Domain | Sequence[float],
               rng: np.random.Generator, *, max_candidates: int = 20_000_000
               ) -> tuple[np.ndarray, np.ndarray]:
    """Points of one inhomogeneous Poisson process on D, by Lewis–Shedler thinning.

    Parameters
    ----------
    species : the intensity.
    domain : the rectangle.
    rng : random source (consumed: count, x, y, acceptance draws).
    max_candidates : refuse if λ*·|D| exceeds this (memory guard).

    Returns
    -------
    x_m, y_m : float64 arrays of the kept points.
    """
    d = Domain.of(domain)
    lam_max = species.upper_bound(d)
    mean = lam_max * d.area_m2
    if mean > max_candidates:
        raise ConfigError(f"expects {mean:.3g} candidate points (more than "
                          f"{max_candidates}); lower the intensity or the domain",
                          key=f"{species.name}.bumps", value=lam_max)
    n = int(rng.poisson(mean)) if mean > 0 else 0
    x = rng.uniform(d.x_min_m, d.x_max_m, n)
    y = rng.uniform(d.y_min_m, d.y_max_m, n)
    u = rng.uniform(0.0, 1.0, n)
    # Keep with probability λ(s)/λ*. The code published with seed 004 keeps
    # with probability λ(s) itself, which gives intensity λ*·λ(s) instead of λ(s).
    keep = u * lam_max < species.intensity(x, y)
    return x[keep], y[keep]


def _rules(min_distance_m: float, crown_factor: float) -> tuple[float, float]:
    """The checked ``(min_distance_m, crown_factor)`` of the thinning."""
    d_min = real("min_distance_m", min_distance_m)
    if d_min < 0:
        raise ConfigError("must be >= 0 m", key="min_distance_m", value=min_distance_m)
    k = real("crown_factor", crown_factor)
    if k < 0:
        raise ConfigError("must be >= 0", key="crown_factor", value=crown_factor)
    return d_min, k


def thin_min_distance(x_m: np.ndarray, y_m: np.ndarray, min_distance_m: float,
                      rng: np.random.Generator, crown_radius_m: np.ndarray | None = None,
                      crown_factor: float = 0.0) -> np.ndarray:
    """Mask of points kept so that no two kept trees are too close.

    Rule: visit the points in a uniformly random order and keep a point unless an
    already kept point ``j`` conflicts with it: ``d_ij ≤ min_distance_m``, or
    ``d_ij < k·(r_i + r_j)`` with ``k = crown_factor`` and ``r`` the crown radii
    (Matérn type III style). Kept points therefore satisfy
    ``d_ij > min_distance_m`` and ``d_ij ≥ k·(r_i + r_j)``, every dropped point
    conflicts with a kept one, and no species is favoured. ``min_distance_m = 0``
    and ``k = 0`` keep everything.
    """
    d_min, k = _rules(min_distance_m, crown_factor)
    x_m, y_m = np.asarray(x_m, np.float64), np.asarray(y_m, np.float64)
    n = len(x_m)
    r = np.zeros(n) if crown_radius_m is None else np.asarray(crown_radius_m, np.float64)
    if r.shape != (n,) or not (np.isfinite(r).all() and (r >= 0).all()):
        raise ConfigError(f"must be {n} finite radii ≥ 0", key="crown_radius_m", value=r.shape)
    keep = np.ones(n, dtype=bool)
    reach = max(d_min, 2.0 * k * float(r.max(initial=0.0)))   # no conflict beyond this
    if n < 2 or reach == 0:
        return keep
    rank = np.empty(n, dtype=np.int64)
    rank[rng.permutation(n)] = np.arange(n)
    pairs = cKDTree(np.column_stack([x_m, y_m])).query_pairs(reach, output_type="ndarray")
    if len(pairs):
        i, j = pairs[:, 0], pairs[:, 1]
        d = np.hypot(x_m[i] - x_m[j], y_m[i] - y_m[j])
        pairs = pairs[(d <= d_min) | (d < k * (r[i] + r[j]))]
    if len(pairs) == 0:
        return keep
    # adjacency (CSR) of conflicting pairs; isolated points are kept whatever the order
    both = np.concatenate([pairs, pairs[:, ::-1]])
    both = both[np.argsort(both[:, 0], kind="stable")]
    indptr = np.searchsorted(both[:, 0], np.arange(n + 1))
    nbrs = both[:, 1]
    busy = np.unique(pairs)
    keep[busy] = False
    for i in busy[np.argsort(rank[busy])]:
        if not keep[nbrs[indptr[i]:indptr[i + 1]]].any():
            keep[i] = True
    return keep


def crown_overlap_share(x_m: np.ndarray, y_m: np.ndarray, crown_radius_m: np.ndarray) -> float:
    """Share of trees whose nearest neighbour's trunk stands inside their own crown (d_nn < r_i)."""
    x_m, y_m = np.asarray(x_m, np.float64), np.asarray(y_m, np.float64)
    if len(x_m) < 2:
        return 0.0
    d, _ = cKDTree(np.column_stack([x_m, y_m])).query(np.column_stack([x_m, y_m]), 2)
    return float((d[:, 1] < np.asarray(crown_radius_m, np.float64)).mean())


#: What a species' intensity counts: the Poisson points before the thinning (the paper's
#: reading, seed 004 §III) or the trees of the final stand (C solved after the thinning).
COUNT_MODES = ("poisson", "stand")
#: Default bound of the candidates a "stand" species may draw, in units of its expected
#: Poisson count ∫_D λ: beyond it the crown rule leaves no room and the shortfall is reported.
MAX_CANDIDATE_FACTOR = 20.0
_BATCH = 32    # crown radii asked for at a time (trees grow together in batches)
_BLOCK = 256   # points a stream draws at a time: fixed, so the bytes do not depend on demand


class _Stream:
    """One species' candidates in arrival order: a Poisson process in time t ≥ 0 of rate
    E = ∫_D λ, each point placed i.i.d. with density λ(s)/E on D (Lewis–Shedler rejection
    from λ*). The points with t ≤ 1 are exactly the inhomogeneous Poisson process of
    intensity λ; those with t ≤ T are that of T·λ (C scaled by T). Times and positions come
    from two child generators in fixed blocks, so point i never depends on how many were asked for.
    """

    def __init__(self, species: SpeciesIntensity, d: Domain, rng: np.random.Generator,
                 max_candidates: int) -> None:
        self.s, self.d = species, d
        self.E = float(expected_count(species, d))
        self.lam_max = species.upper_bound(d)
        self.rng_t, self.rng_xy = rng.spawn(2)
        self.max_candidates = max_candidates
        self.t = np.zeros(0)
        self.x = np.zeros(0)
        self.y = np.zeros(0)
        self._px, self._py = np.zeros(0), np.zeros(0)   # accepted positions not yet timed

    def __len__(self) -> int:
        return len(self.t)

    def extend(self) -> None:
        """Draw the next block of points (times and positions)."""
        if len(self.t) + _BLOCK > self.max_candidates:
            raise ConfigError(f"needs more than {self.max_candidates} candidate points; lower "
                              "the intensity or the domain", key=f"{self.s.name}.bumps",
                              value=self.lam_max)
        last = self.t[-1] if len(self.t) else 0.0
        self.t = np.concatenate([self.t, last + np.cumsum(self.rng_t.exponential(1.0 / self.E, _BLOCK))])
        d = self.d
        while len(self._px) < _BLOCK:
            px = self.rng_xy.uniform(d.x_min_m, d.x_max_m, _BLOCK)
            py = self.rng_xy.uniform(d.y_min_m, d.y_max_m, _BLOCK)
            u = self.rng_xy.uniform(0.0, 1.0, _BLOCK)
            # keep with probability λ(s)/λ*; the code published with seed 004 keeps with
            # probability λ(s) itself, which gives intensity λ*·λ(s) instead of λ(s)
            keep = u * self.lam_max < self.s.intensity(px, py)
            self._px = np.concatenate([self._px, px[keep]])
            self._py = np.concatenate([self._py, py[keep]])
        self.x = np.concatenate([self.x, self._px[:_BLOCK]])
        self.y = np.concatenate([self.y, self._py[:_BLOCK]])
        self._px, self._py = self._px[_BLOCK:], self._py[_BLOCK:]

    def time(self, i: int) -> float:
        while i >= len(self.t):
            self.extend()
        return float(self.t[i])


class _Kept:
    """The kept trees on a grid of cells, for the conflict test of one new point."""

    def __init__(self, cell_m: float) -> None:
        self.cell = cell_m
        self.cells: dict[tuple[int, int], list[int]] = {}
        self.x: list[float] = []
        self.y: list[float] = []
        self.r: list[float] = []
        self.r_max = 0.0

    def conflicts(self, x: float, y: float, r: float, d_min: float, k: float) -> bool:
        reach = max(d_min, k * (r + self.r_max))
        if not self.x or reach <= 0:
            return False
        c, m = self.cell, int(math.ceil(reach / self.cell))
        cx, cy = int(math.floor(x / c)), int(math.floor(y / c))
        idx = [j for a in range(cx - m, cx + m + 1) for b in range(cy - m, cy + m + 1)
               for j in self.cells.get((a, b), ())]
        if not idx:
            return False
        # only the neighbours' values: converting the whole kept lists made every test O(trees),
        # the placement O(trees²) (100 ha, 7.7 k trees: most of `generate`; BENCHMARKS §17)
        xs, ys, rs = (np.array([v[j] for j in idx], np.float64) for v in (self.x, self.y, self.r))
        d = np.hypot(xs - x, ys - y)
        return bool(((d <= d_min) | (d < k * (r + rs))).any())

    def add(self, x: float, y: float, r: float) -> None:
        c = self.cell
        self.cells.setdefault((int(math.floor(x / c)), int(math.floor(y / c))), []).append(len(self.x))
        self.x.append(x)
        self.y.append(y)
        self.r.append(r)
        self.r_max = max(self.r_max, r)


@dataclass(frozen=True)
class Placement:
    """Tree positions of all species after the thinning.

    Attributes
    ----------
    x_m, y_m : (n,) float64 positions in metres (species in input order, then arrival order).
    species : (n,) int32 index into ``species_names``.
    species_names : names in input order.
    count_before : (n_species,) candidates (Poisson points) each species drew: its
        Poisson count (mean ∫_D λ) in ``"poisson"`` mode, as many as the stand needed
        in ``"stand"`` mode.
    removed : (n_species,) candidates per species the thinning removed.
    lambda_max_per_m2 : (n_species,) the thinning bounds λ* used.
    min_distance_m : the distance rule applied.
    candidate : (n,) int64 arrival index of each tree among its species' candidates:
        with ``species`` the identity its seed is made from.
    crown_radius_m : (n,) the crown radii the crown rule used (zeros without one).
    crown_factor : the ``k`` of the crown rule ``d_ij ≥ k·(r_i + r_j)`` (0: none).
    count_mode : (n_species,) ``"poisson"`` or ``"stand"``: what ∫_D λ counts.
    requested : (n_species,) ∫_D λ, the mean count the scene asks for.
    target : (n_species,) the stand count a ``"stand"`` species aimed at (a draw of
        Poisson(∫_D λ)); −1 for ``"poisson"`` species.
    candidate_factor : (n_species,) T, the multiple of λ the candidates were drawn at
        (the arrival time reached; 1 in ``"poisson"`` mode).
    reached : (n_species,) False where a ``"stand"`` species stopped at the candidate
        bound with fewer trees than its target.
    """

    x_m: np.ndarray
    y_m: np.ndarray
    species: np.ndarray
    species_names: tuple[str, ...]
    count_before: np.ndarray
    removed: np.ndarray
    lambda_max_per_m2: np.ndarray
    min_distance_m: float
    domain: Domain = field(repr=False, default=None)  # type: ignore[assignment]
    candidate: np.ndarray = field(repr=False, default=None)  # type: ignore[assignment]
    crown_radius_m: np.ndarray = field(repr=False, default=None)  # type: ignore[assignment]
    crown_factor: float = 0.0
    count_mode: tuple[str, ...] = ()
    requested: np.ndarray = field(repr=False, default=None)  # type: ignore[assignment]
    target: np.ndarray = field(repr=False, default=None)  # type: ignore[assignment]
    candidate_factor: np.ndarray = field(repr=False, default=None)  # type: ignore[assignment]
    reached: np.ndarray = field(repr=False, default=None)  # type: ignore[assignment]

    def __len__(self) -> int:
        return len(self.x_m)

    @property
    def count_after(self) -> np.ndarray:
        """(n_species,) trees per species that were placed."""
        return self.count_before - self.removed


def _count_modes(count, n: int, crown_factor: float) -> tuple[str, ...]:
    """Per-species count modes; ``None`` → "poisson" (the paper's, the default); ``"auto"`` →
    "stand" with a crown rule, else "poisson"."""
    auto = "stand" if crown_factor > 0 else "poisson"
    if count is None or isinstance(count, str):
        count = [count] * n
    count = list(count)
    if len(count) != n:
        raise ConfigError(f"needs one count mode per species ({n})", key="count", value=count)
    out = []
    for j, c in enumerate(count):
        c = "poisson" if c is None else auto if c == "auto" else c
        if c not in COUNT_MODES:
            raise ConfigError("must be 'auto', 'poisson' or 'stand'", key=f"species[{j}].count", value=c)
        out.append(c)
    return tuple(out)


def place_trees(species: Sequence[SpeciesIntensity], domain: Domain | Sequence[float],
                min_distance_m: float, rng: np.random.Generator, *,
                crown_radius: Callable[[np.ndarray, np.ndarray, int, np.ndarray], np.ndarray] | None = None,
                crown_factor: float = 0.0, count: str | Sequence[str] | None = None,
                max_candidate_factor: float = MAX_CANDIDATE_FACTOR,
                max_candidates: int = 20_000_000) -> Placement:
    """Simulate a forest: one Poisson process per species, thinned in arrival order.

    Every species' candidates arrive as a Poisson process in time (:class:`_Stream`: rate
    ∫_D λ, positions with density ∝ λ). All species' candidates are visited in order of
    arrival time (a uniformly random order, favouring no species) and a candidate is kept
    unless a kept tree ``j`` conflicts with it: ``d_ij ≤ min_distance_m`` or
    ``d_ij < k·(r_i + r_j)`` (``k = crown_factor``, ``r`` the crown radii). This is
    random sequential adsorption: a later candidate never changes an earlier decision.

    What ∫_D λ counts, per species (``count``):

    ``"poisson"`` (the paper's reading, seed 004 §III: C is chosen "to achieve certain
        expected number of trees", then trees that "overlap too much" are thinned)
        the candidates arriving by t = 1: exactly the inhomogeneous Poisson process of
        intensity λ; the thinning then removes some.
    ``"stand"`` (ours)
        the species draws a target N ~ Poisson(∫_D λ) first, then takes candidates until
        N of them are kept: the final stand's count has the Poisson law the scene's λ gives,
        mean ∫_D λ, and its positions follow λ's shape as far as the thinning lets them.
        Stopping at arrival time T is drawing with intensity T·λ: C is solved after the
        thinning, per realisation. If T reaches ``max_candidate_factor`` first (the crowns
        leave no room), the species stops short and ``reached`` is False.

    ``None`` (the default): ``"poisson"``; ``"auto"``: ``"stand"`` when ``crown_factor > 0``,
    else ``"poisson"``.
    With ``min_distance_m = 0`` and ``k = 0`` both modes are the Poisson process.

    Parameters
    ----------
    species : intensities, one per species.
    domain : Domain or ``(x_min_m, x_max_m, y_min_m, y_max_m)``.
    min_distance_m : no two trees (of any species) end up this close or closer; 0 disables.
    rng : random source. One child stream is spawned per species (and the stand targets
        from a first one), so the same seed gives the same placement and appending a
        species does not move the others' candidates.
    crown_radius : ``f(x_m, y_m, j, index) → r_m``, the crown radii of candidates
        ``index`` (arrival indices) of species ``j``, called in batches as candidates are
        needed; with ``crown_factor = k > 0`` kept trees satisfy ``d_ij ≥ k·(r_i + r_j)``.
    crown_factor : k (≥ 0; 0 = the plain minimum distance).
    count : one mode for all species or one per species.
    max_candidate_factor : bound of T for ``"stand"`` species (≥ 1).
    max_candidates : refuse a species that needs more candidates (memory guard).

    Returns
    -------
    Placement

    Examples
    --------
    >>> sp = [SpeciesIntensity("oak", [Bump(0.01, 50, 50, 400, 900)])]
    >>> p = place_trees(sp, (0, 100, 0, 100), 2.0, np.random.default_rng(1))
    >>> int(p.count_after[0]) == len(p)
    True
    """
    d = Domain.of(domain)
    species = list(species)
    for i, s in enumerate(species):
        if not isinstance(s, SpeciesIntensity):
            raise ConfigError("must be a SpeciesIntensity", key=f"species[{i}]", value=s)
    d_min, k = _rules(min_distance_m, crown_factor)
    t_max = real("max_candidate_factor", max_candidate_factor)
    if t_max < 1:
        raise ConfigError("must be >= 1", key="max_candidate_factor", value=max_candidate_factor)
    if not isinstance(rng, np.random.Generator):
        raise ConfigError("must be a numpy.random.Generator", key="rng", value=rng)
    nsp = len(species)
    modes = _count_modes(count, nsp, k)
    target_rng, *species_rngs = rng.spawn(1 + nsp)
    streams = [_Stream(s, d, r, max_candidates) for s, r in zip(species, species_rngs)]
    for s, st in zip(species, streams):
        if st.E > max_candidates:
            raise ConfigError(f"expects {st.E:.3g} trees (more than {max_candidates}); lower the "
                              "intensity or the domain", key=f"{s.name}.bumps", value=st.lam_max)
    # the targets of every species are drawn (one Poisson each), so modes do not move streams
    target = np.array([int(target_rng.poisson(st.E)) if st.E > 0 else 0 for st in streams], np.int64)
    target = np.where(np.array([m == "stand" for m in modes], bool), target, -1)
    stop_t = np.array([1.0 if m == "poisson" else t_max for m in modes])
    radii: list[dict[int, float]] = [{} for _ in range(nsp)]

    def radius(j: int, i: int) -> float:
        """Candidate i's crown radius, asked for with the next candidates of its species that
        no kept tree excludes yet (a batch grows faster; excluded ones are never grown)."""
        if crown_radius is None:
            return 0.0
        if i not in radii[j]:
            st, idx = streams[j], [i]
            m = i + 1
            while len(idx) < _BATCH and m < i + 8 * _BATCH:
                if (st.time(m) > 1.0 and modes[j] == "poisson") or (
                        target[j] >= 0 and len(idx) >= target[j] - kept_n[j]):
                    break
                if m not in radii[j] and not kept.conflicts(float(st.x[m]), float(st.y[m]), 0.0, d_min, k):
                    idx.append(m)
                m += 1
            idx = np.array(idx, np.int64)
            r = np.asarray(crown_radius(st.x[idx], st.y[idx], j, idx), np.float64)
            if r.shape != idx.shape or not (np.isfinite(r).all() and (r >= 0).all()):
                raise ConfigError(f"must be {len(idx)} finite radii ≥ 0", key="crown_radius_m",
                                  value=r.shape)
            radii[j].update(zip(idx.tolist(), r.tolist()))
        return radii[j][i]

    kept = _Kept(max(d_min, 4.0))
    kept_n = np.zeros(nsp, np.int64)
    drawn = np.zeros(nsp, np.int64)
    out_sp: list[int] = []
    out_i: list[int] = []
    out_r: list[float] = []
    active = [j for j in range(nsp) if streams[j].E > 0 and target[j] != 0]
    # the next arrival of each active species; visit them in time order
    nxt = {j: streams[j].time(0) for j in active}
    while nxt:
        j = min(nxt, key=nxt.__getitem__)
        t, i = nxt[j], int(drawn[j])
        if t > stop_t[j]:
            del nxt[j]
            continue
        drawn[j] += 1
        st = streams[j]
        x, y = float(st.x[i]), float(st.y[i])
        # a candidate inside a kept tree's exclusion zone is refused whatever its own crown,
        # so its tree is never grown; otherwise its radius decides
        if not kept.conflicts(x, y, 0.0, d_min, k) and not kept.conflicts(x, y, r := radius(j, i), d_min, k):
            kept.add(x, y, r)
            kept_n[j] += 1
            out_sp.append(j)
            out_i.append(i)
            out_r.append(r)
        if target[j] >= 0 and kept_n[j] >= target[j]:
            del nxt[j]
            continue
        nxt[j] = st.time(i + 1)
    factor = np.array([1.0 if modes[j] == "poisson" else
                       (float(streams[j].t[drawn[j] - 1]) if drawn[j] and kept_n[j] >= target[j]
                        else t_max if target[j] > 0 else 0.0) for j in range(nsp)])
    sp = np.array(out_sp, np.int32)
    ci = np.array(out_i, np.int64)
    order = np.lexsort((ci, sp))   # species in input order, then arrival order
    sp, ci, rr = sp[order], ci[order], np.array(out_r, np.float64)[order]
    xs = np.array([streams[j].x[i] for j, i in zip(sp, ci)], np.float64)
    ys = np.array([streams[j].y[i] for j, i in zip(sp, ci)], np.float64)
    return Placement(
        x_m=xs, y_m=ys, species=sp, species_names=tuple(s.name for s in species),
        count_before=drawn, removed=drawn - kept_n,
        lambda_max_per_m2=np.array([s.upper_bound(d) for s in species], dtype=np.float64),
        min_distance_m=d_min, domain=d, candidate=ci, crown_radius_m=rr, crown_factor=k,
        count_mode=modes, requested=np.array([st.E for st in streams], np.float64), target=target,
        candidate_factor=factor, reached=np.array([target[j] < 0 or kept_n[j] >= target[j]
                                                   for j in range(nsp)], bool))


def candidate_points(species: Sequence[SpeciesIntensity], domain: Domain | Sequence[float],
                     rng: np.random.Generator, counts: Sequence[int]
                     ) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """The first ``counts[j]`` candidates ``(x_m, y_m, arrival time)`` of every species that
    :func:`place_trees` draws from the same ``rng`` (for audits and tests)."""
    d = Domain.of(domain)
    _, *species_rngs = rng.spawn(1 + len(species))
    out = []
    for s, r, n in zip(species, species_rngs, counts):
        st = _Stream(s, d, r, 20_000_000)
        if int(n):
            st.time(int(n) - 1)
        out.append((st.x[:int(n)], st.y[:int(n)], st.t[:int(n)]))
    return out
