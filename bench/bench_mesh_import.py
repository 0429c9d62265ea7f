"""Mesh readers on a large OBJ and PLY: time and peak memory of each candidate.

    python bench/bench_mesh_import.py make DIR        # DIR/table3.obj, .ply (2.37 M triangles), obj/ply_scene.toml
    python bench/bench_mesh_import.py e2e DIR [ROOT]  # scan both scenes (all files) with this package or ROOT's
    python bench/bench_mesh_import.py readers DIR [NAME]   # each reader 3× in fresh processes: the fastest
    python bench/bench_mesh_import.py pipe SCENE.toml      # generate here vs in run_scan's forked child

The mesh is the Table 3 orchard (scenes/simlidar_table3_7x4.toml) as the scene builder makes
it: 12-facet prisms with caps, in real coordinates, written by our OBJ and PLY exporters.
Each reader runs in its own process; "peak MB" is the peak resident memory minus the
resident memory after the reader's imports (the arrays and the reader's temporaries).
"""
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def make(out: Path) -> None:
    sys.path.insert(0, str(ROOT))
    from simlidar_mi.config import load_scene
    from simlidar_mi.io.mesh_export import write_obj_stream, write_ply
    from simlidar_mi.lidar.survey import generate
    from simlidar_mi.scene.build import clean_branches
    from simlidar_mi.scene.prisms import exposed_ends, prism_arrays
    out.mkdir(parents=True, exist_ok=True)
    cfg = load_scene(ROOT / "scenes/simlidar_table3_7x4.toml")
    kept, _, _ = clean_branches(generate(cfg).branches)
    k = 12
    r = 0.5 * kept.diameter * np.pi / (k * np.sin(np.pi / k))
    v, f, _ = prism_arrays(kept.p0, kept.p1, r, k, caps=exposed_ends(kept.p0, kept.p1, kept.diameter))
    write_obj_stream(out / "table3.obj", [("wood", lambda: iter([(v, f)]))])
    write_ply(out / "table3.ply", v, f, 0)
    scene = (ROOT / "scenes/simlidar_table3_7x4.toml").read_text()
    keep = scene[scene.index("[ground]"):]  # the ground and the Table 3 sweep, the trees from the file
    for kind in ("obj", "ply"):
        (out / f"{kind}_scene.toml").write_text(f'[scene]\nname = "table3_from_{kind}"\nseed = 2013\n\n'
                                                f'[[primitive]]\ntype = "{kind}"\npath = "table3.{kind}"\n\n' + keep)
    print(f"{len(v)} vertices, {len(f)} triangles -> {out}")


def _mitsuba(path, kind):
    import mitsuba as mi
    mi.set_variant("llvm_ad_mono")
    mi.set_log_level(mi.LogLevel.Error)  # "attribute 'part' ignored"
    s = mi.load_dict({"type": kind, "filename": str(path), "face_normals": True})
    p = mi.traverse(s)
    return np.array(p["vertex_positions"]).reshape(-1, 3), np.array(p["faces"]).reshape(-1, 3)


def _ours(path, kind):
    from simlidar_mi.io.mesh_import import read_mesh
    m = read_mesh(path, kind)
    return m.vertices, m.faces


# The hand-written parser scene primitives used before (kept here as the baseline).
def parse_obj(lines):
    """Parse the ``v``, ``f`` and ``o``/``g`` records of Wavefront OBJ text; the one OBJ parser
    (scene primitives and export round trips both use it).

    Returns ``(vertices (n, 3) float64, faces (m, 3) int64 0-based and global, vertex_object
    (n,) int, face_object (m,) int, names)``: polygons become triangle fans, negative
    indices count back from the last vertex read, and each record belongs to the object
    whose ``o``/``g`` block it is in ("default" before any).  Raises ``ValueError`` naming
    the line number for a malformed record.
    """
    verts, faces, v_obj, f_obj = [], [], [], []
    names = ["default"]
    obj = 0
    lineno = 0
    try:
        for lineno, line in enumerate(lines, 1):
            parts = line.split()
            if not parts:
                continue
            tag = parts[0]
            if tag in ("o", "g"):
                name = " ".join(parts[1:]) or "default"
                if name not in names:
                    names.append(name)
                obj = names.index(name)
            elif tag == "v":
                if len(parts) < 4:
                    raise ValueError("a vertex needs three coordinates")
                verts.append([float(x) for x in parts[1:4]])
                v_obj.append(obj)
            elif tag == "f":
                idx = [int(x.split("/")[0]) for x in parts[1:]]
                if len(idx) < 3:
                    raise ValueError("a face needs three vertices")
                idx = [i - 1 if i > 0 else len(verts) + i for i in idx]
                faces += [[idx[0], idx[j], idx[j + 1]] for j in range(1, len(idx) - 1)]
                f_obj += [obj] * (len(idx) - 2)
    except UnicodeDecodeError:
        raise  # a ValueError too, but the caller words it (not UTF-8 text)
    except (ValueError, IndexError) as exc:
        raise ValueError(f"line {lineno}: {exc}") from exc
    return (np.asarray(verts, np.float64).reshape(-1, 3), np.asarray(faces, np.int64).reshape(-1, 3),
            np.asarray(v_obj, np.int64), np.asarray(f_obj, np.int64), names)


def _python_parser(path, kind):
    with open(path, encoding="utf-8") as fh:
        v, f, *_ = parse_obj(fh)
    return v, f


def _trimesh(path, kind):
    import trimesh
    m = trimesh.load(str(path), force="mesh", process=False, maintain_order=True)
    return np.asarray(m.vertices), np.asarray(m.faces)


def _meshio(path, kind):
    import meshio
    m = meshio.read(str(path))
    return m.points, np.concatenate([c.data for c in m.cells if c.type == "triangle"])


def _plyfile(path, kind):
    import plyfile
    d = plyfile.PlyData.read(str(path), known_list_len={"face": {"vertex_indices": 3}})
    vert = d["vertex"].data
    # memory-mapped: copy out what a scene needs (float64 vertices, uint32 faces)
    return (np.column_stack([vert["x"], vert["y"], vert["z"]]).astype(np.float64),
            d["face"].data["vertex_indices"].astype(np.uint32))


def _read_ply_ours_old(path, kind):
    from simlidar_mi.io.mesh_export import read_ply
    m = read_ply(path)
    return m.vertices, m.faces


READERS = {"obj": {"python parser (before)": _python_parser, "ours (pyarrow)": _ours,
                   "mitsuba obj": _mitsuba, "trimesh": _trimesh, "meshio": _meshio},
           "ply": {"ours (plyfile)": _ours, "plyfile": _plyfile, "read_ply (export round trip)": _read_ply_ours_old,
                   "mitsuba ply": _mitsuba, "trimesh": _trimesh, "meshio": _meshio}}
IMPORTS = {"_mitsuba": "mitsuba", "_trimesh": "trimesh", "_meshio": "meshio", "_plyfile": "plyfile",
           "_ours": "simlidar_mi.io.mesh_import", "_python_parser": "numpy",
           "_read_ply_ours_old": "simlidar_mi.io.mesh_export"}


def one(kind: str, name: str, path: str) -> None:
    sys.path.insert(0, str(ROOT))
    fn = READERS[kind][name]
    __import__(IMPORTS[fn.__name__])
    import pyarrow, pyarrow.csv, pyarrow.compute  # noqa: E401,F401  (imports outside the timing)
    base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    t = time.perf_counter()
    v, f = fn(path, kind)
    dt = time.perf_counter() - t
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024 - base
    print(f"{dt:.3f}\t{peak:.0f}\t{len(v)}\t{len(f)}\t{float(np.asarray(v, np.float64).sum()):.6e}")


def readers(d: Path, only: str | None = None, repeat: int = 3) -> None:
    """Each reader ``repeat`` times, each in a fresh process: the fastest run's seconds and peak."""
    print("| file | reader | seconds | peak MB | vertices | triangles | vertex sum |\n|---|---|---|---|---|---|---|")
    for kind in ("obj", "ply"):
        path = d / f"table3.{kind}"
        for name in READERS[kind]:
            if only and only not in name:
                continue
            runs = []
            for _ in range(repeat):
                r = subprocess.run([sys.executable, __file__, "one", kind, name, str(path)],
                                   capture_output=True, text=True)
                if r.returncode != 0:
                    runs = [[f"failed: {r.stderr.strip().splitlines()[-1][-100:]}"]]
                    break
                runs.append(r.stdout.strip().splitlines()[-1].split("\t"))
            cells = min(runs, key=lambda c: float(c[0]) if len(c) > 1 else 0.0)
            print(f"| {path.name} ({path.stat().st_size / 1e6:.0f} MB) | {name} | " + " | ".join(cells) + " |",
                  flush=True)


def e2e(d: Path, checkout: str | None = None) -> None:
    """``simlidar-mi scan`` of the OBJ and PLY scenes (all files), wall time and peak memory
    (/usr/bin/time), with this checkout or another one's package (``checkout``: its root)."""
    env = dict(os.environ, PYTHONPATH=checkout or str(ROOT))
    code = "import sys; from simlidar_mi.cli import main; sys.exit(main())"
    for kind in ("obj", "ply"):
        out = d / f"out_{kind}" if checkout is None else d / f"out_{kind}_{Path(checkout).name}"
        r = subprocess.run(["/usr/bin/time", "-f", "%e\t%M", sys.executable, "-c", code, "scan",
                            f"{kind}_scene.toml", "--out", str(out)], cwd=d, env=env, capture_output=True, text=True)
        if r.returncode != 0:
            print(kind, "failed:", r.stderr.strip().splitlines()[-1])
            continue
        wall, kb = r.stderr.strip().splitlines()[-1].split("\t")
        m = json.loads((out / "measures.json").read_text())
        print(f"| {kind} | {checkout or 'this checkout'} | {float(wall):.1f} | {int(kb) / 1024:.0f} | "
              + " | ".join(f"{m['seconds'][k]:.2f}" for k in ("generate", "build", "scan", "write"))
              + f" | {m['hits']} | {open('/proc/loadavg').read().split()[0]} |", flush=True)


def pipe(scene: Path, repeat: int = 3) -> None:
    """The cost of carrying a mesh primitive's arrays back from run_scan's forked generation:
    pickled through the fork helper's pipe, or left in a nameless shared file (what run_scan does)."""
    import pickle
    sys.path.insert(0, str(ROOT))
    from simlidar_mi._runtime.fork import Forked
    from simlidar_mi.config import load_scene
    from simlidar_mi.io.mesh_import import mesh_drop, unship_meshes
    from simlidar_mi.lidar.survey import _plan
    cfg = load_scene(scene)
    here, piped, filed, size = [], [], [], 0
    for _ in range(repeat):
        t = time.perf_counter()
        g, _ = _plan(cfg)
        here.append(time.perf_counter() - t)
        size = len(pickle.dumps(g, protocol=pickle.HIGHEST_PROTOCOL))
        t = time.perf_counter()
        job = Forked("generating", _plan, cfg, parallel=True)
        job.wait()
        job.close()
        piped.append(time.perf_counter() - t)
        t = time.perf_counter()
        with mesh_drop() as drop:
            job = Forked("generating", _plan, cfg, None, drop, parallel=True)
            g, _ = job.wait()
            job.close()
            g.primitives = unship_meshes(g.primitives, drop)
        filed.append(time.perf_counter() - t)
    print(f"{scene.name}: generate here {min(here):.3f} s; in a forked child and back pickled through "
          f"the pipe {min(piped):.3f} s ({size / 1e6:.0f} MB), through the shared file {min(filed):.3f} s")


if __name__ == "__main__":
    cmd = sys.argv[1]
    if cmd == "make":
        make(Path(sys.argv[2]))
    elif cmd == "e2e":
        e2e(Path(sys.argv[2]), sys.argv[3] if len(sys.argv) > 3 else None)
    elif cmd == "pipe":
        pipe(Path(sys.argv[2]))
    elif cmd == "one":
        one(*sys.argv[2:5])
    else:
        readers(Path(sys.argv[2]), sys.argv[3] if len(sys.argv) > 3 else None)
