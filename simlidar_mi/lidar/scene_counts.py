"""What a scene holds for the sensor, counted where it is, and what the scan saw of it.

Counts: generated plants, the
``[[primitive]]`` tables (meshes with their per-face classes, boxes, cylinders) and the trees an
instanced forest places.

``scan`` and ``measure`` once counted only the generated leaves: a mesh tree whose leaves
``truth`` counts was reported with "0 leaf triangles" and zero areas, and an instanced forest
with the leaves of no tree at all. The areas here follow the truth's closed forms
(:mod:`simlidar_mi.truth.compute`): a triangle's area, a box's six faces, a cylinder's side and
both its ends (a leaf-labelled cylinder's surface is leaf area).

A scan whose beams hit nothing (a static scanner's default profile looks along +x, wherever
the scene lies) or only the ground is warned about (:func:`warn_if_unseen`), with the scene's
bounds and the keys that aim the sensor; so is a scanner placed inside wood
(:func:`warn_scanner_inside_wood`).
"""
from __future__ import annotations

import warnings

import numpy as np

from ..errors import SimlidarWarning
from ..geometry import CLASS_CODES
from ..io.mesh_import import primitive_mesh_data

__all__ = ["primitive_surfaces", "placed_counts", "leaf_triangle_counts", "describe", "generated_line",
           "warn_if_unseen"]


def _tri_area(v: np.ndarray, f: np.ndarray) -> float:
    t = np.asarray(v, float)[np.asarray(f, np.int64)]
    return float(0.5 * np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1).sum())


def primitive_surfaces(primitives, source: str | None = None) -> dict:
    """Leaf and wood surface of the ``[[primitive]]`` tables, m² (one-sided), and the leaf
    triangles of their meshes: ``{"n_leaf_triangles_meshes", "primitive_leaf_area_m2",
    "primitive_wood_area_m2"}``; ground-labelled faces count in neither area."""
    n_leaf, area = 0, {"leaf": 0.0, "wood": 0.0}
    for j, prim in enumerate(primitives):
        p = prim.params
        if prim.kind in ("obj", "ply"):
            m = prim.mesh if prim.mesh is not None else primitive_mesh_data(prim, source, j)
            codes = (np.full(len(m.faces), CLASS_CODES[prim.label], np.uint8) if m.face_class is None
                     else np.asarray(m.face_class))
            for cls in ("leaf", "wood"):
                sel = codes == CLASS_CODES[cls]
                if sel.any():
                    area[cls] += _tri_area(m.vertices, m.faces[sel])
            n_leaf += int(np.count_nonzero(codes == CLASS_CODES["leaf"]))
        elif prim.label in area:
            if prim.kind == "box":
                d = np.asarray(p["max_m"], float) - np.asarray(p["min_m"], float)
                area[prim.label] += float(2 * (d[0] * d[1] + d[1] * d[2] + d[2] * d[0]))
            elif prim.kind == "cylinder":
                r = 0.5 * float(p["diameter_m"])
                length = float(np.linalg.norm(np.subtract(p["p1_m"], p["p0_m"])))
                area[prim.label] += 2 * np.pi * r * length + 2 * np.pi * r * r
    return {"n_leaf_triangles_meshes": n_leaf, "primitive_leaf_area_m2": area["leaf"],
            "primitive_wood_area_m2": area["wood"]}


def placed_counts(instances) -> dict:
    """Branches and leaf triangles an instanced forest places (every tree's prototype counted
    once per tree), and those built (each prototype once); zeros without instances."""
    if instances is None or not len(instances):
        return {"n_instances": 0, "n_branches_placed": 0, "n_leaf_triangles_placed": 0,
                "n_leaf_triangles_prototypes": 0}
    nb = np.array([len(b) for b, _ in instances.prototypes], np.int64)
    nt = np.array([len(lv) for _, lv in instances.prototypes], np.int64)
    idx = np.asarray(instances.proto_index, np.int64)
    return {"n_instances": len(idx), "n_branches_placed": int(nb[idx].sum()), "n_leaf_triangles_placed": int(nt[idx].sum()),
            "n_leaf_triangles_prototypes": int(nt.sum())}


def leaf_triangle_counts(geometry) -> dict:
    """Every leaf triangle the sensor can see: ``n_leaf_triangles`` = the generated ones + the
    leaf faces of mesh primitives + those the instanced trees place, each part beside it."""
    out = {"n_leaf_triangles_generated": int(len(geometry.leaves)),
           **primitive_surfaces(geometry.primitives, geometry.source), **placed_counts(geometry.instances)}
    out["n_leaf_triangles"] = (out["n_leaf_triangles_generated"] + out["n_leaf_triangles_meshes"]
                               + out["n_leaf_triangles_placed"])
    return out


def describe(m: dict) -> str:
    """'1,234 leaf triangles (…)' for a command's summary line, its parts named when not all generated."""
    parts = []
    if m.get("n_leaf_triangles_meshes"):
        parts.append(f"{m['n_leaf_triangles_meshes']:,} in meshes")
    if m.get("n_leaf_triangles_placed"):
        parts.append(f"{m['n_leaf_triangles_placed']:,} placed by {m.get('n_instances', 0):,} instanced trees "
                     f"from {m.get('n_leaf_triangles_prototypes', 0):,} built")
    return f"{m['n_leaf_triangles']:,} leaf triangles" + (f" ({'; '.join(parts)})" if parts else "")


def generated_line(geometry) -> str:
    """The progress line after generation: branches (placed ones included) and every leaf triangle."""
    m = leaf_triangle_counts(geometry)
    return f"generated {len(geometry.branches) + m['n_branches_placed']:,} branches, {describe(m)}"


#: The keys that aim each platform's beams, named when a scan misses the scene.
AIM_KEYS = {"tractor": "scan.x0_m, scan.z0_m (it looks along +x), scan.y_start_m/y_end_m, scan.theta_*",
            "static": "platform.position_m and platform.azimuth_deg (0° looks along +x, 90° along +y), "
                      "platform.elevation_deg"}


def warn_if_unseen(cfg, hits: dict, geometry) -> None:
    """Warn when no beam hit anything, or when beams hit the ground but no plant or primitive
    of a scene that holds some: the sensor looks away from the scene."""
    seen = sum(v for k, v in hits.items() if k != "escape")
    plants = sum(v for k, v in hits.items() if k in ("wood", "leaf"))
    if plants:
        return
    has_plants = bool(len(geometry.branches) or len(geometry.leaves) or geometry.primitives
                      or (geometry.instances is not None and len(geometry.instances)))
    if seen and not has_plants:
        return
    try:
        lo, hi = geometry.bounds_m()
        where = "; the scene's plants and primitives lie in " + ", ".join(
            f"{a} [{lo[i]:.4g}, {hi[i]:.4g}] m" for i, a in enumerate("xyz"))
    except Exception:  # noqa: BLE001  (a scene with no geometry: nothing more to say)
        where = ""
    kind = cfg["platform"]["kind"]
    n = sum(hits.values())
    what = (f"the scan hit nothing: all {n:,} beams escaped" if not seen else
            f"the scan hit no plant or primitive: {hits.get('ground', 0):,} of {n:,} beams hit the ground, "
            "the rest nothing")
    warnings.warn(SimlidarWarning(
        f"{cfg.source or 'scene'}: {what}{where}; aim the sensor ({kind}: "
        f"{AIM_KEYS.get(kind, 'the [platform] keys')})"))


def warn_scanner_inside_wood(geometry, patterns: list) -> int:
    """Warn (SimlidarWarning) when scanner positions lie inside wood: their beams start
    inside a branch and report its inner wall.  Returns the number of such positions."""
    rows = [getattr(p, "row_origin_m", None) for p in patterns]
    rows = [r if r is not None else p.pattern().row_origin_m for r, p in zip(rows, patterns)]
    pts = np.concatenate(rows) if rows else np.zeros((0, 3))
    if not len(pts):
        return 0
    inside, element = geometry.inside_wood(pts)
    n = int(inside.sum())
    if n:
        i = int(np.argmax(inside))
        e = int(element[i])
        what = (f"branch {e} (diameter {geometry.branches.diameter[e]:.4g} m)"
                if e < len(geometry.branches) else f"primitive {e - len(geometry.branches)}")
        warnings.warn(f"{n} of {len(pts)} scanner positions lie inside wood, the first at "
                      f"{np.round(pts[i], 4).tolist()} m in {what}: their beams start inside it and "
                      "report its inner wall; move the scanner (scan.x0_m/z0_m or the platform)",
                      SimlidarWarning, stacklevel=3)
    return n
