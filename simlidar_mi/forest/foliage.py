"""A forest's foliage in numbers: leaf area per tree, crown projections, LAI per species and stand.

Definitions (what ``forest`` prints and ``forest.json`` records):

leaf area
    the one-sided area of a tree's leaf elements (the sum of its rows in the leaf table:
    what the sensors see and the truth scores). For a species whose elements are conifer
    shoots (``shoot_star > 0``) the **needle area** is reported beside it: half the total
    needle area the shoots stand for, ``leaf area / (4·STAR)``
    (:func:`simlidar_mi.plants.foliage.needle_area_factor`; LAI of Chen & Black 1992).
crown projection
    the area of the convex hull, seen from above, of the tree's leaf centres and branch end
    points (a field crown projection is the polygon of measured crown radii).
crown LAI of a species
    its trees' leaf area over the sum of their crown projections; the **domain** LAI is
    its leaf area over the domain's area.
stand LAI
    all leaf area over the domain's area, and over the union of all crown projections
    (rasterised on a ``UNION_CELL_M`` grid).
crown radii by sector
    the distance from the trunk foot to the crown projection's edge along the eight compass
    bearings N, NE, … NW (clockwise from north, +y), as foresters measure crown radii in
    the field (``trees.csv`` ``crown_radius_n_m`` …).
crown base, DBH
    the lowest leaf vertex above the trunk foot; the diameter of the trunk's (order-1)
    segment that crosses 1.3 m above the foot (NaN where the trunk is shorter; the random
    trees' trunks are prisms of one diameter a segment, so this is that segment's).
"""
from __future__ import annotations

import numpy as np

from ..plants.foliage import needle_area_factor
from ..plants.random_tree import RandomTree

__all__ = ["SECTORS", "UNION_CELL_M", "crown_hull", "foliage_summary", "hull_radii_m", "polygon_area_m2",
           "sector_radius_columns", "union_area_m2"]

#: Grid step of the union of crown projections (m): cells whose centre lies in a hull count.
UNION_CELL_M = 0.25


def crown_hull(tree: RandomTree) -> np.ndarray:
    """(k, 2) vertices, counter-clockwise, of the convex hull of the tree's leaf centres and
    branch end points projected on the ground (own frame); (0, 2) for a bare point."""
    from scipy.spatial import ConvexHull, QhullError  # noqa: PLC0415

    pts = np.concatenate([tree.leaf_table.centre_m[:, :2], tree.branches.p0[:, :2],
                          tree.branches.p1[:, :2], np.zeros((1, 2))])
    try:
        h = ConvexHull(pts)
    except QhullError:      # fewer than 3 points off a line: no area
        return np.zeros((0, 2))
    return pts[h.vertices]


#: The compass sectors of the crown radii, clockwise from north (+y).
SECTORS = ("n", "ne", "e", "se", "s", "sw", "w", "nw")


def hull_radii_m(hull: np.ndarray, direction_xy: np.ndarray) -> np.ndarray:
    """Distance from the origin to the edge of a convex polygon holding it ((k, 2) vertices)
    along each unit direction of ``direction_xy`` (m, 2); 0 for a polygon of fewer than 3 points.

    The ray r·u meets edge p → q where r = (p × e) / (u × e) and s = (p × u) / (u × e) lies in
    [0, 1] (e = q − p, × the 2-D cross product); the largest such r ≥ 0 is the edge's."""
    u = np.asarray(direction_xy, np.float64).reshape(-1, 2)
    if len(hull) < 3:
        return np.zeros(len(u))
    p = np.asarray(hull, np.float64)
    e = np.roll(p, -1, axis=0) - p
    cross = lambda a, b: a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]  # noqa: E731
    den = cross(u[:, None, :], e[None, :, :])                           # (m, k)
    with np.errstate(divide="ignore", invalid="ignore"):
        r = cross(p, e)[None, :] / den
        s = cross(p[None, :, :], u[:, None, :]) / den
    ok = (den != 0) & (s >= -1e-12) & (s <= 1 + 1e-12) & (r >= 0)
    return np.where(ok, r, 0.0).max(axis=1)


def sector_radius_columns(hulls, prototype, yaw_deg, scale) -> dict[str, np.ndarray]:
    """``trees.csv``'s crown radii by compass sector: tree i's hull is ``hulls[prototype[i]]`` in
    its own frame, turned by ``yaw_deg[i]`` (counter-clockwise) and scaled by ``scale[i]``."""
    prototype = np.asarray(prototype)
    yaw, scale = np.asarray(yaw_deg, np.float64), np.asarray(scale, np.float64)
    ccw = np.pi / 2 - np.deg2rad(45.0 * np.arange(len(SECTORS)))  # compass bearing → ccw from +x
    out = np.zeros((len(prototype), len(SECTORS)))
    for j in np.unique(prototype):  # one call a hull: its trees' bearings in its own frame at once
        m = prototype == j
        a = ccw[None, :] - np.deg2rad(yaw[m])[:, None]
        own = np.stack([np.cos(a), np.sin(a)], axis=-1).reshape(-1, 2)
        out[m] = scale[m, None] * hull_radii_m(hulls[int(j)], own).reshape(-1, len(SECTORS))
    return {f"crown_radius_{name}_m": out[:, k] for k, name in enumerate(SECTORS)}


def polygon_area_m2(v: np.ndarray) -> float:
    """Shoelace area of a simple polygon's (k, 2) vertices (0 for k < 3)."""
    if len(v) < 3:
        return 0.0
    x, y = v[:, 0], v[:, 1]
    return 0.5 * abs(float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))


def union_area_m2(polygons, cell_m: float = UNION_CELL_M) -> float:
    """Area of the union of convex polygons ((k, 2) vertex arrays, world frame), rasterised:
    the number of grid cells (side ``cell_m``, aligned at 0) whose centre lies inside one."""
    polys = [np.asarray(p, np.float64) for p in polygons if len(p) >= 3]
    if not polys:
        return 0.0
    lo = np.floor(np.min([p.min(0) for p in polys], axis=0) / cell_m).astype(np.int64)
    hi = np.ceil(np.max([p.max(0) for p in polys], axis=0) / cell_m).astype(np.int64)
    grid = np.zeros((hi[1] - lo[1], hi[0] - lo[0]), bool)
    for p in polys:
        a = np.floor(p.min(0) / cell_m).astype(np.int64)
        b = np.ceil(p.max(0) / cell_m).astype(np.int64)
        cx = (np.arange(a[0], b[0]) + 0.5) * cell_m
        cy = (np.arange(a[1], b[1]) + 0.5) * cell_m
        X, Y = np.meshgrid(cx, cy)
        inside = np.ones(X.shape, bool)
        q = np.roll(p, -1, axis=0)
        orient = np.sign(np.sum(p[:, 0] * q[:, 1] - q[:, 0] * p[:, 1])) or 1.0
        for (x0, y0), (x1, y1) in zip(p, q):   # a convex polygon: left of every edge
            inside &= orient * ((x1 - x0) * (Y - y0) - (y1 - y0) * (X - x0)) >= 0
        grid[a[1] - lo[1]:b[1] - lo[1], a[0] - lo[0]:b[0] - lo[0]] |= inside
    return float(grid.sum()) * cell_m * cell_m


def _ratio(a: float, b: float) -> float | None:
    return a / b if b > 0 else None


def foliage_summary(forest) -> dict:
    """Leaf area and LAI per species and for the stand (JSON-ready; see the module docstring).

    ``forest``: a :class:`~simlidar_mi.forest.stand.Forest` (its per-tree ``leaf_area_m2``,
    ``needle_area_m2``, ``crown_projection_m2`` and world crown hulls).
    """
    area = forest.params.domain.area_m2
    per = []
    for j, s in enumerate(forest.params.species):
        m = forest.species == j
        la, na = float(forest.leaf_area_m2[m].sum()), float(forest.needle_area_m2[m].sum())
        cp = float(forest.crown_projection_m2[m].sum())
        rec = {"name": s.name, "n_trees": int(m.sum()), "leaf_area_m2": la,
               "mean_leaf_area_per_tree_m2": la / m.sum() if m.any() else None,
               "crown_projection_m2": cp, "crown_lai": _ratio(la, cp), "domain_lai": la / area}
        if s.tree.shoot_star > 0:
            rec.update({"shoot_star": s.tree.shoot_star,
                        "needle_area_factor": needle_area_factor(s.tree.shoot_star),
                        "needle_area_m2": na, "crown_needle_lai": _ratio(na, cp),
                        "domain_needle_lai": na / area})
        per.append(rec)
    la, na = float(forest.leaf_area_m2.sum()), float(forest.needle_area_m2.sum())
    union = union_area_m2(forest.crown_hulls_world())
    return {"leaf_area_m2": la, "needle_area_m2": na, "lai": la / area, "needle_lai": na / area,
            "crown_union_m2": union, "crown_union_cell_m": UNION_CELL_M,
            "lai_over_crowns": _ratio(la, union), "species": per,
            "definitions": "one-sided leaf-element area (what the sensors see; the truth's); "
                           "needle area = half the total needle area a conifer shoot element "
                           "stands for, leaf area/(4·STAR); crown projection = convex hull of "
                           "a tree's leaf centres and branch ends seen from above"}


#: Breast height of DBH above the trunk foot, metres (the forestry convention).
BREAST_HEIGHT_M = 1.3


def crown_base_m(tree: RandomTree) -> float:
    """Lowest leaf vertex above the trunk foot (the tree's own frame); NaN without leaves."""
    if not len(tree.leaves):
        return float("nan")
    return float(tree.leaves.vertices[..., 2].min())


def dbh_m(tree: RandomTree, breast_m: float = BREAST_HEIGHT_M) -> float:
    """Diameter of the trunk (order-1 segments) where it crosses z = ``breast_m`` in the tree's
    own frame (the lowest such segment); NaN when the trunk does not reach that height."""
    b = tree.branches
    z0, z1 = b.p0[:, 2], b.p1[:, 2]
    on = (b.order == 1) & (np.minimum(z0, z1) <= breast_m) & (np.maximum(z0, z1) > breast_m)
    if not on.any():
        return float("nan")
    k = np.flatnonzero(on)
    return float(b.diameter[k[np.argmin(np.minimum(z0, z1)[k])]])


def crown_bases_m(forest) -> np.ndarray:
    """(n,) crown base height of each tree of a :class:`~simlidar_mi.forest.stand.Forest` above its
    trunk foot (:func:`crown_base_m`, instance scale applied)."""
    if forest.instancing:  # once a prototype (a 300 m stand: 12 a species, not 30 000 trees)
        per = np.array([crown_base_m(t) for t in forest.prototypes] or [np.nan])
        return per[forest.prototype] * forest.instance_scale
    return np.array([crown_base_m(t) for t in forest.trees]) * forest.instance_scale


def dbhs_m(forest) -> np.ndarray:
    """(n,) DBH of each tree of a forest (:func:`dbh_m` at 1.3 m above the placed trunk's foot)."""
    s = forest.instance_scale
    if forest.instancing and (s == 1).all():
        return np.array([dbh_m(t) for t in forest.prototypes] or [np.nan])[forest.prototype]
    return np.array([dbh_m(forest.local_tree(i), BREAST_HEIGHT_M / s[i]) * s[i] for i in range(len(forest))])
