"""Geometry → Mitsuba shapes.  The only module that knows about facets, curves and the origin.

Branch representations (see BENCHMARKS.md for what each costs and how exact it is):

``mesh``
    One merged triangle mesh, every branch a k-facet prism, with k-gon caps on the
    ends that beams can meet (tips, bases, steps down in diameter; see exposed_ends).
    The radius is scaled by π/(k·sin(π/k)) so the mean projected width over view
    azimuths equals the cylinder's (a k-prism's mean width is k·sin(π/k)/π of it).
``cylinder``
    Mitsuba's analytic ``cylinder`` (one shape per branch; open, so the ends are
    closed by one extra mesh of 32-gon caps).  Solved in float32 in a radius-scaled
    frame: inexact for thin branches far away.
``linearcurve``
    One ``linearcurve`` shape, each branch a 2-point segment; rounded ends.

All coordinates are taken relative to a float64 scene origin before they become
float32, so a scene 1e6 m from the origin scans like one at the origin.  The default
origin is the centre of the bounding box of every shape (branches, leaves, primitives,
instances) and of the scanner path, rounded to metres; when the float32 spacing at the
scene's extent from the origin exceeds :data:`FLOAT32_FEATURE_SHARE` of its smallest
feature, a :class:`~simlidar_mi.errors.SimlidarWarning` says so.  Zero-length segments
are dropped (they would make the scene bounding box NaN) and counted.
"""
from __future__ import annotations

import logging
import os
import stat
import tempfile
import warnings
from dataclasses import dataclass, field

import numpy as np

from .._runtime.mitsuba import mitsuba
from ..errors import ConfigError, SimlidarWarning
from ..geometry import CLASS_CODES, NO_ID, Branches, Leaves, Primitive
from ..io.mesh_import import primitive_mesh_data
from .prisms import exposed_ends, prism_arrays, prism_mesh

log = logging.getLogger(__name__)

REPRESENTATIONS = ("mesh", "cylinder", "linearcurve")
CAP_SIDES = 32
MIN_LENGTH_M = 1e-9
# Warn when float32 rounding at the scene's extent exceeds this share of its smallest feature.
FLOAT32_FEATURE_SHARE = 0.01
# Flat wood/leaf meshes of at least this many triangles go into one shape group placed by an
# identity instance: Embree then builds them with its instance-level quality, 2.5x faster on
# the Table 3 orchard (2.4 M triangles) with the same coherent and incoherent trace speed
# (BENCHMARKS.md); below it the top-level build is already fast.
GROUP_MIN_TRIANGLES = 200_000


@dataclass(frozen=True)
class Instances:
    """Identical geometry built once and placed many times (forests).

    ``prototypes[p]`` is (Branches, Leaves) in the prototype's own frame (tree base at
    the origin); tree t places prototype ``proto_index[t]`` scaled by ``scale[t]``,
    turned by ``yaw_deg[t]`` about z and moved to ``translation_m[t]`` (float64, real).
    """

    prototypes: list
    proto_index: np.ndarray
    translation_m: np.ndarray
    yaw_deg: np.ndarray
    scale: np.ndarray
    tree_id: np.ndarray

    def __len__(self) -> int:
        return len(self.proto_index)


@dataclass
class BuiltScene:
    """A Mitsuba scene plus the tables that map hits back to our elements.

    Element ids: wood hits report the branch's row in ``branches``; explicit
    primitives report ``len(branches) + j``; leaf hits report the leaf id.  Hits on
    instances report the row or leaf id within their prototype, and the tree id through
    ``instance_tree`` (indexed by the instance's registry id).
    """

    scene: object
    origin_m: np.ndarray
    shape_class: np.ndarray
    shape_base: np.ndarray
    prim_element: np.ndarray
    n_branches: int
    n_dropped: int
    n_triangles: int
    representation: str
    facets: int
    bbox_min_m: np.ndarray = field(default_factory=lambda: np.zeros(3))
    bbox_max_m: np.ndarray = field(default_factory=lambda: np.zeros(3))
    # Instancing: per instance registry id, its tree id and prototype; per (prototype,
    # shape index in the group), class and offset into prim_element.
    instance_tree: np.ndarray | None = None
    instance_proto: np.ndarray | None = None
    group_class: np.ndarray | None = None
    group_base: np.ndarray | None = None
    n_instances: int = 0
    prim_tree: np.ndarray | None = None  # tree id per primitive (several plants, no instancing)
    # Per shape registry id, a shape's own reflectance ([[primitive]] reflectance); −1: its class's.
    shape_reflectance: np.ndarray | None = None
    # Per instance registry id, its yaw (rad): turns prototype-frame normals into the scene's.
    instance_yaw_rad: np.ndarray | None = None
    # The shape holding each part of prim_element, in its order (meshes, or None for analytic
    # shapes): the source of prim_normals(), computed only when a sensor needs incidence.
    prim_shapes: list = field(default_factory=list, repr=False)
    # The terrain's top-level mesh, its registry id and cell (the range integrator's set_terrain).
    terrain_mesh: object = field(default=None, repr=False)
    terrain_shape_id: int | None = None
    terrain_cell_m: float | None = None

    def prim_normals(self) -> np.ndarray | None:
        """Unit geometric normal of every primitive, laid out like ``prim_element`` (float32
        (n, 3), in each shape's own frame: prototypes' in the prototype's), or None when a
        part is not a triangle mesh (analytic cylinders, curves).

        Read back from the built meshes (float32 vertices, as Embree sees them); a table
        lookup at a hit replaces Mitsuba's surface interaction, whose per-shape dispatch
        compiles one function per instance (minutes for a forest of a thousand trees)."""
        if not self.prim_shapes or any(m is None for m in self.prim_shapes):
            return None
        import drjit as dr  # noqa: PLC0415  (the variant is set: the scene exists)
        import mitsuba as mi  # noqa: PLC0415
        parts = []
        for mesh in self.prim_shapes:
            # One Dr.Jit kernel a mesh (2.4 M triangles: ~0.05 s against numpy's ~0.7 s): the
            # float64 cross product and norm of numpy's np.cross / np.linalg.norm, operation by
            # operation (Dr.Jit contracts no a·b − c·d into an fma), so the same float32 bits
            params = mi.traverse(mesh)
            v, f = params["vertex_positions"], params["faces"]
            idx = dr.arange(mi.UInt32, dr.width(f) // 3) * 3
            corner = []
            for k in range(3):
                vi = dr.gather(mi.UInt32, f, idx + k) * 3
                corner.append([mi.Float64(dr.gather(mi.Float, v, vi + j)) for j in range(3)])
            a = [corner[1][j] - corner[0][j] for j in range(3)]
            b = [corner[2][j] - corner[0][j] for j in range(3)]
            n = [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
            norm = dr.sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2])
            unit = [mi.Float(dr.select(norm > 0, c / norm, 0.0)) for c in n]
            dr.eval(unit)
            parts.append(np.stack([c.numpy() for c in unit], axis=1))
        return np.concatenate(parts) if parts else np.zeros((1, 3), np.float32)

    def integrator_tables(self) -> dict:
        """Keyword arguments for the range integrator's ``set_tables``."""
        tables = {"shape_class": self.shape_class, "shape_base": self.shape_base,
                  "prim_element": self.prim_element}
        if self.instance_proto is not None:  # placed trees and/or the flat meshes' group
            tables.update(instance_tree=self.instance_tree if self.n_instances else None,
                          instance_proto=self.instance_proto,
                          group_class=self.group_class, group_base=self.group_base)
        if self.prim_tree is not None:
            tables["prim_tree"] = self.prim_tree
        return tables


def _mi_mesh(mi, name: str, vertices: np.ndarray, faces: np.ndarray):
    mesh = mi.Mesh(name, len(vertices), len(faces))
    params = mi.traverse(mesh)
    params["vertex_positions"] = mi.Float(np.ascontiguousarray(vertices, np.float32).ravel())
    params["faces"] = mi.UInt32(np.ascontiguousarray(faces, np.uint32).ravel())
    params.update()
    return mesh


def clean_branches(branches: Branches) -> tuple[Branches, int, np.ndarray]:
    """Validate branches; drop zero-length ones.  Returns (kept, n_dropped, kept_index)."""
    if len(branches) == 0:
        return branches, 0, np.zeros(0, np.int64)
    for name in ("p0", "p1", "diameter"):
        a = getattr(branches, name)
        bad = ~np.isfinite(a)
        if bad.any():
            row = int(np.argwhere(bad)[0][0])
            raise ConfigError("branch coordinates and diameters must be finite numbers",
                              key=f"branches.{name}[{row}]", value=a[row].tolist())
    if (branches.diameter <= 0).any():
        row = int(np.argmax(branches.diameter <= 0))
        raise ConfigError("branch diameters must be > 0 metres",
                          key=f"branches.diameter[{row}]", value=float(branches.diameter[row]))
    keep = branches.length > MIN_LENGTH_M
    n_dropped = int((~keep).sum())
    if n_dropped:
        log.info("dropped %d zero-length branch segment(s)", n_dropped)
    kept = branches.subset(keep) if n_dropped else branches  # all kept: no copy (read only)
    return kept, n_dropped, np.flatnonzero(keep)


def default_origin(points_m: np.ndarray) -> np.ndarray:
    """Centre of the bounding box, rounded to whole metres (keeps round numbers round)."""
    if len(points_m) == 0:
        return np.zeros(3)
    return np.round(0.5 * (points_m.min(0) + points_m.max(0))) + 0.0  # + 0.0: no -0


def primitive_mesh(prim: Primitive, k: int, source: str | None, index: int | None = None):
    """Triangles of an explicit primitive, in real (float64) coordinates: (vertices, faces,
    class code per face or None when every face has the primitive's label)."""
    p = prim.params
    if prim.kind == "cylinder":
        p0, p1 = np.asarray([p["p0_m"]], float), np.asarray([p["p1_m"]], float)
        r = np.array([0.5 * float(p["diameter_m"])]) * np.pi / (k * np.sin(np.pi / k))
        v, f, _ = prism_mesh(p0, p1, r, k)
        return v, f, None
    if prim.kind == "box":
        lo, hi = np.asarray(p["min_m"], float), np.asarray(p["max_m"], float)
        c = np.array([[x, y, z] for z in (lo[2], hi[2]) for y in (lo[1], hi[1]) for x in (lo[0], hi[0])])
        f = np.array([[0, 2, 1], [1, 2, 3], [4, 5, 6], [5, 7, 6], [0, 1, 4], [1, 5, 4],
                      [2, 6, 3], [3, 6, 7], [0, 4, 2], [2, 4, 6], [1, 3, 5], [3, 7, 5]])
        return c, f, None
    if prim.kind in ("obj", "ply"):
        m = primitive_mesh_data(prim, source, index)
        return m.vertices, m.faces, m.face_class
    raise ConfigError("unknown primitive type; valid: cylinder, box, obj, ply", file=source,
                      key="primitive.type" if index is None else f"primitive[{index}].type",
                      value=prim.kind)


def _primitive_feature_m(prim: Primitive) -> float:
    """Smallest size of a cylinder (diameter) or box (side) primitive; inf for meshes."""
    p = prim.params
    if prim.kind == "cylinder":
        return float(p["diameter_m"])
    if prim.kind == "box":
        side = np.abs(np.asarray(p["max_m"], float) - np.asarray(p["min_m"], float))
        return float(side.min())
    return float("inf")


def build_scene(branches: Branches, leaves: Leaves | None = None,
                primitives: list[Primitive] = (), *, representation: str = "mesh",
                facets: int = 12, origin_m=None, variant: str | None = None,
                source: str | None = None, instances: Instances | None = None,
                scanner_m=None, terrain=None) -> BuiltScene:
    """Turn plain geometry into a Mitsuba scene for range/coverage integrators.

    Parameters
    ----------
    branches : woody segments (real coordinates, metres).
    leaves : leaf triangles, or None.
    primitives : explicit calibration shapes.
    representation : 'mesh', 'cylinder' or 'linearcurve'.
    facets : k for the mesh representation (≥ 3).
    origin_m : float64 scene origin; default the centre of the bounding box of every
        shape and of ``scanner_m``, rounded to metres.
    instances : prototypes placed as Mitsuba instances (mesh representation only).
    scanner_m : (n, 3) scanner positions (real coordinates), counted in the default
        origin and in the float32 precision check.
    terrain : a :class:`~simlidar_mi.io.terrain.Terrain`: its mesh becomes the ground (class
        ground, no element id), counted in the default origin; scan it with the analytic
        ground plane off.
    """
    if representation not in REPRESENTATIONS:
        raise ConfigError(f"unknown branch representation; valid: {', '.join(REPRESENTATIONS)}",
                          file=source, key="scene.representation", value=representation)
    if int(facets) != facets or facets < 3:
        raise ConfigError("facets must be an integer ≥ 3", file=source, key="scene.facets", value=facets)
    mi = mitsuba(variant)
    leaves = leaves if leaves is not None else Leaves.empty()
    kept, n_dropped, kept_index = clean_branches(branches)
    prim_meshes = [primitive_mesh(prim, 64, source, j) for j, prim in enumerate(primitives)]
    extra = scanner_m if terrain is None else (terrain.corners_m() if scanner_m is None else np.concatenate(
        [np.asarray(scanner_m, np.float64).reshape(-1, 3), terrain.corners_m()]))
    origin = _scene_origin(kept, leaves, primitives, prim_meshes, instances, extra, origin_m, source)

    parts = _Shapes()
    if terrain is not None:  # the ground: one mesh of the terrain grid, recentred in float64
        v, f = terrain.mesh(origin)
        parts.shapes["ground_mesh"] = _mi_mesh(mi, "ground_mesh", v, f)
        parts.groups.append(("ground_mesh", CLASS_CODES["ground"], np.full(len(f), NO_ID, np.uint32)))
        parts.n_tri += len(f)
    k = int(facets)
    _add_wood(mi, parts, kept, kept_index, origin, representation, k)
    _add_leaves_and_primitives(mi, parts, leaves, primitives, prim_meshes, origin, len(branches))
    real_instances = bool(instances is not None and len(instances))
    if real_instances:
        parts.n_tri += _add_instances(mi, instances, origin, k, parts.shapes, parts.group_rows,
                                      parts.instance_keys, parts.group_meshes)
    flat = _group_big_meshes(mi, parts, len(instances.prototypes) if real_instances else 0)

    scene = mi.load_dict({"type": "scene", **parts.shapes})
    tables = _lookup_tables(mi, scene, parts, primitives, instances)
    # Several plants without instancing (an orchard, a flattened forest): a tree id per
    # primitive, so hits report their tree; one plant needs no extra lookup.
    plants = np.concatenate([branches.tree_id, leaves.plant_id])
    if not real_instances and len(plants) and plants.min() < plants.max():
        trees = []  # laid out like prim_element: top-level shapes, then group rows
        for key, _, elems in parts.groups + flat:
            trees.append(_plant_ids(key, elems, branches, leaves, kept_index, parts.faces_per_branch.get(key)))
        tables["prim_tree"] = _joined(trees)
    if len(parts.shapes):
        bb = scene.bbox()
        lo, hi = np.array(bb.min, float) + origin, np.array(bb.max, float) + origin
    else:
        lo = hi = origin.copy()
    if terrain is not None:
        tables["terrain_cell_m"] = float(min(terrain.dx_m, terrain.dy_m))
    return BuiltScene(scene, origin, n_branches=len(kept), n_dropped=n_dropped, n_triangles=parts.n_tri,
                      representation=representation, facets=k, bbox_min_m=lo, bbox_max_m=hi, **tables)


@dataclass
class _Shapes:
    """The Mitsuba shapes of a scene as :func:`build_scene` gathers them, with what each one's
    primitives are: (shape key, class, element id per primitive) for top-level shapes, and
    (prototype, shape index, class, element ids) for meshes placed through instances."""

    shapes: dict = field(default_factory=dict)
    groups: list = field(default_factory=list)
    faces_per_branch: dict = field(default_factory=dict)  # wood meshes: faces per kept branch
    group_rows: list = field(default_factory=list)
    instance_keys: list = field(default_factory=list)  # (shape key, tree id, prototype)
    group_meshes: list = field(default_factory=list)  # the mesh of each group row
    top_level: set = field(default_factory=set)  # shapes kept out of groups (own reflectance)
    n_tri: int = 0


def _scene_origin(kept: Branches, leaves: Leaves, primitives, prim_meshes, instances, scanner_m,
                  origin_m, source) -> np.ndarray:
    """The float64 origin the float32 scene is placed around, checked for float32 precision
    against the smallest feature."""
    pts = [kept.p0, kept.p1, leaves.vertices.reshape(-1, 3)] + [m[0] for m in prim_meshes]
    if instances is not None and len(instances):
        pts.append(np.asarray(instances.translation_m, np.float64))
    if scanner_m is not None:
        pts.append(np.asarray(scanner_m, np.float64).reshape(-1, 3))
    # Per-part bounds, so a large scene is not copied into one array just for its box.
    corners = np.array([c for p in pts if len(p) for c in (p.min(0), p.max(0))]).reshape(-1, 3)
    if origin_m is None:
        origin = default_origin(corners)
    else:
        origin = np.asarray(origin_m, np.float64)
        if origin.shape != (3,) or not np.isfinite(origin).all():
            raise ConfigError("origin_m must be three finite numbers", file=source,
                              key="scene.origin_m", value=origin_m)
    _check_float32(corners, origin, _smallest_feature(kept, leaves, primitives, instances, prim_meshes))
    return origin


def _add_wood(mi, parts: _Shapes, kept: Branches, kept_index: np.ndarray, origin: np.ndarray,
              representation: str, k: int) -> None:
    """The branches as one prism mesh, analytic cylinders (with capping discs) or linear curves."""
    if not len(kept):
        return
    shapes, groups = parts.shapes, parts.groups
    p0, p1 = kept.p0 - origin, kept.p1 - origin
    radius = 0.5 * kept.diameter
    elem_of_branch = kept_index.astype(np.uint32)  # ids refer to rows of the input branches
    if representation == "mesh":
        caps = exposed_ends(kept.p0, kept.p1, kept.diameter)
        v, f, per = prism_arrays(p0, p1, radius * np.pi / (k * np.sin(np.pi / k)), k, caps=caps,
                                 dtype=np.float32)
        shapes["wood_mesh"] = _mi_mesh(mi, "wood_mesh", v, f)
        groups.append(("wood_mesh", CLASS_CODES["wood"], np.repeat(elem_of_branch, per)))
        parts.faces_per_branch["wood_mesh"] = per
        parts.n_tri += len(f)
    elif representation == "cylinder":
        for j in range(len(kept)):
            key = f"wood_cyl_{j:07d}"
            shapes[key] = mi.load_dict({"type": "cylinder", "p0": p0[j].tolist(),
                                        "p1": p1[j].tolist(), "radius": float(radius[j])})
            groups.append((key, CLASS_CODES["wood"], elem_of_branch[j:j + 1]))
        v, f, per = prism_arrays(p0, p1, radius, CAP_SIDES, sides=False, dtype=np.float32,
                                 caps=exposed_ends(kept.p0, kept.p1, kept.diameter))
        shapes["wood_caps"] = _mi_mesh(mi, "wood_caps", v, f)
        groups.append(("wood_caps", CLASS_CODES["wood"], np.repeat(elem_of_branch, per)))
        parts.faces_per_branch["wood_caps"] = per
        parts.n_tri += len(f)
    else:  # linearcurve: Mitsuba reads curves from a text file, one blank line between curves
        with tempfile.NamedTemporaryFile("w", suffix=".txt", delete=False) as fh:
            rows = np.concatenate([p0, radius[:, None], p1, radius[:, None]], axis=1).astype(np.float32)
            np.savetxt(fh, rows, fmt="%.9g %.9g %.9g %.9g\n%.9g %.9g %.9g %.9g\n")
            curve_path = fh.name
        try:
            shapes["wood_curves"] = mi.load_dict({"type": "linearcurve", "filename": curve_path})
        finally:
            os.unlink(curve_path)
        groups.append(("wood_curves", CLASS_CODES["wood"], elem_of_branch))


def _add_leaves_and_primitives(mi, parts: _Shapes, leaves: Leaves, primitives, prim_meshes,
                               origin: np.ndarray, n_branches: int) -> None:
    """Leaf triangles as one mesh; each primitive as its own mesh (element id after the branches)."""
    if len(leaves):
        # float64 subtraction rounded once to float32 (the bits of converting afterwards)
        v = np.subtract(leaves.vertices, origin, out=np.empty(leaves.vertices.shape, np.float32),
                        casting="unsafe").reshape(-1, 3)
        f = np.arange(len(v), dtype=np.uint32).reshape(-1, 3)
        parts.shapes["leaf_mesh"] = _mi_mesh(mi, "leaf_mesh", v, f)
        parts.groups.append(("leaf_mesh", CLASS_CODES["leaf"], leaves.leaf_id.astype(np.uint32)))
        parts.n_tri += len(f)
    for j, (prim, (v, f, face_class)) in enumerate(zip(primitives, prim_meshes)):
        v = v - origin
        key = f"primitive_{j:04d}"
        label = CLASS_CODES[prim.label if prim.label in ("wood", "leaf") else "wood"]
        if prim.params.get("reflectance") is not None:  # read per top-level shape
            parts.top_level.update([key] + [f"{key}_{c}" for c in CLASS_CODES.values()])
        if face_class is None:
            parts.shapes[key] = _mi_mesh(mi, key, v, f)
            parts.groups.append((key, label, np.full(len(f), n_branches + j, np.uint32)))
        else:  # faces of several classes: one mesh a class (same element id), face order kept
            for code in np.unique(face_class):
                sub = f"{key}_{int(code)}"
                fc = f[face_class == code]
                used = np.zeros(len(v), bool)
                used[fc] = True  # only this class's vertices, renumbered in their order
                parts.shapes[sub] = _mi_mesh(mi, sub, v[used], (np.cumsum(used) - 1)[fc].astype(np.uint32))
                parts.groups.append((sub, int(code), np.full(len(fc), n_branches + j, np.uint32)))
        parts.n_tri += len(f)


def _group_big_meshes(mi, parts: _Shapes, proto: int) -> list:
    """Big wood and leaf meshes go into one shape group placed once without a transform (the
    last "prototype", number ``proto``; BENCHMARKS §9), and so do mesh primitives that are big
    on their own (a user's 2.4 M-triangle OBJ built in 10 s at the top level, 4 s grouped).
    Returns the groups moved."""
    flat = [g for g in parts.groups if g[0] in ("wood_mesh", "leaf_mesh")
            or (g[0].startswith("primitive_") and len(g[2]) >= GROUP_MIN_TRIANGLES
                and g[0] not in parts.top_level)]
    if sum(len(e) for _, _, e in flat) < GROUP_MIN_TRIANGLES:
        return []
    members = {}
    for j, (key, cls, elems) in enumerate(flat):  # names keep the shape index order
        members[f"{chr(ord('a') + j)}_{key}"] = mesh_j = parts.shapes.pop(key)
        parts.group_rows.append((proto, j, cls, elems))
        parts.group_meshes.append(mesh_j)
    parts.groups = [g for g in parts.groups if g not in flat]
    parts.shapes["flat_group"] = mi.load_dict({"type": "shapegroup", **members})
    parts.shapes["flat_instance"] = mi.load_dict({"type": "instance", "shapegroup": parts.shapes["flat_group"]})
    parts.instance_keys.append(("flat_instance", 0xFFFFFFFF, proto))
    return flat


def _lookup_tables(mi, scene, parts: _Shapes, primitives, instances) -> dict:
    """The per-shape tables the integrators read by a hit's shape registry id: class, first
    element row, reflectance; then each instance's tree, prototype and yaw."""
    import drjit as dr  # noqa: PLC0415
    shapes = parts.shapes
    reg_ids = dr.reinterpret_array(mi.UInt32, scene.shapes_dr()).numpy() if shapes else np.zeros(0, np.uint32)
    by_key = {s.id(): int(r) for s, r in zip(scene.shapes(), reg_ids)}
    size = (max(by_key.values()) + 1) if by_key else 1
    shape_class = np.zeros(size, np.uint32)
    shape_base = np.zeros(size, np.uint32)
    prim_parts, offset = [], 0
    shape_rho = np.full(size, -1.0, np.float32)
    for j, prim in enumerate(primitives):
        if prim.params.get("reflectance") is not None:
            for key in by_key:
                if key == f"primitive_{j:04d}" or key.startswith(f"primitive_{j:04d}_"):
                    shape_rho[by_key[key]] = prim.params["reflectance"]
    prim_shapes = []
    for key, cls, elems in parts.groups:
        rid = by_key[key]
        shape_class[rid], shape_base[rid] = cls, offset
        prim_parts.append(elems)
        prim_shapes.append(shapes[key] if isinstance(shapes[key], mi.Mesh) else None)
        offset += len(elems)
    inst = {}
    if parts.instance_keys:
        group_rows = parts.group_rows
        n_groups = max(g[1] for g in group_rows) + 1
        n_proto = max(g[0] for g in group_rows) + 1
        inst["group_class"] = np.zeros(n_proto * n_groups, np.uint32)
        inst["group_base"] = np.zeros(n_proto * n_groups, np.uint32)
        for (proto, gidx, cls, elems), mesh in zip(group_rows, parts.group_meshes):
            inst["group_class"][proto * n_groups + gidx] = cls
            inst["group_base"][proto * n_groups + gidx] = offset
            prim_parts.append(elems)
            prim_shapes.append(mesh)
            offset += len(elems)
        size_i = max(by_key[key] for key, _, _ in parts.instance_keys) + 1
        inst["instance_tree"] = np.zeros(size_i, np.uint32)
        inst["instance_proto"] = np.zeros(size_i, np.uint32)
        inst["instance_yaw_rad"] = np.zeros(size_i, np.float64)
        for key, tree, proto in parts.instance_keys:
            inst["instance_tree"][by_key[key]] = tree
            if key.startswith("tree_"):
                inst["instance_yaw_rad"][by_key[key]] = np.deg2rad(instances.yaw_deg[int(key[5:])])
            inst["instance_proto"][by_key[key]] = proto * n_groups  # premultiplied row
        grouped = any(key == "flat_instance" for key, _, _ in parts.instance_keys)
        inst["n_instances"] = len(parts.instance_keys) - grouped  # placed trees only
    prim_element = _joined(prim_parts) if prim_parts else np.zeros(1, np.uint32)
    if "ground_mesh" in shapes:
        inst.update(terrain_mesh=shapes["ground_mesh"], terrain_shape_id=by_key["ground_mesh"])
    return {"shape_class": shape_class, "shape_base": shape_base,
            "prim_element": prim_element.astype(np.uint32, copy=False), "shape_reflectance": shape_rho,
            "prim_shapes": prim_shapes, **inst}


def _joined(parts: list) -> np.ndarray:
    """The parts end to end: the part itself when there is one (no copy)."""
    return parts[0] if len(parts) == 1 else np.concatenate(parts)


def _plant_ids(key: str, elems: np.ndarray, branches: Branches, leaves: Leaves,
               kept_index: np.ndarray, faces_per_branch: np.ndarray | None = None) -> np.ndarray:
    """Tree or plant id of every primitive of one shape (none for calibration primitives).

    A wood mesh's ids repeat its kept branches' tree ids ``faces_per_branch`` times (as its
    element ids repeat the branch rows): no gather over every face."""
    if key.startswith("wood"):
        if faces_per_branch is not None:
            return np.repeat(branches.tree_id[kept_index].astype(np.uint32), faces_per_branch)
        return branches.tree_id[elems].astype(np.uint32)
    if key == "leaf_mesh":
        return leaves.plant_id.astype(np.uint32)
    return np.full(len(elems), 0xFFFFFFFF, np.uint32)


def _smallest_feature(kept: Branches, leaves: Leaves, primitives, instances,
                      prim_meshes=None) -> tuple[float, str]:
    """The smallest size float32 rounding must resolve, and what it is: the thinnest
    branch or cylinder, the shortest box side, or the shortest leaf-triangle or imported
    mesh edge (``prim_meshes``: :func:`primitive_mesh` of each primitive)."""
    sizes = [(float(kept.diameter.min()) if len(kept) else np.inf, "branch diameter")]
    sizes += [(_primitive_feature_m(p), f"primitive {j}") for j, p in enumerate(primitives)]
    sizes += [(_mesh_shortest_edge(m[0], m[1]), f"primitive {j}'s shortest mesh edge")  # imported meshes
              for j, m in enumerate(prim_meshes or ()) if primitives[j].kind in ("obj", "ply")]
    sizes.append((_shortest_edge(leaves.vertices), "leaf edge"))
    if instances is not None and len(instances):
        s = float(np.min(instances.scale))
        for b, lv in instances.prototypes:
            if len(b):
                sizes.append((s * float(b.diameter.min()), "branch diameter"))
            if lv is not None and len(lv):
                sizes.append((_shortest_edge(lv.vertices), "leaf edge"))
    return min(sizes, key=lambda t: t[0])


def _mesh_shortest_edge(vertices: np.ndarray, faces: np.ndarray, chunk: int = 1_000_000) -> float:
    """Shortest edge of an indexed triangle mesh, ``chunk`` faces at a time (bounded memory)."""
    return min((_shortest_edge(vertices[faces[a:a + chunk]]) for a in range(0, len(faces), chunk)),
               default=np.inf)


def _shortest_edge(tri: np.ndarray, chunk: int = 1_000_000) -> float:
    """Shortest edge of (n, 3, 3) triangles, in chunks (bounded memory); inf for none."""
    best = np.inf
    for a in range(0, len(tri), chunk):
        t = tri[a:a + chunk]
        e = np.linalg.norm(t - np.roll(t, 1, axis=1), axis=2)
        e = e[e > 0]
        if len(e):
            best = min(best, float(e.min()))
    return best


def _check_float32(corners: np.ndarray, origin: np.ndarray, feature: tuple[float, str]) -> None:
    """Warn when float32 coordinates cannot resolve the scene's smallest feature."""
    size_m, what = feature
    if not len(corners) or not np.isfinite(size_m):
        return
    extent = float(np.abs(corners - origin).max())
    spacing = float(np.spacing(np.float32(extent)))
    if spacing > FLOAT32_FEATURE_SHARE * size_m:
        warnings.warn(
            f"float32 coordinates are {spacing:.3g} m apart at {extent:.4g} m from the scene origin "
            f"{origin.tolist()}, {100 * spacing / size_m:.1f} % of the smallest feature ({what} "
            f"{size_m:.3g} m; the limit is {100 * FLOAT32_FEATURE_SHARE:g} %): hits and ranges may "
            "be wrong; scan a smaller area or split the scene", SimlidarWarning, stacklevel=3)


def _add_instances(mi, instances: Instances, origin: np.ndarray, k: int, shapes: dict,
                   group_rows: list, instance_keys: list, group_meshes: list) -> int:
    """One shapegroup per prototype (wood mesh, then leaf mesh), one instance per tree;
    ``group_meshes`` gets the mesh of each row appended to ``group_rows``.

    Returns the triangles built (each prototype once, however often it is placed)."""
    n_tri = 0
    groups = []
    for p, (branches, leaves) in enumerate(instances.prototypes):
        members = {}
        kept, _, kept_index = clean_branches(branches)
        if len(kept):
            caps = exposed_ends(kept.p0, kept.p1, kept.diameter)
            r = 0.5 * kept.diameter * np.pi / (k * np.sin(np.pi / k))
            v, f, per = prism_arrays(kept.p0, kept.p1, r, k, caps=caps, dtype=np.float32)
            members["a_wood"] = _mi_mesh(mi, f"proto{p}_wood", v, f)
            group_rows.append((p, len(members) - 1, CLASS_CODES["wood"],
                               np.repeat(kept_index.astype(np.uint32), per)))
            group_meshes.append(members["a_wood"])
            n_tri += len(f)
        if leaves is not None and len(leaves):
            v = leaves.vertices.reshape(-1, 3)
            members["b_leaf"] = _mi_mesh(mi, f"proto{p}_leaf", v, np.arange(len(v), dtype=np.uint32).reshape(-1, 3))
            group_meshes.append(members["b_leaf"])
            group_rows.append((p, len(members) - 1, CLASS_CODES["leaf"], leaves.leaf_id.astype(np.uint32)))
            n_tri += len(leaves)
        # Shape index inside a group follows insertion order: wood 0, leaf 1.
        group = mi.load_dict({"type": "shapegroup", **members}) if members else None
        if group is not None:
            shapes[f"proto_{p:05d}"] = group
        groups.append(group)
    T = mi.ScalarTransform4f
    for t in range(len(instances)):
        p = int(instances.proto_index[t])
        if groups[p] is None:
            continue
        pos = (np.asarray(instances.translation_m[t], np.float64) - origin).tolist()
        to_world = T().translate(pos) @ T().rotate([0, 0, 1], float(instances.yaw_deg[t])) \
            @ T().scale(float(instances.scale[t]))
        key = f"tree_{t:07d}"
        shapes[key] = mi.load_dict({"type": "instance", "shapegroup": groups[p], "to_world": to_world})
        instance_keys.append((key, int(instances.tree_id[t]), p))
    return n_tri
