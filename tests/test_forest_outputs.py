"""The forest's files after growth (issue #8): the Parquet leaf table against the CSV, same
bytes run to run, the pictures drawn in a forked process (same bytes as in turn, errors
surfaced, nothing left behind) and the prototype meshes' identity shortcut."""
from __future__ import annotations

import copy
import os
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

pq = pytest.importorskip("pyarrow.parquet")

import simlidar_mi.forest.outputs as outputs_mod  # noqa: E402
from simlidar_mi.errors import ConfigError, SimlidarError  # noqa: E402
from simlidar_mi.forest.outputs import _LEAF_FMT, _Stand, _write_mesh  # noqa: E402
from simlidar_mi.forest.run import _use_fork, run_forest  # noqa: E402
from simlidar_mi.io.text_columns import format_rows  # noqa: E402

SCENE = Path(__file__).resolve().parents[1] / "scenes" / "forest_small.toml"
SMALL = ["forest.domain_m=[0.0, 16.0, 0.0, 16.0]", "forest.instancing=true",
         "forest.prototypes_per_species=2"]
needs_fork = pytest.mark.skipif(not _use_fork(True), reason="no fork start method here")


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """The same small forest three times: Parquet in a forked picture process (twice) and CSV
    drawn in turn."""
    base = tmp_path_factory.mktemp("forest_outputs")
    a = run_forest(SCENE, base / "a", SMALL, parallel=_use_fork(True))
    b = run_forest(SCENE, base / "b", SMALL, parallel=_use_fork(True))
    c = run_forest(SCENE, base / "c", SMALL + ['forest.leaf_table_format="csv"'], parallel=False)
    return a, b, c


def test_parquet_holds_the_leaf_table_and_formats_to_the_csv_bytes(runs):
    a, _, c = runs
    assert a.files["leaves"].name == "leaves.parquet" and c.files["leaves"].name == "leaves.csv"
    assert a.summary["leaf_table_format"] == "parquet" and c.summary["leaf_table_format"] == "csv"
    t = pq.read_table(a.files["leaves"])
    assert t.column_names == ["tree_id", "leaf_id", "x", "y", "z", "length_m", "width_m", "area_m2",
                              "nx", "ny", "nz", "hx", "hy", "hz"]
    assert [str(f.type) for f in t.schema] == ["int32"] * 2 + ["double"] * 12
    assert t.num_rows == int(a.forest.n_leaves.sum()) == a.summary["leaf_rows_written"] > 1000
    cols = [t.column(k).to_numpy() for k in t.column_names]
    # the exact float64 of the forest's world-frame leaf table, not a rounded copy
    world = a.forest.leaf_table()
    assert cols[2].tobytes() == np.ascontiguousarray(world.centre_m[:, 0]).tobytes()
    assert cols[7].tobytes() == world.area_m2.tobytes()
    assert cols[13].tobytes() == np.ascontiguousarray(world.heading[:, 2]).tobytes()
    # formatted as the CSV formats them: the CSV's bytes
    header = (",".join(t.column_names) + "\n").encode()
    assert header + format_rows(cols, _LEAF_FMT) == c.files["leaves"].read_bytes()


def test_parquet_is_the_same_bytes_run_to_run_and_holds_no_time(runs):
    a, b, _ = runs
    assert a.files["leaves"].read_bytes() == b.files["leaves"].read_bytes()
    meta = pq.ParquetFile(a.files["leaves"]).metadata
    assert set(meta.metadata) == {b"ARROW:schema"}          # no other key-value metadata
    assert meta.created_by.startswith("parquet-cpp-arrow version")
    assert meta.row_group(0).column(2).compression == "ZSTD"


def test_pictures_from_the_forked_process_are_the_bytes_drawn_in_turn(runs):
    a, b, c = runs
    assert a.summary["export"] == "stand"   # placed with BLAS (one thread while forked)
    for name in ("layout.png", "preview.png", "trees.csv", "stand.ply"):
        data = (a.files["summary"].parent / name).read_bytes()
        assert data == (c.files["summary"].parent / name).read_bytes()
        assert data == (b.files["summary"].parent / name).read_bytes()
    assert a.summary["seconds"]["plots"] > 0 and c.summary["seconds"]["plots"] > 0


@needs_fork
def test_a_picture_error_in_the_child_is_raised_and_nothing_is_written(tmp_path, monkeypatch):
    def boom(*a, **k):
        raise RuntimeError("no fonts")
    monkeypatch.setattr("simlidar_mi.forest.run.plot_preview", boom)  # the fork inherits it
    with pytest.raises(RuntimeError, match=r"no fonts") as err:  # what drawing in turn raises
        run_forest(SCENE, tmp_path / "out", SMALL, parallel=True)
    if hasattr(err.value, "__notes__"):
        assert "drawing layout.png and preview.png failed in a forked process" in err.value.__notes__[0]
    assert list(tmp_path.iterdir()) == []       # no output folder, no staging folder


@needs_fork
def test_a_child_that_dies_is_an_error(tmp_path, monkeypatch):
    monkeypatch.setattr("simlidar_mi.forest.run.plot_layout", lambda *a, **k: os._exit(3))
    with pytest.raises(SimlidarError, match=r"died \(exit code 3\)"):
        run_forest(SCENE, tmp_path / "out", SMALL, parallel=True)
    assert list(tmp_path.iterdir()) == []


def test_a_main_process_error_ends_the_child(tmp_path, monkeypatch):
    def boom(*a, **k):
        raise RuntimeError("disk full")
    monkeypatch.setattr("simlidar_mi.forest.run.write_leaf_tables", boom)
    with pytest.raises(RuntimeError, match="disk full"):
        run_forest(SCENE, tmp_path / "out", SMALL, parallel=_use_fork(True))
    assert list(tmp_path.iterdir()) == []


def test_format_key_without_pyarrow(tmp_path, monkeypatch):
    monkeypatch.setattr(outputs_mod, "_have_pyarrow", lambda: False)
    assert outputs_mod.leaf_table_format("auto") == "csv"
    assert outputs_mod.leaf_table_format("csv") == "csv"
    with pytest.raises(ConfigError, match=r"key 'forest.leaf_table_format', value 'parquet': "
                                          r"needs pyarrow"):
        run_forest(SCENE, tmp_path / "out", SMALL + ['forest.leaf_table_format="parquet"'])
    monkeypatch.undo()
    assert outputs_mod.leaf_table_format("auto") == "parquet"


def test_prototype_mesh_in_its_own_frame_is_the_bytes_of_the_identity_transform(runs, tmp_path):
    p = runs[0].forest.prototypes[0]
    t = SimpleNamespace(branches=copy.deepcopy(p.branches), leaves=copy.deepcopy(p.leaves))
    # −0.0 coordinates, which the transform's + (0, 0, 0) turns into +0.0
    t.leaves.vertices[0, 0] = [-0.0, 0.5, -0.0]
    shortcut = _Stand(1, lambda i: t, None, lambda i: None)
    placed = _Stand(1, lambda i: t, lambda i: (np.zeros(3), 0.0, 1.0), lambda i: None)
    a = _write_mesh(shortcut, tmp_path / "a.ply", "ply", 6, False, ["x"], atomic=False).read_bytes()
    b = _write_mesh(placed, tmp_path / "b.ply", "ply", 6, False, ["x"]).read_bytes()
    assert a == b
    first_leaf = a.index(b"end_header\n") + 11 + 12 * 2 * 6 * len(t.branches)
    v = np.frombuffer(a, "<f4", 3, first_leaf)
    assert v.tolist() == [0.0, 0.5, 0.0] and not np.signbit(v).any()


def test_meshes_written_in_small_blocks_are_the_bytes_of_one_block(runs, tmp_path, monkeypatch):
    """The PLY writer converts and writes vertices and faces in blocks, and a prototype's leaf
    vertices come in blocks: the file is the bytes of writing each tree whole."""
    import simlidar_mi.io.mesh_export as mesh_mod  # noqa: PLC0415
    forest = runs[0].forest
    p = forest.prototypes[0]
    for stand_of in (lambda: _Stand(1, lambda i: p, None, lambda i: None), lambda: _Stand.of(forest)):
        whole = _write_mesh(stand_of(), tmp_path / "whole.ply", "ply", 6, False, ["x"]).read_bytes()
        with monkeypatch.context() as m:
            m.setattr(mesh_mod, "_WRITE_BLOCK", 7)
            m.setattr(outputs_mod, "_MESH_BLOCK", 5)
            small = _write_mesh(stand_of(), tmp_path / "small.ply", "ply", 6, False, ["x"]).read_bytes()
        assert small == whole and len(whole) > 100_000
    assert len(p.leaves) > 3 * 5


def test_a_mesh_error_stops_the_leaf_table_thread_and_is_the_one_raised(tmp_path, monkeypatch):
    seen = []

    def slow_tables(path, tables, id_name, fmt):   # counts the tables the thread took
        for t in tables:
            seen.append(len(t))
            import time  # noqa: PLC0415
            time.sleep(0.05)
        raise AssertionError("the tables ran to their end")

    def boom(*a, **k):
        raise RuntimeError("disk full")
    monkeypatch.setattr("simlidar_mi.forest.run.write_leaf_tables", slow_tables)
    monkeypatch.setattr("simlidar_mi.forest.run.write_stand", boom)
    with pytest.raises(RuntimeError, match="disk full"):
        run_forest(SCENE, tmp_path / "out", SMALL + ["forest.instancing=false"], parallel=False)
    assert list(tmp_path.iterdir()) == []
    assert len(seen) <= 2   # stopped at its next table (or before its first), not after all the trees
