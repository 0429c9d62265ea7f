"""Vertical-shoot-positioned (VSP) vineyards: trellis, vines, shoots, leaves and clusters.

Frame and layout (all heights above the ground plane z = ``ground_z_m``, [ground] z_m)
------------------------------------------------------------------------------------
Rows run along +y.  Row r's centreline is x_r = ``first_row_x_m`` + r·``row_spacing_m``;
it is L = ``vines_per_row``·``vine_spacing_m`` long, from y₀ = ``y_start_m`` to y₀ + L.
Vine k of row r stands at y₀ + (k + ½)·``vine_spacing_m`` (``tree_id`` = r·vines_per_row + k).

Trellis (``Branches`` rows with ``order`` = 0 and ``tree_id`` = −1, class wood; the
scanner reports no plant for them, 0xFFFFFFFF)
    posts: n_bays = ⌈L / ``post_spacing_m``⌉ equal bays, so n_bays + 1 vertical
    cylinders (end posts included) from z = 0 to ``post_height_m`` at
    y₀ + i·L/n_bays; wires: one cylinder per wire from y₀ to y₀ + L (length L), the
    fruiting wire at (x_r, ``fruiting_wire_height_m``) and one catch-wire pair per height
    in ``catch_wire_heights_m`` at x_r ± ``catch_wire_spacing_m``/2.  When the post
    spacing is a whole number of vine spacings (the default scene's 4 m), posts stand
    where two vines' arms meet, as in the field; arm tips and a bay's outermost shoots
    may then touch a post.

Vine wood (``order`` 1 trunk, 2 cordon, 3 shoot, 4 petiole; class wood)
    The cordon lies on the fruiting wire: its axis is at z_c = fruiting wire height +
    (wire + cordon diameter)/2.  The trunk rises from the ground to ``trunk_height_m``
    (default z_c); two arms (bilateral cordon) run from the trunk's head to
    y_k ± a at z_c, a = (vine_spacing − ``cordon_gap_m``)/2.  Each arm carries
    n_s = round(``shoots_per_m``·a) shoots at its top (z_c + cordon diameter/2 = the
    canopy base z_b), evenly spaced with a ±¼-spacing uniform jitter.

Shoots (VSP: trained upwards between the catch wires, hedged at the top)
    A shoot has ``leaves_per_shoot`` internodes.  Internode i leans θ_i from the vertical,
    |θ_i| half-normal with SD ``shoot_inclination_sd_deg`` (capped at 80°), towards an
    azimuth within ±``shoot_azimuth_spread_deg``/2 of the row direction, +y or −y with
    equal odds (180°: any direction; the default 90° is an assumption, not a measured
    figure: the catch wires hold shoots in the row plane); the internode lengths are equal and set so
    the shoot tip reaches the hedge, z_b + ``canopy_height_m`` − shoot radius.  The
    catch wires then hold every node within the shoot zone: node x is clamped to
    x_r ± (``canopy_width_m`` − shoot diameter)/2.

Leaves (:mod:`simlidar_mi.plants.vine_leaf`): one per node, 8 triangles, blade area
log-normal with mean ``leaf_area_mean_m2`` and SD ``leaf_area_sd_m2`` (capped so a blade
fits the shoot zone).  The defaults are the measured vertically shoot-positioned
("Vertical") vines of W. M. Kliewer & N. K. Dokoozlian, "Leaf area/crop weight ratios of
grapevines: influence on fruit composition and wine quality", Am. J. Enol. Vitic.
56(2):170–181, 2005 (doi:10.5344/ajev.2005.56.2.170), Table 3 (Cabernet Sauvignon,
Oakville, 1993–1995): 14.0 shoots per metre of canopy, 24.0 nodes per shoot, and
2280 cm² of primary leaf area per shoot, so a mean primary leaf of 2280/24 = 95 cm².
Their laterals (28.5 % of the leaf area, 4.72 m² per metre of canopy in all) are not
modelled: the default wall holds the primary leaves, 14 × 0.0095 × 24 = 3.2 m² per
metre of row.  The SD (a 30 % coefficient of variation) is an assumption, not a
measured figure (unverified).  For comparison, the shoot density is close to the
optimum of ~15 shoots/m of R. E. Smart, "Shoot spacing and canopy light microclimate",
Am. J. Enol. Vitic. 39(4):325–333, 1988 (doi:10.5344/ajev.1988.39.4.325), and 95 cm² lies
at the small end of "normally … 100 to 200 cm²" (J. Robinson (ed.), *The Oxford
Companion to Wine*, 3rd ed., 2006, "leaf").  A blade that would cross the shoot zone's box
(|x − x_r| ≤ width/2, z_b ≤ z ≤ z_b + height) is moved (not turned or scaled) back into
it, and its petiole ends at the moved blade: the leaf wall stays within the configured
width and height, like a hedged, positioned canopy.  It reaches the hedge; its width
follows from the shoots and leaves (default scene: 99 % of leaf vertices within ±0.14 m
of the centreline, the widest at ±0.225 m).  In the default scene the confinement moves
11 % of the blades, by 3.9 cm on average: top leaves down under the hedge (8 %), basal
leaves up above the cordon (2 %), hardly any across the row (0.02 %).
``confine_leaves = false`` lets the blades hang freely from their nodes (areas and
orientations are the same draws either way).

The cylinders overlap where they meet: the arms start on the trunk's axis (half their
section inside the trunk's top), petioles start on the shoot's axis, and wires pass
through posts and trunks.  A volume summed over cylinders counts those parts twice:
about 2.9e-5 m³ a vine (arms in the trunk 1.8e-5, petioles in shoots 1.1e-5), 0.8 % of
a default vine's 3.6e-3 m³ of wood.

Clusters (``clusters = true``; off by default) hang leaf-opposed from nodes 3, 4, …
(``clusters_per_shoot`` of them) as vertical cylinder :class:`~simlidar_mi.geometry.Primitive`
shapes labelled 'wood' (``cluster_length_m`` × ``cluster_diameter_m``, a proxy of the
bunch's envelope).  They are neither ``Leaves`` nor ``Branches``: a ground truth built
from leaf triangles and branch cylinders counts them in neither leaf area nor wood,
while the scanner sees them (as non-leaf hits).

Random numbers: vine k of row r draws from ``default_rng(SeedSequence(seed,
spawn_key=(r, k)))``, so a vine does not change when rows or vines are added.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from ..config.checks import flag, real
from ..errors import ConfigError
from ..geometry import Branches, Leaves, Primitive
from .tree_leaves import LeafTable
from .vine_leaf import OUTLINE_AREA_FACTOR, blades, leaf_records, lognormal_areas

__all__ = ["VineyardParams", "Vineyard", "vineyard", "ORDER_TRELLIS", "ORDER_TRUNK", "ORDER_CORDON",
           "ORDER_SHOOT", "ORDER_PETIOLE", "TRELLIS_TREE_ID",
           "vineyard_from_config", "vineyard_params", "trellis_mask"]

ORDER_TRELLIS, ORDER_TRUNK, ORDER_CORDON, ORDER_SHOOT, ORDER_PETIOLE = 0, 1, 2, 3, 4
#: tree_id of posts and wires (no plant).
TRELLIS_TREE_ID = -1
#: Largest vineyard generated by default: cylinders + leaf triangles (+ clusters), about 2 GB.
MAX_ELEMENTS = 20_000_000
#: Triangles of one blade (plants/vine_leaf.py).
TRIANGLES_PER_LEAF = 8
#: [vineyard.canopy] keys; every other field is a [vineyard] key.
CANOPY_KEYS = ("canopy_height_m", "canopy_width_m", "shoots_per_m", "leaves_per_shoot", "shoot_diameter_m",
               "shoot_inclination_sd_deg", "shoot_azimuth_spread_deg", "leaf_area_mean_m2", "leaf_area_sd_m2",
               "leaf_inclination_mean_deg", "leaf_inclination_sd_deg", "leaf_azimuth_sd_deg",
               "leaf_roll_sd_deg", "petiole_length_ratio", "petiole_diameter_m", "petiole_elevation_deg",
               "confine_leaves", "clusters", "clusters_per_shoot", "cluster_length_m", "cluster_diameter_m")


#: Largest accepted value of the angle keys (as [vineyard.canopy] checks them).
_ANGLE_MAX_DEG = {"shoot_inclination_sd_deg": 60.0, "shoot_azimuth_spread_deg": 180.0,
                  "leaf_inclination_mean_deg": 90.0, "leaf_inclination_sd_deg": 90.0,
                  "leaf_azimuth_sd_deg": 180.0, "leaf_roll_sd_deg": 180.0, "petiole_elevation_deg": 90.0}


def _key(name: str) -> str:
    return f"vineyard.canopy.{name}" if name in CANOPY_KEYS else f"vineyard.{name}"


@dataclass(frozen=True)
class VineyardParams:
    """Every [vineyard] and [vineyard.canopy] key (module docstring); checked on creation."""

    n_rows: int = 1
    row_spacing_m: float = 2.2
    first_row_x_m: float = 0.0
    y_start_m: float = 0.0
    vines_per_row: int = 12
    vine_spacing_m: float = 1.0
    post_spacing_m: float = 5.0
    post_height_m: float = 2.1
    post_diameter_m: float = 0.08
    wire_diameter_m: float = 0.0025
    fruiting_wire_height_m: float = 0.9
    catch_wire_heights_m: tuple = (1.25, 1.6, 1.95)
    catch_wire_spacing_m: float = 0.3
    trunk_height_m: float | None = None
    trunk_diameter_m: float = 0.05
    cordon_diameter_m: float = 0.03
    cordon_gap_m: float = 0.06
    canopy_height_m: float = 1.1
    canopy_width_m: float = 0.45
    shoots_per_m: float = 14.0
    leaves_per_shoot: int = 24
    shoot_diameter_m: float = 0.009
    shoot_inclination_sd_deg: float = 12.0
    shoot_azimuth_spread_deg: float = 90.0
    leaf_area_mean_m2: float = 0.0095
    leaf_area_sd_m2: float = 0.00285
    leaf_inclination_mean_deg: float = 60.0
    leaf_inclination_sd_deg: float = 15.0
    leaf_azimuth_sd_deg: float = 30.0
    leaf_roll_sd_deg: float = 20.0
    petiole_length_ratio: float = 0.7
    petiole_diameter_m: float = 0.003
    petiole_elevation_deg: float = 30.0
    confine_leaves: bool = True
    clusters: bool = False
    clusters_per_shoot: int = 2
    cluster_length_m: float = 0.15
    cluster_diameter_m: float = 0.08

    def __post_init__(self) -> None:
        ints = {"n_rows": 1, "vines_per_row": 1, "leaves_per_shoot": 1, "clusters_per_shoot": 0}
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if f.name in ints:
                if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < ints[f.name]:
                    raise ConfigError(f"must be a whole number ≥ {ints[f.name]}", key=_key(f.name), value=v)
            elif f.name in ("clusters", "confine_leaves"):
                flag(_key(f.name), v)
            elif f.name == "catch_wire_heights_m":
                hs = [real(_key(f.name), h, positive=True) for h in v]
                if hs != sorted(set(hs)):
                    raise ConfigError("must be increasing heights", key=_key(f.name), value=list(v))
                object.__setattr__(self, f.name, tuple(hs))
            elif f.name == "trunk_height_m" and v is None:
                continue
            elif f.name in ("first_row_x_m", "y_start_m", "petiole_elevation_deg"):
                real(_key(f.name), v)
            elif f.name in ("cordon_gap_m", "leaf_area_sd_m2") or f.name.endswith("_deg"):
                real(_key(f.name), v, nonneg=True)
            else:
                real(_key(f.name), v, positive=True)
        self._check_rules()

    def _check_rules(self) -> None:
        def bad(name, why):
            v = getattr(self, name)
            raise ConfigError(why, key=_key(name), value=list(v) if isinstance(v, tuple) else v)
        if self.fruiting_wire_height_m >= self.post_height_m:
            bad("fruiting_wire_height_m", f"must be below the post top, post_height_m = {self.post_height_m:g}")
        for h in self.catch_wire_heights_m:
            if not self.fruiting_wire_height_m < h <= self.post_height_m:
                bad("catch_wire_heights_m", "each must lie above fruiting_wire_height_m and at most "
                    f"post_height_m ({self.fruiting_wire_height_m:g} < h ≤ {self.post_height_m:g})")
        if self.catch_wire_spacing_m > self.canopy_width_m:
            bad("catch_wire_spacing_m", f"must be at most canopy_width_m = {self.canopy_width_m:g}")
        if self.shoot_diameter_m >= self.canopy_width_m:
            bad("shoot_diameter_m", f"must be below canopy_width_m = {self.canopy_width_m:g}")
        if self.cordon_gap_m >= self.vine_spacing_m:
            bad("cordon_gap_m", f"must be below vine_spacing_m = {self.vine_spacing_m:g}")
        if self.trunk_height_m is not None and self.trunk_height_m > self.cordon_z_m + 1e-12:
            bad("trunk_height_m", f"must be at most the cordon's axis height {self.cordon_z_m:g} m")
        if self.row_length_m / (self.n_posts_per_row - 1) <= self.post_diameter_m:
            bad("post_spacing_m", f"puts posts {self.row_length_m / (self.n_posts_per_row - 1):.3g} m apart, "
                f"within post_diameter_m = {self.post_diameter_m:g} of each other (they would overlap)")
        if self.row_spacing_m <= self.canopy_width_m and self.n_rows > 1:
            bad("row_spacing_m", f"must exceed canopy_width_m = {self.canopy_width_m:g} (rows would touch)")
        if self.leaf_area_mean_m2 > self.leaf_area_max_m2:
            bad("leaf_area_mean_m2", f"a blade this large does not fit the shoot zone (at most "
                f"{self.leaf_area_max_m2:.4g} m² for canopy width {self.canopy_width_m:g} m and height "
                f"{self.canopy_height_m:g} m)")
        for name, hi in _ANGLE_MAX_DEG.items():
            if abs(getattr(self, name)) > hi:
                bad(name, f"must lie in [{0 if name != 'petiole_elevation_deg' else -hi}, {hi}] degrees")

    # --- derived quantities (module docstring) ---------------------------------------
    @property
    def row_length_m(self) -> float:
        return self.vines_per_row * self.vine_spacing_m

    @property
    def n_posts_per_row(self) -> int:
        return int(math.ceil(self.row_length_m / self.post_spacing_m - 1e-9)) + 1

    @property
    def cordon_z_m(self) -> float:
        return self.fruiting_wire_height_m + 0.5 * (self.wire_diameter_m + self.cordon_diameter_m)

    @property
    def canopy_base_z_m(self) -> float:
        return self.cordon_z_m + 0.5 * self.cordon_diameter_m

    @property
    def canopy_top_z_m(self) -> float:
        return self.canopy_base_z_m + self.canopy_height_m

    @property
    def arm_length_m(self) -> float:
        return 0.5 * (self.vine_spacing_m - self.cordon_gap_m)

    @property
    def shoots_per_arm(self) -> int:
        return int(round(self.shoots_per_m * self.arm_length_m))

    @property
    def leaf_area_max_m2(self) -> float:
        """Largest blade that fits the shoot zone in any orientation (every outline point
        lies within one midrib length L of the petiole junction: 2L ≤ min(width, height))."""
        return OUTLINE_AREA_FACTOR * (0.5 * min(self.canopy_width_m, self.canopy_height_m)) ** 2

    def n_elements(self) -> dict[str, int]:
        """What :func:`vineyard` makes, counted from the keys (nothing generated): cylinders
        (trellis, trunks, arms, shoot internodes, petioles), leaf triangles and clusters."""
        vines = self.n_rows * self.vines_per_row
        nodes = 2 * self.shoots_per_arm * self.leaves_per_shoot  # a vine's leaves
        clusters = (2 * self.shoots_per_arm * max(0, min(self.leaves_per_shoot - 2, self.clusters_per_shoot))
                    if self.clusters else 0)
        return {"trellis": self.n_rows * (self.n_posts_per_row + 1 + 2 * len(self.catch_wire_heights_m)),
                "wood": vines * (3 + 2 * nodes), "leaf_triangles": vines * nodes * TRIANGLES_PER_LEAF,
                "clusters": vines * clusters}

    def check_size(self, max_elements: int = MAX_ELEMENTS, source=None) -> int:
        """The element count (:meth:`n_elements`), or a ConfigError naming the key that grew it
        most over its default when it exceeds ``max_elements``."""
        counts = self.n_elements()
        total = sum(counts.values())
        if total <= max_elements:
            return total
        base = VineyardParams()
        growth = {k: getattr(self, k) / getattr(base, k) for k in
                  ("n_rows", "vines_per_row", "shoots_per_m", "leaves_per_shoot")}
        growth["post_spacing_m"] = base.post_spacing_m / self.post_spacing_m
        growth["vine_spacing_m"] = self.vine_spacing_m / base.vine_spacing_m
        name = max(growth, key=growth.get)
        raise ConfigError(f"{total:.3g} cylinders and leaf triangles ({', '.join(f'{v:.3g} {k}' for k, v in counts.items())}) "
                          f"exceed vineyard.max_elements = {max_elements}; change this key or raise max_elements",
                          file=source, key=_key(name), value=getattr(self, name))

    def row_x_m(self, r: int) -> float:
        return self.first_row_x_m + r * self.row_spacing_m

    def vine_y_m(self, k: int) -> float:
        return self.y_start_m + (k + 0.5) * self.vine_spacing_m


@dataclass(frozen=True)
class Vineyard:
    """A generated vineyard: wood (trellis and vines), leaf triangles, the per-leaf table and
    the cluster primitives (empty unless ``clusters``)."""

    branches: Branches
    leaves: Leaves
    leaf_table: LeafTable
    clusters: list


def _cyl(p0, p1, d, order, tid) -> Branches:
    p0, p1 = np.atleast_2d(np.asarray(p0, float)), np.atleast_2d(np.asarray(p1, float))
    n = len(p0)
    return Branches(p0, p1, np.broadcast_to(np.asarray(d, float), (n,)).copy(),
                    np.full(n, order, np.int32), np.broadcast_to(np.asarray(tid, np.int32), (n,)).copy())


def trellis(P: VineyardParams, r: int, terrain=None) -> Branches:
    """Posts and wires of row r (``order`` 0, ``tree_id`` −1).  On a ``terrain``
    (:class:`~simlidar_mi.io.terrain.Terrain`) each post stands at the terrain height under it
    and each wire runs post to post, one cylinder a bay, at its height above each post's foot."""
    x, y0, L = P.row_x_m(r), P.y_start_m, P.row_length_m
    yp = y0 + L * np.arange(P.n_posts_per_row) / (P.n_posts_per_row - 1)
    zp = np.zeros_like(yp) if terrain is None else terrain.height_m(np.full_like(yp, x), yp)
    posts = _cyl(np.column_stack([np.full_like(yp, x), yp, zp]),
                 np.column_stack([np.full_like(yp, x), yp, zp + P.post_height_m]),
                 P.post_diameter_m, ORDER_TRELLIS, TRELLIS_TREE_ID)
    wires = [(x, P.fruiting_wire_height_m)]
    half = 0.5 * P.catch_wire_spacing_m
    wires += [(x + sx, h) for h in P.catch_wire_heights_m for sx in (-half, half)]
    w = np.array(wires)
    if terrain is None:
        wire = _cyl(np.column_stack([w[:, 0], np.full(len(w), y0), w[:, 1]]),
                    np.column_stack([w[:, 0], np.full(len(w), y0 + L), w[:, 1]]),
                    P.wire_diameter_m, ORDER_TRELLIS, TRELLIS_TREE_ID)
    else:  # wire by wire, bay by bay
        wire = _cyl(np.concatenate([np.column_stack([np.full(len(yp) - 1, wx), yp[:-1], zp[:-1] + h]) for wx, h in w]),
                    np.concatenate([np.column_stack([np.full(len(yp) - 1, wx), yp[1:], zp[1:] + h]) for wx, h in w]),
                    P.wire_diameter_m, ORDER_TRELLIS, TRELLIS_TREE_ID)
    return Branches.concat([posts, wire])


def _fit(lo_v: np.ndarray, hi_v: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """Shift that moves [lo_v, hi_v] into [lo, hi] (none when it already fits)."""
    return np.maximum(lo - lo_v, 0.0) - np.maximum(hi_v - hi, 0.0)


def vine(P: VineyardParams, r: int, k: int, seed: int) -> tuple[Branches, Leaves, LeafTable, list]:
    """One vine (module docstring): wood, leaves, leaf table and cluster primitives."""
    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(r, k)))
    tid = r * P.vines_per_row + k
    x, y = P.row_x_m(r), P.vine_y_m(k)
    zc, zb, zt = P.cordon_z_m, P.canopy_base_z_m, P.canopy_top_z_m
    head = np.array([x, y, zc if P.trunk_height_m is None else P.trunk_height_m])
    a = P.arm_length_m
    ends = np.array([[x, y - a, zc], [x, y + a, zc]])
    wood = [_cyl([x, y, 0.0], head, P.trunk_diameter_m, ORDER_TRUNK, tid),
            _cyl(np.stack([head, head]), ends, P.cordon_diameter_m, ORDER_CORDON, tid)]
    ns = P.shoots_per_arm
    if ns == 0:
        return Branches.concat(wood), Leaves.empty(), LeafTable.empty(), []
    # Shoot bases on the arms' tops: evenly spaced, jittered by ±¼ spacing.
    t = (np.arange(ns) + 0.5 + rng.uniform(-0.25, 0.25, (2, ns))) / ns          # (2 arms, ns)
    sign = np.array([-1.0, 1.0])[:, None]
    by = (y + sign * t * a).ravel()
    n_sh, n_in = 2 * ns, P.leaves_per_shoot
    # A straight arm from head to end: its axis height at the base (sloped when the head is low).
    bz = (head[2] + t * (zc - head[2])).ravel() + 0.5 * P.cordon_diameter_m
    base = np.column_stack([np.full(n_sh, x), by, bz])
    th = np.abs(rng.normal(0.0, math.radians(P.shoot_inclination_sd_deg), (n_sh, n_in)))
    th = np.minimum(th, math.radians(80.0))  # trained upwards: never below 10° from horizontal
    # lean along the row, either way (±y), within ±spread/2 (the catch wires hold shoots in the row plane)
    ph = (0.5 * np.pi + np.pi * rng.integers(0, 2, (n_sh, n_in))
          + np.deg2rad(rng.uniform(-0.5, 0.5, (n_sh, n_in)) * P.shoot_azimuth_spread_deg))
    d = np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], axis=2)
    rise = zt - 0.5 * P.shoot_diameter_m - bz                                   # tip at the hedge
    seg = rise / d[..., 2].sum(1)
    nodes = base[:, None, :] + np.cumsum(d * seg[:, None, None], axis=1)        # (n_sh, n_in, 3)
    lim = 0.5 * (P.canopy_width_m - P.shoot_diameter_m)
    nodes[..., 0] = np.clip(nodes[..., 0], x - lim, x + lim)                    # the catch wires
    pts = np.concatenate([base[:, None, :], nodes], axis=1)
    wood.append(_cyl(pts[:, :-1].reshape(-1, 3), pts[:, 1:].reshape(-1, 3), P.shoot_diameter_m,
                     ORDER_SHOOT, tid))
    # Leaves: one per node, distichous (alternate sides) about a random plane per shoot.
    nl = n_sh * n_in
    node = nodes.reshape(-1, 3)
    psi = (rng.uniform(0, 2 * np.pi, n_sh)[:, None] + np.pi * (np.arange(n_in) % 2)[None, :]).ravel()
    psi = psi + rng.normal(0.0, math.radians(P.leaf_azimuth_sd_deg), nl)
    area = lognormal_areas(rng, nl, P.leaf_area_mean_m2, P.leaf_area_sd_m2, P.leaf_area_max_m2)
    length = np.sqrt(area / OUTLINE_AREA_FACTOR)
    incl = np.clip(rng.normal(math.radians(P.leaf_inclination_mean_deg),
                              math.radians(P.leaf_inclination_sd_deg), nl), 0.0, 0.5 * np.pi)
    roll = rng.normal(0.0, math.radians(P.leaf_roll_sd_deg), nl)
    el = math.radians(P.petiole_elevation_deg)
    pdir = np.column_stack([math.cos(el) * np.cos(psi), math.cos(el) * np.sin(psi), np.full(nl, math.sin(el))])
    tri, normal, heading = blades(node + (P.petiole_length_ratio * length)[:, None] * pdir, psi, incl, roll, length)
    # Hedged and positioned: move blades that leave the shoot zone back into it.
    v = tri.reshape(nl, -1, 3)
    hw = 0.5 * P.canopy_width_m
    shift = np.zeros((nl, 3))
    shift[:, 0] = _fit(v[..., 0].min(1), v[..., 0].max(1), x - hw, x + hw)
    shift[:, 2] = _fit(v[..., 2].min(1), v[..., 2].max(1), zb, zt)
    if P.confine_leaves:
        tri = tri + shift[:, None, None, :]
    wood.append(_cyl(node, tri[:, 0, 0], P.petiole_diameter_m, ORDER_PETIOLE, tid))
    leaves, table = leaf_records(tri, normal, heading, length, np.full(nl, tid), np.arange(nl))
    return Branches.concat(wood), leaves, table, _clusters(P, node, psi, n_sh, n_in)


def _clusters(P: VineyardParams, node: np.ndarray, psi: np.ndarray, n_sh: int, n_in: int) -> list:
    """Leaf-opposed cylinder primitives hanging from nodes 3, 4, … of every shoot."""
    if not P.clusters or P.clusters_per_shoot == 0:
        return []
    idx = np.arange(2, min(n_in, 2 + P.clusters_per_shoot))
    rows = (np.arange(n_sh)[:, None] * n_in + idx[None, :]).ravel()
    out = -np.column_stack([np.cos(psi[rows]), np.sin(psi[rows]), np.zeros(len(rows))])
    top = node[rows] + 0.5 * (P.shoot_diameter_m + P.cluster_diameter_m) * out
    bottom = top - [0.0, 0.0, P.cluster_length_m]
    return [Primitive("cylinder", {"p0_m": [float(c) for c in p0], "p1_m": [float(c) for c in p1],
                                   "diameter_m": P.cluster_diameter_m}, "wood")
            for p0, p1 in zip(top, bottom)]


def vineyard(params: VineyardParams, seed: int = 0, ground_z_m: float = 0.0,
             max_elements: int = MAX_ELEMENTS, terrain=None) -> Vineyard:
    """All rows: trellis of each row, then its vines in order (module docstring), standing
    on the ground plane z = ``ground_z_m`` (built at z = 0 and moved, so heights never
    depend on it), or on a ``terrain`` (:class:`~simlidar_mi.io.terrain.Terrain`; then
    ``ground_z_m`` is not used): each vine raised whole by the terrain height under its
    trunk, posts and wires as :func:`trellis` places them.  More than ``max_elements``
    cylinders and triangles is refused first."""
    params.check_size(max_elements)
    seed = int(seed)
    wood, leaves, tables, clusters = [], [], [], []
    for r in range(params.n_rows):
        wood.append(trellis(params, r, terrain))
        for k in range(params.vines_per_row):
            v = Vineyard(*vine(params, r, k, seed))
            if terrain is not None:
                v = _raised(v, float(terrain.height_m(params.row_x_m(r), params.vine_y_m(k))))
            wood.append(v.branches)
            leaves.append(v.leaves)
            tables.append(v.leaf_table)
            clusters += v.clusters
    out = Vineyard(Branches.concat(wood), Leaves.concat(leaves), LeafTable.concat(tables), clusters)
    return out if ground_z_m == 0 or terrain is not None else _raised(out, float(ground_z_m))


def _raised(v: Vineyard, dz: float) -> Vineyard:
    off = np.array([0.0, 0.0, dz])
    lv = Leaves(v.leaves.vertices + off, v.leaves.leaf_id, v.leaves.plant_id)
    cl = [Primitive(c.kind, {**c.params, "p0_m": [c.params["p0_m"][0], c.params["p0_m"][1], c.params["p0_m"][2] + dz],
                             "p1_m": [c.params["p1_m"][0], c.params["p1_m"][1], c.params["p1_m"][2] + dz]}, c.label)
          for c in v.clusters]
    return Vineyard(v.branches.translated(off), lv, v.leaf_table.placed(off), cl)


def vineyard_params(cfg) -> tuple[VineyardParams, int]:
    """(params, max_elements) of a scene's [vineyard] and [vineyard.canopy], its size checked
    from the keys (nothing generated); a ConfigError names the file or ``--set`` argument."""
    keys = {**cfg["vineyard"], **cfg["vineyard.canopy"]}
    keys["catch_wire_heights_m"] = tuple(keys["catch_wire_heights_m"])
    limit = keys.pop("max_elements")
    try:
        params = VineyardParams(**keys)
        params.check_size(limit)
    except ConfigError as exc:
        raise cfg.relabel(ConfigError(exc.reason, file=cfg.source, key=exc.key, value=exc.value)) from None
    return params, limit


def vineyard_from_config(cfg, terrain=None) -> Vineyard:
    """The vineyard of a scene's [vineyard] and [vineyard.canopy] (a ConfigError names the
    file), on ``terrain`` when given (the scene's ``[terrain]``)."""
    params, limit = vineyard_params(cfg)
    if terrain is not None:  # every post and vine must stand on it
        from ..io.terrain import check_inside  # noqa: PLC0415
        xs = [params.row_x_m(r) for r in range(params.n_rows)]
        ys = [params.y_start_m, params.y_start_m + params.row_length_m]
        check_inside(terrain, np.repeat(xs, 2), np.tile(ys, len(xs)), "vineyard rows", cfg.source)
    return vineyard(params, cfg.seed, cfg["ground"]["z_m"], limit, terrain)


def trellis_mask(branches: Branches) -> np.ndarray:
    """Rows of ``branches`` that are posts or wires (order 0), for a truth that separates them."""
    return np.asarray(branches.order) == ORDER_TRELLIS
