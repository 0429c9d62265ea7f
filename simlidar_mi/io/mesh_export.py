"""Triangle-mesh export of plant geometry: binary PLY and text OBJ, written in chunks.

Both writers stream: the caller passes *factories* of chunk iterators, so a stand
of thousands of trees is written one tree at a time without holding the whole
mesh in memory. Files are written to a temporary name and renamed when complete.

PLY layout (``binary_little_endian 1.0``; MeshLab, CloudCompare, Blender,
trimesh and Open3D read it)::

    element vertex N     property float x, y, z            (metres, float32)
    element face M       property list uchar int vertex_indices   (always 3)
                         property uchar part               (0 = wood, 1 = leaves)
                         property int tree_id

OBJ layout: ``o wood`` with its ``v`` and ``f`` lines, then ``o leaves`` (1-based
indices, global over the file).

Branches become open ``k``-facet prisms (``2k`` vertices and ``2k`` outward-facing
triangles a segment, no end caps); every leaf triangle keeps its own three
vertices. float32 coordinates resolve about 30 µm at 300 m from the origin.
"""
from __future__ import annotations

import contextlib
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterable, Iterator, Sequence

import numpy as np

from ..errors import ConfigError
from ..geometry import Branches, Leaves
from .atomic import atomic_file

__all__ = ["PART_WOOD", "PART_LEAVES", "PlyMesh", "prism_tubes", "tube_faces", "leaf_triangles",
           "write_ply", "write_ply_stream", "read_ply", "write_obj_stream", "read_obj",
           "ply_size_bytes"]

PART_WOOD = 0
PART_LEAVES = 1
_WRITE_BLOCK = 1 << 16   # rows converted and written at a time
FACE_DTYPE = np.dtype([("n", "u1"), ("v", "<i4", (3,)), ("part", "u1"), ("tree_id", "<i4")])


def prism_tubes(branches: Branches, facets: int = 6) -> np.ndarray:
    """Vertices of open ``facets``-prisms around every segment: ``(n·2k, 3)`` float64.

    Segment ``j`` owns vertices ``2k·j … 2k·j + 2k − 1``: the ring at ``p0`` then the
    ring at ``p1``, radius ``diameter / 2``. Faces: :func:`tube_faces`.
    """
    k = int(facets)
    if k < 3:
        raise ConfigError("must be ≥ 3", key="facets", value=facets)
    n = len(branches)
    if n == 0:
        return np.zeros((0, 3))
    axis = branches.p1 - branches.p0
    ln = np.linalg.norm(axis, axis=1, keepdims=True)
    w = np.where(ln > 0, axis / np.where(ln > 0, ln, 1.0), [[0.0, 0.0, 1.0]])
    helper = np.where(np.abs(w[:, 2:3]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]])
    u = np.cross(helper, w)   # u × v = w: rings run counter-clockwise about the axis
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    v = np.cross(w, u)
    a = 2 * np.pi * np.arange(k) / k
    r = 0.5 * branches.diameter[:, None, None]
    ring = r * (np.cos(a)[None, :, None] * u[:, None, :] + np.sin(a)[None, :, None] * v[:, None, :])
    out = np.concatenate([branches.p0[:, None, :] + ring, branches.p1[:, None, :] + ring], axis=1)
    return out.reshape(-1, 3)


def tube_faces(n_segments: int, facets: int = 6, offset: int = 0) -> np.ndarray:
    """Triangles of :func:`prism_tubes` (``(n·2k, 3)`` int64), outward normals."""
    k = int(facets)
    j = np.arange(k)
    a, a1, b, b1 = j, (j + 1) % k, j + k, (j + 1) % k + k
    one = np.concatenate([np.stack([a, a1, b], 1), np.stack([a1, b1, b], 1)])   # (2k, 3)
    base = offset + 2 * k * np.arange(int(n_segments), dtype=np.int64)
    return (one[None, :, :] + base[:, None, None]).reshape(-1, 3)


def leaf_triangles(leaves: Leaves) -> np.ndarray:
    """Leaf vertices, three per triangle: ``(3n, 3)``; faces are ``arange(3n).reshape(n, 3)``."""
    return leaves.vertices.reshape(-1, 3)


def _header(n_vertices: int, n_faces: int, comments: Sequence[str]) -> bytes:
    lines = ["ply", "format binary_little_endian 1.0"]
    lines += [f"comment {c}" for c in comments]
    lines += [f"element vertex {n_vertices}", "property float x", "property float y",
              "property float z", f"element face {n_faces}",
              "property list uchar int vertex_indices", "property uchar part",
              "property int tree_id", "end_header"]
    return ("\n".join(lines) + "\n").encode("ascii")


def write_ply_stream(path: str | Path, n_vertices: int, n_faces: int,
                     vertex_chunks: Iterable[np.ndarray],
                     face_chunks: Iterable[tuple[np.ndarray, np.ndarray, np.ndarray]],
                     comments: Sequence[str] = (), *, atomic: bool = True) -> Path:
    """Write a binary PLY whose counts are known in advance, chunk by chunk.

    Parameters
    ----------
    n_vertices, n_faces : totals announced in the header (checked at the end).
    vertex_chunks : ``(m, 3)`` float arrays, in order.
    face_chunks : ``(faces (k, 3) global vertex indices, part (k,), tree_id (k,))``.
    comments : header comment lines.
    atomic : write a temporary file and rename it when complete; ``False`` writes ``path``
        itself, for files inside a staged folder that appears as a whole (the forest's 284
        prototype meshes: the renames took 0.8 of their 2.4 s).

    Raises
    ------
    ConfigError
        if the chunks do not add up to the announced counts (nothing is left behind).
    """
    path = Path(path)
    if n_vertices >= 2**31:
        raise ConfigError("a PLY with int32 indices holds at most 2^31 − 1 vertices",
                          key="n_vertices", value=n_vertices)
    with atomic_file(path) if atomic else contextlib.nullcontext(path) as tmp, open(tmp, "wb") as fh:
        fh.write(_header(n_vertices, n_faces, comments))
        nv = nf = 0
        # converted and written _WRITE_BLOCK rows at a time into buffers used again: a whole
        # chunk's float32 copy and face records were fresh pages the kernel zeroed first
        vbuf, rec = np.empty((_WRITE_BLOCK, 3), "<f4"), np.empty(_WRITE_BLOCK, FACE_DTYPE)
        rec["n"] = 3
        for v in vertex_chunks:
            v = np.asarray(v).reshape(-1, 3)
            for a in range(0, len(v), _WRITE_BLOCK):
                m = min(_WRITE_BLOCK, len(v) - a)
                np.copyto(vbuf[:m], v[a:a + m], casting="unsafe")  # float64 → float32 as astype
                fh.write(vbuf[:m].data)
            nv += len(v)
        for faces, part, tree_id in face_chunks:
            faces = np.asarray(faces).reshape(-1, 3)
            part, tree_id = np.broadcast_to(part, len(faces)), np.broadcast_to(tree_id, len(faces))
            for a in range(0, len(faces), _WRITE_BLOCK):
                m = min(_WRITE_BLOCK, len(faces) - a)
                r = rec[:m]
                r["v"] = faces[a:a + m]
                r["part"] = part[a:a + m]
                r["tree_id"] = tree_id[a:a + m]
                fh.write(r.tobytes())
            nf += len(faces)
        if (nv, nf) != (n_vertices, n_faces):
            raise ConfigError(f"wrote {nv} vertices and {nf} faces, header says {n_vertices} "
                              f"and {n_faces}", key="ply counts", value=(nv, nf))
    return path


def write_ply(path: str | Path, vertices: np.ndarray, faces: np.ndarray, part: np.ndarray,
              tree_id: np.ndarray | None = None, comments: Sequence[str] = ()) -> Path:
    """Write one in-memory mesh as binary PLY (see the module docstring)."""
    faces = np.asarray(faces).reshape(-1, 3)
    tid = np.zeros(len(faces), np.int32) if tree_id is None else tree_id
    return write_ply_stream(path, len(vertices), len(faces), [vertices],
                            [(faces, np.broadcast_to(part, len(faces)), tid)], comments)


@dataclass(frozen=True)
class PlyMesh:
    """A PLY file read back: vertices, triangle faces and the per-face properties."""

    vertices: np.ndarray
    faces: np.ndarray
    face_props: dict[str, np.ndarray]
    comments: list[str]


_PLY_TYPES = {"char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2",
              "int16": "i2", "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4",
              "uint": "u4", "uint32": "u4", "float": "f4", "float32": "f4", "double": "f8",
              "float64": "f8"}


def read_ply(path: str | Path) -> PlyMesh:
    """Read a binary little-endian PLY of triangles (a small independent parser).

    Handles any scalar vertex/face properties and a ``list`` vertex-index property
    whose count is 3 on every face (checked).
    """
    data = Path(path).read_bytes()
    end = data.find(b"end_header")
    if not data.startswith(b"ply") or end < 0:
        raise ConfigError("not a PLY file", key="path", value=str(path))
    head_end = data.index(b"\n", end) + 1
    lines = data[:head_end].decode("ascii").splitlines()
    if "format binary_little_endian 1.0" not in lines:
        raise ConfigError("only binary_little_endian PLY is supported", key="path", value=str(path))
    elements: list[tuple[str, int, list]] = []
    comments = []
    for ln in lines:
        tok = ln.split()
        if not tok:
            continue
        if tok[0] == "comment":
            comments.append(ln[8:])
        elif tok[0] == "element":
            elements.append((tok[1], int(tok[2]), []))
        elif tok[0] == "property":
            elements[-1][2].append(tok[1:])
    off = head_end
    out: dict[str, np.ndarray] = {}
    for name, count, props in elements:
        fields = []
        for p in props:
            if p[0] == "list":
                fields.append(("__n_" + p[3], _PLY_TYPES[p[1]]))
                fields.append((p[3], "<" + _PLY_TYPES[p[2]], (3,)))
            else:
                fields.append((p[1], "<" + _PLY_TYPES[p[0]]))
        dt = np.dtype(fields)
        arr = np.frombuffer(data, dt, count, off)
        off += dt.itemsize * count
        out[name] = arr
    if off != len(data):
        raise ConfigError(f"file size does not match the header ({len(data) - off} bytes left)",
                          key="path", value=str(path))
    vert = out["vertex"]
    vertices = np.stack([vert["x"], vert["y"], vert["z"]], 1).astype(np.float64)
    face = out.get("face")
    if face is None:
        return PlyMesh(vertices, np.zeros((0, 3), np.int64), {}, comments)
    list_name = next(n for n in face.dtype.names if not n.startswith("__n_") and face.dtype[n].shape == (3,))
    if len(face) and not (face["__n_" + list_name] == 3).all():
        raise ConfigError("only triangle faces are supported", key="path", value=str(path))
    props = {n: np.array(face[n]) for n in face.dtype.names
             if not n.startswith("__n_") and n != list_name}
    return PlyMesh(vertices, np.array(face[list_name], np.int64), props, comments)


def write_obj_stream(path: str | Path,
                     objects: Sequence[tuple[str, Callable[[], Iterator[tuple[np.ndarray, np.ndarray]]]]],
                     comments: Sequence[str] = ()) -> Path:
    """Write a text OBJ with one ``o NAME`` block per object.

    Parameters
    ----------
    objects : ``(name, chunks)`` where ``chunks()`` yields ``(vertices (m, 3), faces (k, 3))``
        with faces indexing that chunk's own vertices (0-based). The factory is called
        twice (vertices, then faces), so every object's vertices precede its faces.
    """
    path = Path(path)
    with atomic_file(path) as tmp, open(tmp, "w") as fh:
        for c in comments:
            fh.write(f"# {c}\n")
        base = 1
        for name, chunks in objects:
            fh.write(f"o {name}\n")
            n_obj = 0
            for v, _ in chunks():
                if len(v):
                    np.savetxt(fh, np.asarray(v, np.float64).reshape(-1, 3), fmt="v %.6f %.6f %.6f")
                n_obj += len(v)
            off = base
            for v, f in chunks():
                if len(f):
                    np.savetxt(fh, np.asarray(f, np.int64).reshape(-1, 3) + off, fmt="f %d %d %d")
                off += len(v)
            base += n_obj
    return path


def read_obj(path: str | Path) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Read an OBJ we exported: object name → (its vertices, its faces re-indexed 0-based to them).

    Vertices are assigned to the object (``o``, else ``g``) in whose block they appear; faces
    are re-indexed to that object's vertex list (ours never cross objects).  The parser is
    the scene primitives' (:func:`simlidar_mi.io.mesh_import.parse_obj_file`).
    """
    from .mesh_import import parse_obj_file  # noqa: PLC0415
    try:
        v, f, names = parse_obj_file(path)
    except ValueError as exc:
        raise ConfigError(f"not a readable OBJ mesh: {exc}", key="path", value=str(path)) from exc
    tag = "o" if "o" in names else "g" if "g" in names else None
    uniq, f_obj, v_obj = names[tag] if tag else ([], np.full(len(f), -1), np.full(len(v), -1))
    out = {}
    for k, nm in [(-1, "default")] + list(enumerate(uniq)):
        vk, fk = v[v_obj == k], f[f_obj == k]
        if len(vk) == 0 and len(fk) == 0:
            continue
        first = int(np.argmax(v_obj == k)) if len(vk) else 0
        out[nm] = (vk, fk - first)
    return out


def ply_size_bytes(n_vertices: int, n_faces: int) -> int:
    """Bytes of the body of a PLY written by :func:`write_ply_stream` (header excluded)."""
    return 12 * int(n_vertices) + FACE_DTYPE.itemsize * int(n_faces)
