"""Triangle meshes that users bring: Wavefront OBJ and PLY read once, checked, as plain arrays.

OBJ text is split into lines and tokens and converted to numbers by Apache Arrow's
multithreaded CSV reader and compute kernels (``pyarrow``, a dependency already), so no
Python loop runs per line; PLY goes through ``plyfile`` (binary little/big endian and
ASCII; fixed three-index faces are read as one record array).  Both give vertices in
float64 as written in the file (no float32 rounding before the scene origin is
subtracted) and faces in file order: polygons become triangle fans, a face's triangles
follow each other, so a face's rank in the file decides its triangles' ids.  Vertices
are neither merged nor reordered and degenerate triangles are kept (they cannot be hit).

Class labels (optional): OBJ faces take the class whose name patterns
(:func:`fnmatch.fnmatchcase`) match their ``usemtl`` material, else their ``g`` group,
else their ``o`` object name; PLY faces take the class whose integer values list their
``label_property`` value (``part`` in ``simlidar-mi forest`` exports: 0 wood, 1 leaves).
Unmatched faces keep the primitive's ``label``.
"""
from __future__ import annotations

import fnmatch
import os
import stat
import tempfile
import warnings
from contextlib import contextmanager
from dataclasses import dataclass, replace

import numpy as np

from ..errors import ConfigError, SimlidarWarning
from ..geometry import CLASS_CODES, Mesh, Primitive

__all__ = ["MESH_SUFFIXES", "MAX_MESH_BYTES", "read_mesh", "primitive_mesh_data", "mesh_drop", "ship_meshes",
           "unship_meshes", "parse_obj_file", "read_ply_arrays"]

MESH_SUFFIXES = {"obj": (".obj",), "ply": (".ply",)}
MAX_MESH_BYTES = 256 * 2**20  # a 2.4 M-triangle OBJ is 115 MB (its read peaks at ~6× that), as PLY 66 MB
LABELED = ("wood", "leaf", "ground")  # classes a label key may name


#: The largest coordinate a mesh may hold: float32's largest value (the scene is traced in
#: float32; beyond it a vertex is infinite).  Finite coordinates far from the rest of the scene
#: are then caught by the float32 precision check of scene.build (a warning).
MAX_COORD_M = float(np.finfo(np.float32).max)


def _obj_vertex_line(path, row: int) -> int | None:
    """The 1-based line of the OBJ file that holds vertex ``row`` (0-based); None if not found."""
    seen = 0
    with open(path, "rb") as fh:
        for n, line in enumerate(fh, 1):
            if line.lstrip()[:2] in (b"v ", b"v\t"):
                if seen == row:
                    return n
                seen += 1
    return None


def _bad(kind: str, path, source, index, why: str) -> ConfigError:
    key = "primitive.path" if index is None else f"primitive[{index}].path"
    what = f"{kind.upper()} mesh" + ("" if index is None else f" of primitive {index}")
    return ConfigError(f"{what}: {why}", file=source, key=key, value=str(path))


def read_mesh(path, kind: str, *, label: str = "wood", labels: dict | None = None,
              label_property: str | None = None, source: str | None = None,
              index: int | None = None) -> Mesh:
    """Read, check and label one OBJ or PLY triangle mesh.

    Parameters
    ----------
    path : the file; its name must end in ``.obj``/``.ply`` (``kind``), it must be a regular
        file of at most :data:`MAX_MESH_BYTES` (both checked before a byte is read).
    label : class of faces no ``labels`` entry matches ('wood', 'leaf' or 'ground').
    labels : ``{class: [patterns or values]}``: OBJ name patterns or PLY property values.
    label_property : the PLY face property ``labels`` reads (e.g. ``part``).
    source, index : the scene file and the primitive's position in it, for messages.

    Raises
    ------
    ConfigError
        naming the file (``primitive[index].path``) for a bad name, a missing, unreadable,
        malformed or empty mesh, a non-finite vertex or one beyond float32's range
        (:data:`MAX_COORD_M`), or a face index out of range.
    """
    def bad(why: str) -> ConfigError:
        return _bad(kind, path, source, index, why)
    if not str(path).lower().endswith(MESH_SUFFIXES[kind]):
        raise bad(f"the file name must end in {MESH_SUFFIXES[kind][0]}")
    try:
        st = os.stat(path)
    except OSError as exc:
        raise bad(f"cannot read it: {exc.strerror or exc}") from exc
    if not stat.S_ISREG(st.st_mode):
        raise bad("not a regular file")
    if st.st_size > MAX_MESH_BYTES:
        raise bad(f"{st.st_size} bytes exceed the limit for mesh primitives, {MAX_MESH_BYTES} bytes "
                  f"({MAX_MESH_BYTES / 2**20:g} MiB)")
    try:
        if kind == "obj":
            v, f, names = parse_obj_file(path, names=bool(labels))
            code = _obj_classes(names, labels, label, len(f), path) if labels else None
        else:
            v, f, props = read_ply_arrays(path)
            code = _ply_classes(props, labels, label_property, label, bad, path) if labels else None
    except OSError as exc:
        raise bad(f"cannot read it: {exc.strerror or exc}") from exc
    except UnicodeDecodeError as exc:
        raise bad("not UTF-8 text") from exc
    except ValueError as exc:
        raise bad(str(exc)) from exc
    if len(f) == 0:
        raise bad("no faces")
    out_of_range = ~(np.abs(v) <= MAX_COORD_M).all(1)  # NaN too
    if out_of_range.any():
        row = int(np.argmax(out_of_range))
        where = f"vertex {row} (0-based)" + (f", line {_obj_vertex_line(path, row)}" if kind == "obj" else "")
        what = ("a non-finite vertex" if not np.isfinite(v[row]).all() else
                f"a vertex beyond float32's range (|x| > {MAX_COORD_M:.3g} m)")
        raise bad(f"{what}: {where}, {v[row].tolist()}")
    if f.min() < 0 or f.max() >= len(v):
        j = int(np.argmax((f < 0).any(1) | (f >= len(v)).any(1)))
        raise bad(f"a face index out of range (face {j}, 0-based, of {len(v)} vertices)")
    if ((f[:, 0] == f[:, 1]) | (f[:, 1] == f[:, 2]) | (f[:, 0] == f[:, 2])).all():
        raise bad("every face is degenerate (a vertex used twice)")
    if not _any_area(v, f):
        raise bad("every face is degenerate (zero area: its three vertices on one line), so "
                  "nothing can hit the mesh")
    if code is not None and (code == code[0]).all():
        code = None if code[0] == CLASS_CODES[label] else code  # one class: the shape's own
    return Mesh(v, f.astype(np.uint32), code)


def _any_area(v: np.ndarray, f: np.ndarray, chunk: int = 1 << 16) -> bool:
    """Whether some triangle has a non-zero area (in chunks: usually the first decides)."""
    for a in range(0, len(f), chunk):
        t = v[f[a:a + chunk]]
        if np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]).any():
            return True
    return False


def primitive_mesh_data(prim: Primitive, source: str | None = None, index: int | None = None) -> Mesh:
    """The triangles of an 'obj' or 'ply' primitive: those read already (``prim.mesh``), else
    the file's, read now with the primitive's label keys."""
    if prim.mesh is not None:
        return prim.mesh
    p = prim.params
    return read_mesh(p["path"], prim.kind, label=prim.label, labels=p.get("labels"),
                     label_property=p.get("label_property"), source=source, index=index)


# Handing meshes from a forked child to its parent: as raw bytes in a nameless file both share,
# not pickled through the pipe (+0.43 s for the 76 MB of a 2.4 M-triangle mesh; the file: ~0.05 s).
# Nameless (a memfd, else an unlinked temporary file): the kernel frees it when the last of the
# two processes closes it, so no signal, SIGKILL included, can leave it behind.

@dataclass(frozen=True)
class _Shipped:
    """Where in the shared file a forked child left a mesh's arrays (in place of ``Primitive.mesh``)."""

    v_offset: int
    f_offset: int
    c_offset: int  # −1: no per-face classes
    n_vertices: int
    n_faces: int


@contextmanager
def mesh_drop():
    """A nameless file (its descriptor) for a forked child's meshes; closed at the end."""
    try:
        fd = os.memfd_create("simlidar-mesh", os.MFD_CLOEXEC)  # RAM, Linux
    except (AttributeError, OSError):
        with tempfile.TemporaryFile() as fh:  # unlinked at once where the system allows
            fd = os.dup(fh.fileno())
    try:
        yield fd
    finally:
        os.close(fd)


def _append(fd: int, arr: np.ndarray) -> int:
    """Write ``arr``'s bytes at the end of ``fd``; their offset."""
    off = os.lseek(fd, 0, os.SEEK_END)  # pwrite leaves the offset alone: the end is the size
    view = memoryview(np.ascontiguousarray(arr)).cast("B")
    done = 0
    while done < len(view):
        done += os.pwrite(fd, view[done:], off + done)
    return off


def _read_back(fd: int, off: int, dtype, shape) -> np.ndarray:
    arr = np.empty(shape, dtype)
    view = memoryview(arr).cast("B")
    done = 0
    while done < len(view):
        n = os.preadv(fd, [view[done:]], off + done)
        if n <= 0:
            raise EOFError(f"mesh hand-off: {len(view) - done} bytes missing at offset {off + done}")
        done += n
    return arr


def ship_meshes(primitives: list, drop: int) -> list:
    """The primitives with each mesh written to the shared file ``drop`` (a forked child's side)."""
    out = []
    for prim in primitives:
        m = prim.mesh
        if not isinstance(m, Mesh):
            out.append(prim)
            continue
        v_off = _append(drop, np.asarray(m.vertices, np.float64))
        f_off = _append(drop, np.asarray(m.faces, np.uint32))
        c_off = _append(drop, np.asarray(m.face_class, np.uint8)) if m.face_class is not None else -1
        out.append(replace(prim, mesh=_Shipped(v_off, f_off, c_off, len(m.vertices), len(m.faces))))
    return out


def unship_meshes(primitives: list, drop: int) -> list:
    """The primitives with the meshes :func:`ship_meshes` wrote read back (the parent's side)."""
    out = []
    for prim in primitives:
        s = prim.mesh
        if isinstance(s, _Shipped):
            v = _read_back(drop, s.v_offset, np.float64, (s.n_vertices, 3))
            f = _read_back(drop, s.f_offset, np.uint32, (s.n_faces, 3))
            c = _read_back(drop, s.c_offset, np.uint8, (s.n_faces,)) if s.c_offset >= 0 else None
            prim = replace(prim, mesh=Mesh(v, f, c))
        out.append(prim)
    return out


# ----------------------------------------------------------------------------------- OBJ

def _lines(path):
    """The file's lines as one Arrow string array (line k at row k − 1; empty lines kept)."""
    import pyarrow as pa  # noqa: PLC0415
    import pyarrow.csv as pcsv  # noqa: PLC0415
    try:
        table = pcsv.read_csv(
            path, read_options=pcsv.ReadOptions(column_names=["l"], block_size=1 << 24),
            parse_options=pcsv.ParseOptions(delimiter="\x1f", quote_char=False, double_quote=False,
                                            escape_char=False, ignore_empty_lines=False),
            convert_options=pcsv.ConvertOptions(column_types={"l": pa.string()}, strings_can_be_null=False,
                                                check_utf8=True))
    except pa.ArrowInvalid as exc:
        if "UTF8" in str(exc) or "utf8" in str(exc).lower():
            raise UnicodeDecodeError("utf-8", b"", 0, 1, "not UTF-8") from exc
        if "Empty CSV file" in str(exc):
            return pa.array([], pa.string())
        raise ValueError(f"not line-based text ({exc})") from exc
    return table.column("l").combine_chunks() if table.num_rows else pa.array([], pa.string())


def parse_obj_file(path, names: bool = True):
    """Vertices (n, 3) float64, triangles (m, 3) int64 (0-based, global) and, per triangle,
    the indices of its ``o``, ``g`` and ``usemtl`` names: ``{"o": (names, per triangle, per
    vertex), ...}`` (index −1: none given yet; ``names=False``: {}, not looked up).

    Polygons become fans, negative indices count back from the last vertex read; ``v``
    records may carry more than three numbers (w, colours).  Raises ``ValueError`` naming
    the line for a malformed ``v`` or ``f`` record.

    Regular files ("v x y z" and "f a b c" or "f a/t/n b/t/n c/t/n", one space apart) are
    read block by block by Arrow's CSV reader; anything else line by line through Arrow's
    string kernels (the same result, ~3× slower)."""
    # Mapped, not copied: the page cache is read in place (a copy of 115 MB took 1-5 s on a busy
    # machine); newlines are found 8 MiB at a time (small temporaries).
    raw = np.memmap(path, np.uint8, mode="r") if os.path.getsize(path) else np.zeros(0, np.uint8)
    try:
        bytes(raw[:1 << 16]).decode("utf-8")  # a binary file is refused before it is split
    except UnicodeDecodeError as exc:
        if exc.start < (1 << 16) - 4:
            raise
    step = 1 << 23
    nl = np.concatenate([np.zeros(0, np.int64)] + [np.flatnonzero(raw[a:a + step] == 10) + a
                                                   for a in range(0, len(raw), step)])
    starts = np.concatenate([[0], nl + 1]).astype(np.int64)
    if starts[-1] >= len(raw):
        starts = starts[:-1]
    ends = np.append(starts[1:], len(raw))  # each line with its newline
    c0 = raw[np.minimum(starts, len(raw) - 1)] if len(raw) else np.zeros(0, np.uint8)
    c1 = raw[np.minimum(starts + 1, len(raw) - 1)] if len(raw) else np.zeros(0, np.uint8)
    sep = (c1 == 32) | (c1 == 9)
    rv = np.flatnonzero((c0 == ord("v")) & sep)
    rf = np.flatnonzero((c0 == ord("f")) & sep)
    got = _fast_blocks(raw, starts, ends, rv, rf)
    if got is not None and not ((c0 == 32) | (c0 == 9)).any():
        v, f = got
        t_face = np.arange(len(f))
    else:
        v, f, rv, rf, t_face = _parse_lines(path)
    found = {}
    for tag in ("o", "g", "usemtl") if names else ():
        t = tag.encode()
        cand = np.flatnonzero((c0 == t[0]))
        rows = [r for r in cand.tolist() if bytes(raw[starts[r]:ends[r]]).split(maxsplit=1)[:1] == [t]]
        if not rows:
            continue
        text = [bytes(raw[starts[r]:ends[r]]).decode("utf-8").split(maxsplit=1) for r in rows]
        text = [" ".join(x[1].split()) if len(x) > 1 else "" for x in text]
        uniq, code = np.unique(np.asarray(text, object), return_inverse=True)
        rows = np.asarray(rows)
        per = []
        for r in (rf[t_face], rv):  # the record before each triangle's and each vertex's line
            last = np.searchsorted(rows, r, side="right") - 1
            per.append(np.where(last >= 0, code[np.maximum(last, 0)], -1))
        found[tag] = (list(uniq), *per)
    return v, f, found


def _runs(raw, starts, ends, rows) -> list:
    """The bytes of lines ``rows`` (ascending) as buffers: consecutive lines are one slice of the
    file, passed as it is (no copy) when there are few, else joined into one."""
    import pyarrow as pa  # noqa: PLC0415
    if not len(rows):
        return []
    cut = np.flatnonzero(np.diff(rows) != 1) + 1
    first, last = rows[np.r_[0, cut]], rows[np.r_[cut - 1, len(rows) - 1]]
    spans = list(zip(starts[first].tolist(), ends[last].tolist()))
    if len(spans) <= 64:
        return [pa.py_buffer(raw[a:b]) for a, b in spans]
    return [pa.py_buffer(b"".join(raw[a:b].tobytes() for a, b in spans))]


def _fast_blocks(raw, starts, ends, rv, rf):
    """(vertices, triangles) of a regular file through Arrow's CSV reader; None otherwise."""
    import pyarrow as pa  # noqa: PLC0415
    import pyarrow.compute as pc  # noqa: PLC0415
    import pyarrow.csv as pcsv  # noqa: PLC0415

    def table(buffers: list, typ):
        if not buffers:
            return np.zeros((0, 3), np.float64 if typ == pa.float64() else np.int64)
        opts = dict(read_options=pcsv.ReadOptions(column_names=["t", "a", "b", "c"], block_size=1 << 24),
                    parse_options=pcsv.ParseOptions(delimiter=" ", quote_char=False),
                    convert_options=pcsv.ConvertOptions(include_columns=["a", "b", "c"],
                                                        column_types={k: typ or pa.string() for k in "abc"}))
        return pa.concat_tables([pcsv.read_csv(pa.BufferReader(b), **opts) for b in buffers])
    try:
        tv = table(_runs(raw, starts, ends, rv), pa.float64())
        v = tv if isinstance(tv, np.ndarray) else _columns(tv, np.float64)
        data = _runs(raw, starts, ends, rf)
        try:
            tf = table(data, pa.int64())
        except pa.ArrowInvalid:  # "i/t/n" corners: the text before the first '/'
            tf = table(data, None)
            tf = tf.__class__.from_arrays(
                [pc.cast(pc.list_element(pc.split_pattern(tf.column(k), "/", max_splits=1), 0), pa.int64())
                 for k in "abc"], names=list("abc"))
        f = tf if isinstance(tf, np.ndarray) else _columns(tf, np.int64)
    except (pa.ArrowInvalid, pa.ArrowNotImplementedError):
        return None
    if v is None or f is None or len(v) != len(rv) or len(f) != len(rf):
        return None  # a null (empty field) or a count that does not match: the general path
    if (f <= 0).any():
        if (f == 0).any():
            return None  # the general path names the line
        neg = f < 0  # negative indices count back from the vertices read before the face's line
        f[neg] += (np.searchsorted(rv, rf)[:, None] + np.zeros((1, 3), np.int64))[neg] + 1
    f -= 1
    return v, f


def _columns(table, dtype) -> np.ndarray | None:
    """Columns a, b, c of an Arrow table as one (n, 3) array, chunk by chunk (one copy); None
    when a column holds nulls (an empty field) or another type."""
    import pyarrow as pa  # noqa: PLC0415
    want = pa.float64() if dtype is np.float64 else pa.int64()
    out = np.empty((table.num_rows, 3), dtype)
    for i, k in enumerate("abc"):
        col, row = table.column(k), 0
        if col.null_count or col.type != want:
            return None
        for chunk in col.chunks:
            # the values buffer as it is (Array.to_numpy imports pandas: 1 s in a fresh process)
            out[row:row + len(chunk), i] = np.frombuffer(chunk.buffers()[1], dtype, len(chunk), chunk.offset * 8)
            row += len(chunk)
    return out


def _parse_lines(path):
    """The general path: every line split into tokens by Arrow's string kernels."""
    import pyarrow as pa  # noqa: PLC0415
    import pyarrow.compute as pc  # noqa: PLC0415
    lines = _lines(path)
    tok = pc.utf8_split_whitespace(pc.utf8_trim_whitespace(lines))
    ntok = pc.list_value_length(tok).to_numpy(zero_copy_only=False)
    full = np.flatnonzero(ntok > 0)
    first = np.full(len(ntok), None, object)
    head = pc.list_element(pc.take(tok, pa.array(full)), 0)
    is_v = np.zeros(len(ntok), bool)
    is_f = np.zeros(len(ntok), bool)
    is_v[full] = pc.equal(head, "v").to_numpy(zero_copy_only=False)
    is_f[full] = pc.equal(head, "f").to_numpy(zero_copy_only=False)
    del first
    rv, rf = np.flatnonzero(is_v), np.flatnonzero(is_f)

    def fail(rows, why):
        raise ValueError(f"line {int(rows[0]) + 1}: {why}")
    if len(rv) and (ntok[rv] < 4).any():
        fail(rv[ntok[rv] < 4], "a vertex needs three coordinates")
    if len(rf) and (ntok[rf] < 4).any():
        fail(rf[ntok[rf] < 4], "a face needs three vertices")
    vtok = pc.list_flatten(pc.list_slice(pc.take(tok, pa.array(rv)), 1, 4))
    v = _numbers(vtok, pa.float64(), rv, 3, fail, "a vertex coordinate is not a number")
    v = v.reshape(-1, 3)
    ftok = pc.list_flatten(pc.list_slice(pc.take(tok, pa.array(rf)), 1))
    if len(ftok) and pc.any(pc.match_substring(ftok, "/")).as_py():
        ftok = pc.list_element(pc.split_pattern(ftok, "/", max_splits=1), 0)
    n_corner = ntok[rf] - 1
    idx = _numbers(ftok, pa.int64(), rf, n_corner, fail, "a face index is not an integer")
    if (idx == 0).any():
        fail(np.repeat(rf, n_corner)[idx == 0], "face index 0 (OBJ counts from 1)")
    row_of = np.repeat(rf, n_corner)
    v_before = np.searchsorted(rv, row_of)  # vertices read before each face's line
    idx = np.where(idx > 0, idx - 1, v_before + idx)
    t_face, f = _fans(idx, n_corner)
    return v, f, rv, rf, t_face


def _fans(idx: np.ndarray, n_corner: np.ndarray):
    """Polygons (corner indices end to end, ``n_corner`` each) as triangle fans
    (c0, c_j, c_j+1), j = 1 … n − 2: (polygon of each triangle, triangles (m, 3))."""
    start = np.concatenate([[0], np.cumsum(n_corner)[:-1]]).astype(np.int64)
    n_tri = n_corner - 2
    t_face = np.repeat(np.arange(len(n_corner)), n_tri)
    if not len(t_face):
        return t_face, np.zeros((0, 3), np.int64)
    j = np.arange(len(t_face)) - np.repeat(np.cumsum(n_tri) - n_tri, n_tri) + 1
    s = start[t_face]
    return t_face, np.stack([idx[s], idx[s + j], idx[s + j + 1]], 1)


def _numbers(tokens, typ, rows, per_row, fail, why):
    """Tokens cast to numbers; on failure, the first bad token's line is named."""
    import pyarrow as pa  # noqa: PLC0415
    import pyarrow.compute as pc  # noqa: PLC0415
    try:
        return pc.cast(tokens, typ).to_numpy(zero_copy_only=False)
    except (pa.ArrowInvalid, pa.ArrowNotImplementedError):
        ok = pc.is_valid(_number_like(tokens, typ)).to_numpy(zero_copy_only=False)
        bad = np.flatnonzero(~ok)
        if not len(bad):  # number-like but out of the type's range
            raise ValueError(why + " (or out of range)") from None
        fail(np.repeat(rows, per_row)[bad[:1]], why)


def _number_like(tokens, typ):
    """The tokens, null where a token is not written as a number of ``typ`` (for the error's line)."""
    import pyarrow as pa  # noqa: PLC0415
    import pyarrow.compute as pc  # noqa: PLC0415
    pattern = r"^[+-]?\d+$" if pa.types.is_integer(typ) else \
        r"^[+-]?(\d+\.?\d*([eE][+-]?\d+)?|\.\d+([eE][+-]?\d+)?|inf|nan|infinity)$"
    good = pc.match_substring_regex(tokens, pattern, ignore_case=True)
    return pc.if_else(good, tokens, pa.scalar(None, pa.string()))


def _obj_classes(names: dict, labels: dict, label: str, n: int, path) -> np.ndarray:
    """Class code per triangle: the first of usemtl, g, o whose name a ``labels`` pattern matches."""
    code = np.full(n, -1, np.int16)
    for tag in ("usemtl", "g", "o"):
        if tag not in names:
            continue
        uniq, idx, _ = names[tag]
        table = np.full(len(uniq) + 1, -1, np.int16)  # last row: no name yet (idx −1)
        for k, nm in enumerate(uniq):
            for cls, pats in labels.items():
                if any(fnmatch.fnmatchcase(nm, str(p)) for p in pats):
                    table[k] = CLASS_CODES[cls]
                    break
        code = np.where(code < 0, table[idx], code)
    _warn_unmatched(names, labels, label, path)
    return np.where(code < 0, CLASS_CODES[label], code).astype(np.uint8)


def _warn_unmatched(names: dict, labels: dict, label: str, path) -> None:
    """Warn, naming the patterns and the names the file holds, when a class's patterns match
    no usemtl, g or o name: its faces would silently take the primitive's ``label``."""
    found = {tag: [str(nm) for nm in names[tag][0]] for tag in ("usemtl", "g", "o") if tag in names}
    every = [nm for nms in found.values() for nm in nms]
    for cls, pats in labels.items():
        if any(fnmatch.fnmatchcase(nm, str(p)) for nm in every for p in pats):
            continue
        listed = "; ".join(f"{tag} {', '.join(_few(nms))}" for tag, nms in found.items() if nms)
        warnings.warn(SimlidarWarning(
            f"{path}: labels.{cls} patterns {[str(p) for p in pats]} match no name in the file, so no "
            f"face is {cls} (unmatched faces are {label}); the file names "
            + (listed if listed else "no usemtl, g or o") + " (patterns are case-sensitive, '*' any text)"))


def _few(names: list[str], n: int = 12) -> list[str]:
    return names if len(names) <= n else names[:n] + [f"... ({len(names) - n} more)"]


# ----------------------------------------------------------------------------------- PLY

def read_ply_arrays(path):
    """Vertices (n, 3) float64, triangles (m, 3) of an integer type and the other scalar face properties
    of a PLY file (binary little/big endian or ASCII) through ``plyfile``."""
    import plyfile  # noqa: PLC0415
    counts = _ply_counts(path)
    try:
        try:  # fast path: triangles read (memory-mapped when binary) as one record array
            data = plyfile.PlyData.read(path, known_list_len={"face": {"vertex_indices": 3}})
        except plyfile.PlyElementParseError:
            data = plyfile.PlyData.read(path)  # polygons of other sizes (or the error, worded for them)
    except plyfile.PlyParseError as exc:
        said = " and ".join(f"{n} {name}" for name, n in counts.items()) + " rows"
        hint = (f"; its header announces {said}: a count larger than the data reads one element's rows "
                "as another's or runs past the end" if isinstance(exc, plyfile.PlyElementParseError) else "")
        raise ValueError(f"not a readable PLY file ({exc}){hint}") from exc
    if "vertex" not in data or "face" not in data:
        raise ValueError("a PLY mesh needs 'vertex' and 'face' elements")
    vert = data["vertex"].data
    if not all(c in vert.dtype.names for c in "xyz"):
        raise ValueError("PLY vertices need x, y and z")
    v = np.column_stack([vert["x"], vert["y"], vert["z"]]).astype(np.float64)
    face = data["face"].data
    lists = [n for n in face.dtype.names if n in ("vertex_indices", "vertex_index")]
    if not lists:
        raise ValueError("PLY faces need a vertex_indices list")
    col = face[lists[0]]
    if col.dtype == object:  # polygons of several sizes: fans
        counts = np.fromiter((len(c) for c in col), np.int64, len(col))
        if (counts < 3).any():
            raise ValueError(f"face {int(np.argmax(counts < 3))} has fewer than three vertices")
        flat = np.concatenate(col).astype(np.int64) if len(col) else np.zeros(0, np.int64)
        t_face, f = _fans(flat, counts)
    else:
        f = np.asarray(col).reshape(len(col), -1)  # the file's integer type (checked, then uint32)
        t_face = None
    if f.dtype.kind not in "iu":
        raise ValueError(f"PLY vertex indices must be integers, not {f.dtype}")
    props = {n: (np.asarray(face[n]) if t_face is None else np.asarray(face[n])[t_face])
             for n in face.dtype.names if n not in lists and face.dtype[n] != object}
    return v, f, props


_PLY_HEADER_MAX = 1 << 20  # bytes searched for 'end_header'


def _ply_counts(path) -> dict[str, int]:
    """The element counts of a PLY header ({'vertex': 3, 'face': 1}), each checked: a whole
    number ≥ 0, and no more rows than the bytes after the header could hold (each row of an
    element with properties takes at least one byte), before plyfile sizes arrays by them."""
    with open(path, "rb") as fh:
        head = fh.read(_PLY_HEADER_MAX)
        size = os.fstat(fh.fileno()).st_size
    end = head.find(b"end_header")
    if not head.startswith(b"ply") or end < 0:
        return {}  # plyfile says what is wrong
    body = size - (head.find(b"\n", end) + 1 if head.find(b"\n", end) >= 0 else size)
    counts: dict[str, int] = {}
    name = None
    for raw in head[:end].split(b"\n"):
        words = raw.decode("ascii", "replace").split()
        if words[:1] == ["element"]:
            if len(words) != 3 or not words[2].isdigit():
                raise ValueError(f"header line {' '.join(words)!r}: an element count must be a whole "
                                 "number ≥ 0")
            name, counts[words[1]] = words[1], int(words[2])
        elif words[:1] == ["property"] and name is not None and counts[name] > max(body, 0):
            raise ValueError(f"header line 'element {name} {counts[name]}': the file holds only {max(body, 0)} "
                             f"bytes after its header, too few for {counts[name]} {name} rows")
    return counts


def _ply_classes(props: dict, labels: dict, prop: str | None, label: str, bad, path) -> np.ndarray:
    if prop is None:
        raise bad("labels of a PLY mesh need label_property (the face property to read)")
    if prop not in props:
        raise bad(f"no face property '{prop}' (has: {', '.join(props) or 'none'})")
    val = np.asarray(props[prop])
    code = np.full(len(val), CLASS_CODES[label], np.uint8)
    for cls, values in reversed(list(labels.items())):  # the first listed class wins
        hit = np.isin(val, np.asarray(values))
        code[hit] = CLASS_CODES[cls]
        if not hit.any():  # as for OBJ names: say so, with what the file holds
            found = np.unique(val)
            warnings.warn(SimlidarWarning(
                f"{path}: labels.{cls} values {list(values)} match no face's {prop}, so no face is "
                f"{cls} (unmatched faces are {label}); its faces hold {prop} "
                + ", ".join(_few([f"{x:g}" for x in found.tolist()]))))
    return code
