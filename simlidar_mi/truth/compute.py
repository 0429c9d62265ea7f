"""Canopy ground truth of a scene's geometry on a voxel grid (issue #10 part 3).

:func:`compute_truth` clips every leaf triangle and woody cylinder to the voxels
exactly (:mod:`simlidar_mi.truth.voxelize`) and returns an xarray Dataset with the
quantities of :data:`simlidar_mi.truth.grid.DEFINITIONS`, their totals, what fell
outside the grid, LAI and the vertical profiles.

What counts as what:

* leaf area: one-sided area of ``geometry.leaves`` triangles, and the surface area of
  ``[[primitive]]`` shapes labelled ``leaf`` (a mesh counts each triangle once);
* wood area: lateral surface of every branch cylinder plus its **exposed end discs** —
  the ends the scene builder caps (:func:`simlidar_mi.scene.build.exposed_ends`: tips,
  bases and steps down in diameter). A joint where an equal or thicker segment
  continues is not wood surface a beam can meet, so it is not counted; the truth
  and the scanned mesh agree on which ends are surface. Cylinder primitives count
  both end discs, box primitives their six faces, OBJ primitives their triangles;
* wood volume: branch and cylinder-primitive volume, box volume; OBJ meshes have no
  volume here (they need not be closed). Overlaps of consecutive segments at joints
  are counted for each segment (the geometry is a union of cylinders; the overlap is
  a wedge of order r²·bend, not removed).

Zero-length branches are dropped as the scene builder drops them. Instanced forests
are expanded tree by tree to real coordinates (``translation + Rz(yaw)·(scale·p)``,
the transform the scene builder gives each instance), in batches, so memory stays
bounded; time grows with the number of placed trees.
"""
from __future__ import annotations

import numpy as np

from .._runtime.progress import make_progress
from ..errors import ConfigError
from ..geometry import Branches, Leaves
from .grid import VoxelGrid, grid_dataset
from .voxelize import Accumulator, box_volume, clip_triangles, voxelize_cylinders, voxelize_discs

__all__ = ["compute_truth", "default_grid", "leaf_and_plant_area", "Totals"]

BATCH_ELEMENTS = 500_000  # triangles + cylinders expanded per batch of instanced trees


# Truth holds 6 float64 values a voxel (the Dataset's variables; the accumulators are sparse
# until then): 100 M voxels ≈ 4.8 GB.
MAX_VOXELS = 100_000_000


def default_grid(geometry, voxel_m: float = 0.1, margin_m: float = 0.0,
                 max_voxels: int = MAX_VOXELS) -> VoxelGrid:
    """The grid of ``voxel_m`` voxels (snapped to multiples of ``voxel_m``) covering the
    geometry's bounds plus ``margin_m`` on every side: nothing falls outside it. More
    than ``max_voxels`` voxels is refused (about 48 bytes a voxel)."""
    if not (np.isfinite(margin_m) and margin_m >= 0):
        raise ConfigError("margin must be a finite number ≥ 0 metres", key="margin_m", value=margin_m)
    lo, hi = geometry.bounds_m()
    try:
        grid = VoxelGrid.covering(lo - margin_m, hi + margin_m, voxel_m, max_voxels=max_voxels)
    except ConfigError as exc:
        if exc.key != "voxel_m" or margin_m == 0:
            raise
        try:  # the same voxels without the margin fit: the margin is to blame
            VoxelGrid.covering(lo, hi, voxel_m, max_voxels=max_voxels)
        except ConfigError:
            raise exc from None
        raise ConfigError(f"{exc.reason.split(';')[0]} with this margin on every side; use a smaller margin",
                          key="margin_m", value=margin_m) from None
    # A facet lying in a voxel plane belongs to the voxel above it: when the geometry ends
    # exactly on the grid's top plane (a box's face), one more layer keeps it inside.
    top = (hi + margin_m - grid.hi_m) / voxel_m > -1e-9
    if top.any():
        grid = VoxelGrid(grid.corner_m, grid.voxel_m, tuple(np.asarray(grid.shape) + top))
    return grid


class Totals:
    """Accumulators of the three quantities (voxel units until :meth:`arrays`)."""

    def __init__(self, grid: VoxelGrid, leaf_pieces=None):
        self.grid = grid
        self.leaf_pieces = leaf_pieces  # a leaf_g.LeafPieces collecting each leaf piece's normal
        self.leaf = Accumulator(grid.shape)
        self.wood = Accumulator(grid.shape)
        self.volume = Accumulator(grid.shape)
        self.leaf_exact_m2 = 0.0  # closed-form totals, for the coverage check
        self.wood_exact_m2 = 0.0
        self.volume_exact_m3 = 0.0
        self.n = {"leaf_triangles": 0, "branches": 0, "end_discs": 0, "primitives": 0, "trees_expanded": 0}

    def vox(self, p):
        g = self.grid
        return (np.asarray(p, np.float64) - np.asarray(g.corner_m)) / g.voxel_m

    def triangles(self, tri_m: np.ndarray, acc: Accumulator) -> None:
        if not len(tri_m):
            return
        if acc is self.leaf and self.leaf_pieces is not None:
            for ijk, w, owner in clip_triangles(self.vox(tri_m), owners=True):
                acc.add(ijk, w)
                self.leaf_pieces.add(tri_m, ijk, w, owner)
        else:
            for ijk, w in clip_triangles(self.vox(tri_m)):
                acc.add(ijk, w)
        a = 0.5 * np.linalg.norm(np.cross(tri_m[:, 1] - tri_m[:, 0], tri_m[:, 2] - tri_m[:, 0]), axis=1)
        if acc is self.leaf:
            self.leaf_exact_m2 += float(a.sum())
        else:
            self.wood_exact_m2 += float(a.sum())

    def cylinders(self, p0, p1, d, cap0, cap1) -> None:
        if not len(d):
            return
        h = self.grid.voxel_m
        r = 0.5 * np.asarray(d, np.float64)
        voxelize_cylinders(self.vox(p0), self.vox(p1), r / h, self.wood, self.volume)
        L = np.linalg.norm(p1 - p0, axis=1)
        self.wood_exact_m2 += float(np.sum(2 * np.pi * r * L))
        self.volume_exact_m3 += float(np.sum(np.pi * r * r * L))
        ax = (p1 - p0) / L[:, None]
        cen = np.concatenate([p0[cap0], p1[cap1]])
        rad = np.concatenate([r[cap0], r[cap1]])
        voxelize_discs(self.vox(cen), np.concatenate([ax[cap0], ax[cap1]]), rad / h, self.wood)
        self.wood_exact_m2 += float(np.sum(np.pi * rad * rad))
        self.n["end_discs"] += len(rad)

    def branches(self, b: Branches, caps=None) -> None:
        from ..scene.build import clean_branches, exposed_ends  # noqa: PLC0415

        kept, _, _ = clean_branches(b)
        if not len(kept):
            return
        cap0, cap1 = caps if caps is not None else exposed_ends(kept.p0, kept.p1, kept.diameter)
        self.cylinders(kept.p0, kept.p1, kept.diameter, cap0, cap1)
        self.n["branches"] += len(kept)

    def primitive(self, prim, source, j) -> None:
        from ..scene.build import primitive_mesh  # noqa: PLC0415

        p = prim.params
        acc = self.leaf if prim.label == "leaf" else self.wood
        self.n["primitives"] += 1
        if prim.kind == "cylinder":
            p0, p1 = np.asarray([p["p0_m"]], float), np.asarray([p["p1_m"]], float)
            d = np.array([float(p["diameter_m"])])
            if acc is self.wood:
                self.cylinders(p0, p1, d, np.ones(1, bool), np.ones(1, bool))
                return
            # leaf-labelled cylinder: its surface as leaf area (no volume)
            tmp = Totals(self.grid)
            tmp.cylinders(p0, p1, d, np.ones(1, bool), np.ones(1, bool))
            self.leaf.merge(tmp.wood)
            self.leaf_exact_m2 += tmp.wood_exact_m2
            return
        v, f, face_class = primitive_mesh(prim, 3, source, j)
        tri = np.asarray(v, float)[np.asarray(f)]
        if face_class is None:
            self.triangles(tri, acc)
        else:  # a labelled mesh: its leaf and wood faces apart (ground faces are no vegetation)
            from ..geometry import CLASS_CODES  # noqa: PLC0415
            for cls, to in (("wood", self.wood), ("leaf", self.leaf)):
                sel = face_class == CLASS_CODES[cls]
                if sel.any():
                    self.triangles(tri[sel], to)
        if prim.kind == "box" and acc is self.wood:
            lo, hi = np.asarray(p["min_m"], float), np.asarray(p["max_m"], float)
            ijk, w = box_volume(self.vox(lo), self.vox(hi))
            self.volume.add(ijk, w)
            self.volume_exact_m3 += float(np.prod(hi - lo))

    def arrays(self, names=("leaf_area_m2", "wood_area_m2", "wood_volume_m3")) -> dict:
        """The dense arrays ``names`` (of the three) in m² / m³, each allocated once and scaled
        in place (``x *= h; x *= h`` rounds as ``x * h * h`` does). The closed-form volume and
        disc areas are differences of face integrals, so a voxel that holds (almost) nothing
        can come out at −1e-17 by rounding: such values are set to 0 (no negative densities)."""
        h = self.grid.voxel_m
        acc = {"leaf_area_m2": self.leaf, "wood_area_m2": self.wood, "wood_volume_m3": self.volume}
        out = {}
        for name in names:
            a = acc[name].dense()
            if name == "wood_volume_m3":
                a *= h ** 3
            else:
                a *= h
                a *= h
            np.maximum(a, 0.0, out=a)  # a voxel the surface barely touches can round to −1e-17
            out[name] = a
        return out

    def outside(self) -> dict:
        h = self.grid.voxel_m
        return {"leaf_area_outside_m2": self.leaf.outside * h * h,
                "wood_area_outside_m2": self.wood.outside * h * h,
                "wood_volume_outside_m3": self.volume.outside * h ** 3}


def _placed(b: Branches, lv: Leaves, t_m, yaw_deg, scale):
    """Prototype geometry placed as the scene builder places an instance."""
    c, s = np.cos(np.deg2rad(yaw_deg)), np.sin(np.deg2rad(yaw_deg))
    R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) * float(scale)
    t = np.asarray(t_m, np.float64)
    return (b.p0 @ R.T + t, b.p1 @ R.T + t, b.diameter * float(scale),
            lv.vertices.reshape(-1, 3) @ R.T + t if len(lv) else np.zeros((0, 3)))


def _instances(tot: Totals, inst, prog) -> None:
    from ..scene.build import clean_branches, exposed_ends  # noqa: PLC0415

    protos = []
    for b, lv in inst.prototypes:
        kept, _, _ = clean_branches(b)
        caps = exposed_ends(kept.p0, kept.p1, kept.diameter) if len(kept) else (np.zeros(0, bool),) * 2
        protos.append((kept, lv if lv is not None else Leaves.empty(), caps))
    buf, size = [], 0

    def flush():
        nonlocal buf, size
        if not buf:
            return
        p0, p1, d, c0, c1, tri = (np.concatenate([x[i] for x in buf]) for i in range(6))
        tot.cylinders(p0, p1, d, c0, c1)
        tot.triangles(tri.reshape(-1, 3, 3), tot.leaf)
        tot.n["branches"] += len(d)
        tot.n["leaf_triangles"] += len(tri) // 3
        buf, size = [], 0

    st = prog.stage("truth: instanced trees", total=len(inst), unit="tree")
    for t in range(len(inst)):
        kept, lv, caps = protos[int(inst.proto_index[t])]
        p0, p1, d, tri = _placed(kept, lv, inst.translation_m[t], inst.yaw_deg[t], inst.scale[t])
        buf.append((p0, p1, d, caps[0], caps[1], tri))
        size += len(d) + len(tri) // 3
        if size >= BATCH_ELEMENTS:
            flush()
        st.update()
    flush()
    st.close()
    tot.n["trees_expanded"] = len(inst)


def compute_truth(geometry, grid: VoxelGrid, progress=True, ground_area_m2: float | None = None, *,
                  crs: str | None = None, ground_z_m: float = 0.0, leaf_pieces=None, terrain=None):
    """Exact per-voxel leaf area, wood area, wood volume, plant area, LAD and PAD.

    ``geometry`` is a :class:`simlidar_mi.lidar.survey.SceneGeometry`; ``grid`` a
    :class:`VoxelGrid` (e.g. :func:`default_grid`). Attributes hold the totals (from
    the voxels and from closed forms), what fell outside the grid, LAI over
    ``ground_area_m2`` (default: the grid's footprint) and the element counts; 1-D
    variables ``LAD_profile_m2_m3`` / ``PAD_profile_m2_m3`` (z) are leaf / plant area
    per height bin divided by the footprint area and the voxel height. ``crs`` (the scene's
    ``[scene] crs``) and ``ground_z_m`` (its ground plane) describe the frame on file
    (:func:`simlidar_mi.truth.grid.grid_dataset`). ``leaf_pieces``: a
    :class:`~simlidar_mi.truth.leaf_g.LeafPieces` on ``grid`` that collects every leaf piece
    with its normal (for the truth's G along a scan's beams). ``terrain``: the ground
    (default ``geometry.terrain``, a scene's ``[terrain]``), written as ``terrain_z_m``."""
    tot = _accumulate(geometry, grid, make_progress(progress), leaf_pieces)
    if terrain is None:
        terrain = getattr(geometry, "terrain", None)
    return _dataset(tot, grid, ground_area_m2, crs, ground_z_m, terrain)


def leaf_and_plant_area(geometry, grid: VoxelGrid, progress=True,
                        ground_area_m2: float | None = None) -> tuple[np.ndarray, np.ndarray, float, float]:
    """``(leaf_area_m2, plant_area_m2, LAI, PAI)``: the two per-voxel arrays of
    :func:`compute_truth` and its two attributes, bit for bit, without its other four
    arrays (wood area, volume, LAD, PAD: 32 bytes a voxel that ``evaluate-photo`` never reads;
    the plant area is made in the wood area's array)."""
    tot = _accumulate(geometry, grid, make_progress(progress), None)
    arr = tot.arrays(("leaf_area_m2", "wood_area_m2"))
    leaf, plant = arr["leaf_area_m2"], arr.pop("wood_area_m2")
    np.multiply(plant, 0.5, out=plant)
    np.add(leaf, plant, out=plant)      # leaf + wood/2, as _dataset adds them
    ground = _ground_area(grid, ground_area_m2)
    return leaf, plant, float(leaf.sum()) / ground, float(plant.sum()) / ground


def _ground_area(grid: VoxelGrid, ground_area_m2) -> float:
    foot = grid.voxel_m ** 2 * grid.shape[0] * grid.shape[1]
    ground = float(ground_area_m2) if ground_area_m2 is not None else foot
    if not (np.isfinite(ground) and ground > 0):
        raise ConfigError("ground area must be > 0 m²", key="ground_area_m2", value=ground_area_m2)
    return ground


def _accumulate(geometry, grid: VoxelGrid, prog, leaf_pieces) -> Totals:
    """Every leaf triangle, branch, primitive and instance of ``geometry`` clipped into sparse sums."""
    tot = Totals(grid, leaf_pieces)
    if len(geometry.leaves):
        with prog.stage("truth: leaf triangles", total=1, unit="step") as st:
            tot.triangles(geometry.leaves.vertices, tot.leaf)
            tot.n["leaf_triangles"] += len(geometry.leaves)
            st.step(f"{len(geometry.leaves):,} triangles")
    if len(geometry.branches):
        with prog.stage("truth: branch cylinders", total=1, unit="step") as st:
            tot.branches(geometry.branches)
            st.step(f"{len(geometry.branches):,} cylinders")
    for j, prim in enumerate(geometry.primitives):
        tot.primitive(prim, geometry.source, j)
    if geometry.instances is not None and len(geometry.instances):
        _instances(tot, geometry.instances, prog)
    return tot


def _dataset(tot: Totals, grid: VoxelGrid, ground_area_m2, crs=None, ground_z_m=0.0, terrain=None):
    arr = tot.arrays()
    vol = grid.voxel_volume_m3
    # no full-size temporaries: each derived array is the only allocation of its line
    plant = np.multiply(arr["wood_area_m2"], 0.5)
    arr["plant_area_m2"] = np.add(arr["leaf_area_m2"], plant, out=plant)
    arr["LAD_m2_m3"] = np.divide(arr["leaf_area_m2"], vol)
    arr["PAD_m2_m3"] = np.divide(arr["plant_area_m2"], vol)
    foot = grid.voxel_m ** 2 * grid.shape[0] * grid.shape[1]
    ground = _ground_area(grid, ground_area_m2)
    out = tot.outside()
    leaf_t = float(arr["leaf_area_m2"].sum())
    wood_t = float(arr["wood_area_m2"].sum())
    attrs = {
        "title": "simlidar-mi canopy ground truth (exact clipping of triangles and cylinders)",
        "total_leaf_area_m2": leaf_t, "total_wood_area_m2": wood_t,
        "total_wood_volume_m3": float(arr["wood_volume_m3"].sum()),
        "total_plant_area_m2": float(arr["plant_area_m2"].sum()),
        "exact_leaf_area_m2": tot.leaf_exact_m2, "exact_wood_area_m2": tot.wood_exact_m2,
        "exact_wood_volume_m3": tot.volume_exact_m3, **out,
        "ground_area_m2": ground, "footprint_area_m2": foot,
        "LAI": leaf_t / ground, "PAI": float(arr["plant_area_m2"].sum()) / ground,
        "wood_end_discs": "exposed ends only (scene.build.exposed_ends), as the scanned mesh caps them",
        **{f"n_{k}": int(v) for k, v in tot.n.items()},  # no timing: same scene → same bytes
    }
    ds = grid_dataset(grid, arr, attrs, crs=crs, ground_z_m=ground_z_m, terrain=terrain)
    dz = grid.voxel_m
    ds["LAD_profile_m2_m3"] = ("z", arr["leaf_area_m2"].sum(axis=(0, 1)) / (ground * dz),
                               {"units": "m2 m-3", "long_name": "leaf area per height bin / (ground area * bin height)"})
    ds["PAD_profile_m2_m3"] = ("z", arr["plant_area_m2"].sum(axis=(0, 1)) / (ground * dz),
                               {"units": "m2 m-3", "long_name": "plant area per height bin / (ground area * bin height)"})
    return ds
