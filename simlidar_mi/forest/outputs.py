"""A forest's files and pictures: leaf tables, trees.csv, stand and prototype meshes, layout and preview.

What each file holds: :mod:`simlidar_mi.forest.run`.
"""
from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable, Iterator

import numpy as np

from ..config.keys_base import SAFE_NAME
from ..errors import ConfigError
from ..io.mesh_export import (PART_LEAVES, PART_WOOD, prism_tubes, tube_faces, write_obj_stream,
                             write_ply_stream)
from ..io.text_columns import format_rows
from ..plants.tree_leaves import LeafTable
from .placement import intensity_grid
from .stand import Forest, _bar, _place

__all__ = ["plot_layout", "plot_preview", "write_stand"]


# --- writers ---------------------------------------------------------------------------

_LEAF_FMT = ["%d", "%d", "%.5f", "%.5f", "%.5f", "%.6g", "%.6g", "%.7g",
             "%.6f", "%.6f", "%.6f", "%.6f", "%.6f", "%.6f"]


def _leaf_tables_csv(path: Path, tables: Iterable[LeafTable], id_name: str) -> int:
    """Write leaf tables as one CSV (streamed); returns the rows written."""
    cols = list(LeafTable.COLUMNS)
    cols[0] = id_name
    rows = 0
    with open(path, "wb") as fh:
        fh.write((",".join(cols) + "\n").encode())
        for t in tables:
            if not len(t):
                continue
            c = t.columns()  # np.savetxt's bytes, formatted in numpy (io/text_columns.py)
            fh.write(format_rows([c[k] for k in LeafTable.COLUMNS], _LEAF_FMT, delimiter=","))
            rows += len(t)
    return rows


PARQUET_COMPRESSION = "zstd"  # BENCHMARKS.md §8c: 215 MB in 0.7 s; none 242 MB, snappy 233 MB
_PARQUET_ROW_GROUP = 1 << 18    # rows gathered before a row group is written


def _leaf_schema(id_name: str):
    import pyarrow as pa  # noqa: PLC0415
    return pa.schema([(id_name, pa.int32()), ("leaf_id", pa.int32())]
                     + [(k, pa.float64()) for k in LeafTable.COLUMNS[2:]])


def _leaf_tables_parquet(path: Path, tables: Iterable[LeafTable], id_name: str) -> int:
    """Write leaf tables as one Parquet file (zstd; row groups of ~262 k rows); returns the rows.

    The values are the tables' float64 and int32 as they are (the CSV rounds them to its
    formats).  Same tables → same bytes: the file holds no time stamp, only the schema and
    pyarrow's ``created_by`` version string.  Columns go in as Arrow buffers over the numpy
    arrays: ``pa.array`` / ``pa.table`` import pandas (0.4 s) to ask whether they got one."""
    import pyarrow as pa  # noqa: PLC0415
    import pyarrow.parquet as pq  # noqa: PLC0415
    schema = _leaf_schema(id_name)
    names = list(LeafTable.COLUMNS)
    rows = 0
    pending: list[dict] = []

    def column(j: int, k: str):
        typ = schema.field(j).type
        x = np.ascontiguousarray(np.concatenate([c[k] for c in pending]), typ.to_pandas_dtype())
        return pa.Array.from_buffers(typ, len(x), [None, pa.py_buffer(x)])

    def flush(writer) -> None:
        arrays = [column(j, k) for j, k in enumerate(names)]
        writer.write_table(pa.Table.from_arrays(arrays, schema=schema))
        pending.clear()

    with pq.ParquetWriter(str(path), schema, compression=PARQUET_COMPRESSION,
                          use_dictionary=[id_name]) as writer:
        n_pending = 0
        for t in tables:
            if not len(t):
                continue
            pending.append(t.columns())
            n_pending += len(t)
            rows += len(t)
            if n_pending >= _PARQUET_ROW_GROUP:
                flush(writer)
                n_pending = 0
        if pending:
            flush(writer)
    return rows


def _have_pyarrow() -> bool:
    try:
        import pyarrow.parquet  # noqa: F401, PLC0415  (only asking whether it imports)
    except ImportError:
        return False
    return True


def leaf_table_format(fmt: str, src: str | None = None) -> str:
    """``[forest] leaf_table_format`` → ``"parquet"`` or ``"csv"``.

    ``"auto"`` is Parquet (pyarrow is a dependency), CSV only where pyarrow cannot be
    imported; ``"parquet"`` without pyarrow is an error naming the key."""
    if fmt == "csv":
        return "csv"
    if _have_pyarrow():
        return "parquet"
    if fmt == "auto":
        return "csv"
    raise ConfigError("needs pyarrow (pip install pyarrow), which could not be imported", file=src,
                      key="forest.leaf_table_format", value=fmt)


def write_leaf_tables(path: Path, tables: Iterable[LeafTable], id_name: str, fmt: str) -> int:
    """Write leaf tables as ``fmt`` (``"parquet"`` or ``"csv"``); returns the rows written."""
    return (_leaf_tables_parquet if fmt == "parquet" else _leaf_tables_csv)(path, tables, id_name)


def _write_trees_csv(path: Path, forest: Forest, extra: dict[str, np.ndarray] | None = None) -> None:
    """``trees.csv``: :meth:`Forest.trees_columns`, then the ``extra`` columns (whole numbers)."""
    c = {**forest.trees_columns(), **(extra or {})}
    fmt = {"x": "{:.6f}", "y": "{:.6f}", "z_base_m": "{:.6f}", "height_m": "{:.6f}",
           "crown_base_m": "{:.6f}", "dbh_m": "{:.6f}", "yaw_deg": "{:.6f}",
           "scale": "{:.8f}", "crown_radius_m": "{:.6f}", "branching": "{:.6g}",
           "leaf_area_m2": "{:.6f}", "crown_projection_m2": "{:.6f}", "needle_area_m2": "{:.6f}"}
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(list(c))
        for i in range(len(forest)):
            w.writerow(["" if k in fmt and not np.isfinite(v[i]) else fmt[k].format(v[i]) if k in fmt else v[i]
                        for k, v in c.items()])


@dataclass
class _Stand:
    """Trees to mesh: tree ``i`` is ``local(i)`` placed by ``place(i) = (t, yaw, scale)``
    (``place = None``: left in its own frame); ``key(i)`` names identical geometry (a
    prototype) so its prisms are built once."""

    n: int
    local: Any
    place: Any
    key: Any

    @classmethod
    def of(cls, forest: Forest) -> "_Stand":
        return cls(len(forest), forest.local_tree,
                   lambda i: (forest.translation_m(i), float(forest.yaw_deg[i]),
                              float(forest.instance_scale[i])),
                   (lambda i: int(forest.prototype[i])) if forest.instancing else (lambda i: None))


_MESH_BLOCK = 1 << 16   # leaf triangles a mesh chunk: its temporaries stay small (BENCHMARKS.md §16)


def _write_mesh(stand: _Stand, path: Path, fmt: str, facets: int, progress: bool,
                comments: list[str], atomic: bool = True) -> Path:
    k = int(facets)
    n = stand.n
    nb = np.array([len(stand.local(i).branches) for i in range(n)], np.int64)
    nt = np.array([len(stand.local(i).leaves) for i in range(n)], np.int64)
    cache: dict = {}

    def placed(i: int, v: np.ndarray) -> np.ndarray:
        if stand.place is None:  # own frame: the identity's + 0 only turns −0 into +0 (same bytes)
            return v + 0.0
        return _place(v, *stand.place(i))

    def wood_of(i: int) -> np.ndarray:
        """Tree ``i``'s wood prisms in its own frame (built once per prototype)."""
        t, key = stand.local(i), stand.key(i)
        wood = cache.get(key) if key is not None else None
        if wood is None:
            wood = prism_tubes(t.branches, k)
            if key is not None:
                cache[key] = wood
        return wood

    def leaf_chunks(i: int) -> Iterator[np.ndarray]:
        """Tree ``i``'s placed leaf vertices (3 per triangle): in blocks in its own frame (the
        + 0 is per element), whole when placed (one BLAS product, as the bits were checked)."""
        v = stand.local(i).leaves.vertices.reshape(-1, 3)
        step = len(v) if stand.place is not None else 3 * _MESH_BLOCK
        for a in range(0, len(v), max(step, 1)):
            yield placed(i, v[a:a + step])

    if fmt == "ply":
        def verts() -> Iterator[np.ndarray]:
            for i in _bar(range(n), progress, path.name, total=n):
                yield placed(i, wood_of(i))
                yield from leaf_chunks(i)

        def faces() -> Iterator[tuple[np.ndarray, np.ndarray, np.ndarray]]:
            off = 0
            for i in range(n):
                b, ntri = int(nb[i]), int(nt[i])
                f = tube_faces(b, k, off)
                yield f, np.full(len(f), PART_WOOD, np.uint8), np.full(len(f), i, np.int32)
                first = off + 2 * k * b
                for a in range(0, ntri, _MESH_BLOCK):   # leaf triangles: 3 own vertices each
                    m = min(_MESH_BLOCK, ntri - a)
                    f = first + 3 * a + np.arange(3 * m, dtype=np.int64).reshape(-1, 3)
                    yield f, np.full(m, PART_LEAVES, np.uint8), np.full(m, i, np.int32)
                off += 2 * k * b + 3 * ntri

        return write_ply_stream(path, int((2 * k * nb + 3 * nt).sum()), int((2 * k * nb + nt).sum()),
                                verts(), faces(), comments, atomic=atomic)
    if fmt == "obj":
        def wood() -> Iterator[tuple[np.ndarray, np.ndarray]]:
            for i in _bar(range(n), progress, path.name, total=n):
                yield placed(i, wood_of(i)), tube_faces(int(nb[i]), k)

        def leaves() -> Iterator[tuple[np.ndarray, np.ndarray]]:
            for i in range(n):
                v = placed(i, stand.local(i).leaves.vertices.reshape(-1, 3))
                yield v, np.arange(len(v), dtype=np.int64).reshape(-1, 3)

        return write_obj_stream(path, [("wood", wood), ("leaves", leaves)], comments)
    raise ConfigError("must be 'ply' or 'obj'", key="forest.export_format", value=fmt)


def write_stand(forest: Forest, path: str | Path, fmt: str = "ply", facets: int = 6,
                progress: bool = False) -> Path:
    """Export every tree of the forest as one mesh (wood and leaf parts), streamed per tree.

    ``fmt`` is ``"ply"`` (binary; faces carry ``part`` 0 = wood / 1 = leaves and
    ``tree_id``) or ``"obj"`` (``o wood`` then ``o leaves``). Branches are open
    ``facets``-prisms, leaf triangles keep their own vertices; in PLY tree ``i``'s
    wood vertices precede its leaf vertices, trees in order.
    """
    return _write_mesh(_Stand.of(forest), Path(path), fmt, facets, progress,
                       ["simlidar-mi forest stand, metres", "part 0 = wood (open prisms), 1 = leaves",
                        f"seed {forest.seed}, {len(forest)} trees"])


def _write_prototype_meshes(forest: Forest, folder: Path, fmt: str, facets: int) -> list[Path]:
    """One mesh per prototype, in its own frame (place with the transforms of trees.csv).

    ``folder`` is inside the run's staged folder, which appears whole or not at all, so
    each PLY is written in place (OBJ keeps its writer's temporary file)."""
    names = forest.species_names
    for name in names:  # a name is part of a file name: never a path (the scene check's twin)
        if not SAFE_NAME.fullmatch(name):
            raise ConfigError("a species name that names files must be 1-64 letters, digits, '_', "
                              "'-' or '.', starting with a letter or digit", key="species.name", value=name)
    folder.mkdir(parents=True, exist_ok=True)
    out = []
    for p, t in enumerate(forest.prototypes):
        stand = _Stand(1, lambda i, t=t: t, None, lambda i: None)
        species = names[int(forest.prototype_species[p])]
        out.append(_write_mesh(stand, folder / f"{species}_{p:03d}.{fmt}", fmt, facets, False,
                               [f"simlidar-mi forest prototype {p} ({species}), own frame, metres",
                                "part 0 = wood (open prisms), 1 = leaves"], atomic=False))
    return out


# --- pictures --------------------------------------------------------------------------


def _colours(n: int) -> list:
    import matplotlib  # noqa: PLC0415
    cmap = matplotlib.colormaps["tab10"]
    return [cmap(i % 10) for i in range(n)]


def plot_layout(forest: Forest, path: str | Path) -> Path:
    """Trees as crown-sized discs by species over the intensity contours (``layout.png``)."""
    import matplotlib  # noqa: PLC0415
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415
    from matplotlib.collections import EllipseCollection  # noqa: PLC0415
    from matplotlib.lines import Line2D  # noqa: PLC0415

    d = forest.params.domain
    sp = [s.intensity for s in forest.params.species]
    x, y, lam = intensity_grid(sp, d, 200, 200)
    cols = _colours(len(sp))
    w, h = d.x_max_m - d.x_min_m, d.y_max_m - d.y_min_m
    fig, ax = plt.subplots(figsize=(7.5 * min(2.0, max(0.6, w / h)) + 1.8, 7.5), dpi=120)
    total = lam.sum(0)
    cf = ax.contourf(x, y, total, levels=12, cmap="Greys", alpha=0.45)
    fig.colorbar(cf, ax=ax, label="total intensity λ (trees per m²)", shrink=0.8)
    for j in range(len(sp)):
        if lam[j].max() > 0:
            ax.contour(x, y, lam[j], levels=4, colors=[cols[j]], linewidths=0.8, alpha=0.9)
    handles = []
    for j, name in enumerate(forest.species_names):
        m = forest.species == j
        if m.any():
            diam = 2 * forest.crown_radius_m[m]
            ax.add_collection(EllipseCollection(diam, diam, np.zeros(m.sum()), units="xy",
                                                offsets=np.column_stack([forest.x_m[m], forest.y_m[m]]),
                                                offset_transform=ax.transData, facecolors=[cols[j]],
                                                edgecolors="k", linewidths=0.2, alpha=0.55))
            ax.plot(forest.x_m[m], forest.y_m[m], ".", ms=1.5, color="k")
        pl = forest.placement
        handles.append(Line2D([], [], marker="o", ls="", color=cols[j], markeredgecolor="k",
                              label=f"{name}: {int(m.sum())} trees ({int(pl.removed[j])} removed)"))
    ax.set_xlim(d.x_min_m, d.x_max_m)
    ax.set_ylim(d.y_min_m, d.y_max_m)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(f"{len(forest)} trees; discs = crown diameter; lines = intensity per species; "
                 f"min distance {forest.params.min_distance_m:g} m, d ≥ {forest.params.crown_factor:g}·(r_i + r_j)",
                 fontsize=9)
    ax.legend(handles=handles, loc="upper left", fontsize=8, framealpha=0.85)
    fig.tight_layout()
    fig.savefig(path, format="png")
    plt.close(fig)
    return Path(path)


def _strip(forest: Forest, max_trees: int) -> np.ndarray:
    """Indices of the at most ``max_trees`` trees nearest the domain's middle line y = y_mid."""
    d = forest.params.domain
    order = np.argsort(np.abs(forest.y_m - 0.5 * (d.y_min_m + d.y_max_m)), kind="stable")
    return np.sort(order[:max_trees])


def _segment_lines(segs: np.ndarray, widths_pt: np.ndarray, step_pt: float = 0.1) -> list:
    """(S, 2, 2) segments as one NaN-separated polyline per line width (widths rounded to
    ``step_pt``): [(width, (3·s, 2) xy)].

    matplotlib draws such a line as one path; a LineCollection of the forest preview's 381 k
    segments made 381 k Path objects and took 5 s of the forest's 20 s (issue #8); a single
    PathPatch of move-to/line-to pieces was slower still in Agg (measured)."""
    bins = np.rint(widths_pt / step_pt).astype(np.int64)
    out = []
    for b in np.unique(bins):
        sel = segs[bins == b]
        xy = np.concatenate([sel, np.full((len(sel), 1, 2), np.nan)], axis=1).reshape(-1, 2)
        out.append((float(b * step_pt), xy))
    return out


def plot_preview(forest: Forest, path: str | Path, max_trees: int = 300,
                 max_leaf_points: int = 200_000) -> Path:
    """Side (x–z) and top (x–y) views; branches as lines, leaves as dots (``preview.png``).

    Big forests show a central strip of ``max_trees`` trees (all crowns outlined in the
    top view) and a subsample of at most ``max_leaf_points`` leaf centres.
    """
    import matplotlib  # noqa: PLC0415
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415
    from matplotlib.collections import EllipseCollection  # noqa: PLC0415

    d = forest.params.domain
    idx = _strip(forest, max_trees)
    cols = _colours(len(forest.species_names))
    n_leaves = int(forest.n_leaves[idx].sum()) if len(idx) else 0
    step = max(1, math.ceil(n_leaves / max_leaf_points))
    segs_side, segs_top, lw, leaf_pts = [], [], [], []
    for i in idx:
        # what forest.tree_geometry / tree_leaf_table would place, limited to the branch end
        # points and the drawn leaf centres: placing every leaf vertex, normal and heading
        # of 300 trees took 7 of the preview's 10 s
        t, tr, yaw, s = forest.local_tree(int(i)), forest.translation_m(int(i)), \
            float(forest.yaw_deg[i]), float(forest.instance_scale[i])
        p0, p1 = _place(t.branches.p0, tr, yaw, s), _place(t.branches.p1, tr, yaw, s)
        segs_side.append(np.stack([p0[:, [0, 2]], p1[:, [0, 2]]], 1))
        segs_top.append(np.stack([p0[:, :2], p1[:, :2]], 1))
        lw.append(np.clip(t.branches.diameter * s * 4.0, 0.1, 1.5))
        leaf_pts.append(_place(t.leaf_table.centre_m[::step], tr, yaw, s))
    fig, (a_side, a_top) = plt.subplots(2, 1, figsize=(12, 12), dpi=110,
                                        gridspec_kw={"height_ratios": [1, 2.0]})
    dot = 0.6 * math.sqrt(min(step, 16))  # thinned leaves drawn bigger to keep the crown's tone
    if len(idx):
        pts = np.concatenate(leaf_pts) if leaf_pts else np.zeros((0, 3))
        widths = np.concatenate(lw)
        for ax, segs, alpha in ((a_side, segs_side, 1.0), (a_top, segs_top, 0.8)):
            for width, xy in _segment_lines(np.concatenate(segs), widths):
                ax.plot(xy[:, 0], xy[:, 1], lw=width, color="saddlebrown", alpha=alpha,
                        solid_capstyle="butt")
        # leaf dots as markers of one colour per run of same-species trees, in tree order: Agg
        # stamps one cached marker (a scatter of 200 k dots drew each: 2.3 s of 5.8 s)
        kind = np.concatenate([np.full(len(p), int(forest.species[i])) for p, i in zip(leaf_pts, idx)])
        cuts = np.flatnonzero(np.diff(kind)) + 1
        for a, b in zip(np.r_[0, cuts], np.r_[cuts, len(kind)]):
            for ax, (u, v) in ((a_side, (0, 2)), (a_top, (0, 1))):
                ax.plot(pts[a:b, u], pts[a:b, v], ls="", marker="o", ms=math.sqrt(dot), mew=0,
                        color=cols[kind[a]], alpha=0.35, zorder=3)
    diam = 2 * forest.crown_radius_m
    a_top.add_collection(EllipseCollection(diam, diam, np.zeros(len(forest)), units="xy",
                                           offsets=np.column_stack([forest.x_m, forest.y_m]),
                                           offset_transform=a_top.transData, facecolors="none",
                                           edgecolors=[cols[int(s)] for s in forest.species],
                                           linewidths=0.4))
    zmax = float(forest.height_m.max()) if len(forest) else 1.0
    a_side.set_xlim(d.x_min_m, d.x_max_m)
    a_side.set_ylim(0, 1.05 * zmax)
    # wide stands would be a thin strip at 1:1; exaggerate z so the side view stays readable
    exag = max(1.0, 0.3 * (d.x_max_m - d.x_min_m) / max(zmax, 1e-9))
    a_side.set_aspect(exag)
    a_side.set_xlabel("x (m)")
    a_side.set_ylabel("z (m)")
    y_lo = float(forest.y_m[idx].min()) if len(idx) else d.y_min_m
    y_hi = float(forest.y_m[idx].max()) if len(idx) else d.y_max_m
    a_side.set_title(f"side view (looking along +y) of {len(idx)} of {len(forest)} trees, "
                     f"y in [{y_lo:.0f}, {y_hi:.0f}] m; leaf dots 1 in {step}"
                     + (f"; z exaggerated ×{exag:.1f}" if exag > 1 else ""), fontsize=9)
    a_top.set_xlim(d.x_min_m, d.x_max_m)
    a_top.set_ylim(d.y_min_m, d.y_max_m)
    a_top.set_aspect("equal")
    a_top.set_xlabel("x (m)")
    a_top.set_ylabel("y (m)")
    a_top.set_title("top view: the same trees drawn, every crown outlined; leaves coloured by species",
                    fontsize=9)
    from matplotlib.lines import Line2D  # noqa: PLC0415
    a_side.legend(handles=[Line2D([], [], marker="o", ls="", color=cols[j], label=nm)
                           for j, nm in enumerate(forest.species_names)], loc="upper right",
                  fontsize=8, framealpha=0.85)
    fig.tight_layout()
    fig.savefig(path, format="png")
    plt.close(fig)
    return Path(path)
