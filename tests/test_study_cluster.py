"""The §5 study on a Dask ``distributed`` cluster: ``--scheduler``, an active Client and
``DASK_SCHEDULER_ADDRESS`` send the orchards to the cluster's workers, each row names its
worker, and everything else is the same bytes as a local run (resume and interrupts too)."""
from __future__ import annotations

import csv
import io
import json
import os
import shutil
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from simlidar_mi._runtime import cluster as _dask
from simlidar_mi.cli import main
from simlidar_mi.errors import ConfigError
from simlidar_mi.lidar import study
from simlidar_mi.lidar.study import _cluster_task, _scene_bundle, code_version, run_one, run_study
from simlidar_mi.config import load_scene
from tests.conftest import REPO, SCENES

distributed = pytest.importorskip("distributed")

SCENE = SCENES / "apple_orchard.toml"
# Four tiny orchards (3 and 4 iterations, one tree, coarse beams): about 0.5 s each.
GRID = [[f"orchard.tree.iterations={it}", "orchard.n_trees=1", "scan.dtheta_deg=1.0", "scan.dy_m=0.01",
         f"orchard.tree.d_min_m={d}"] for it in (3, 4) for d in (0.005, 0.007)]
VARYING = {"worker", "seconds", "scan_seconds"}  # who and how long: all else is the same bytes



@pytest.fixture(scope="module")
def local_run(tmp_path_factory):
    """The reference: the same study on the local scheduler in this process."""
    out = tmp_path_factory.mktemp("local") / "study"
    run_study(SCENE, out, GRID, scheduler="local")
    return out


@pytest.fixture(autouse=True)
def _no_env_scheduler(monkeypatch):
    monkeypatch.delenv(_dask.ENV, raising=False)


def _workers(cluster) -> set[str]:
    with distributed.Client(cluster, set_as_default=False) as c:
        return set(c.scheduler_info(n_workers=-1)["workers"])


def _rows(out: Path) -> dict[str, dict]:
    return {p.name: json.loads(p.read_text()) for p in (out / "rows").glob("*.json")}


def _assert_same_as_local(out: Path, local: Path) -> None:
    """Rows, study.csv, regression.json and correlations.png equal the local run's, byte for
    byte once the worker and the timings are left out."""
    mine, ref = _rows(out), _rows(local)
    assert sorted(mine) == sorted(ref) and len(ref) == len(GRID)
    for name, row in mine.items():
        strip = lambda r: json.dumps({k: v for k, v in r.items() if k not in VARYING}, sort_keys=True)
        assert strip(row) == strip(ref[name]), name
    for f in ("regression.json", "correlations.png"):
        assert (out / f).read_bytes() == (local / f).read_bytes(), f

    def table(path):
        rows = list(csv.DictReader(io.StringIO(path.read_text())))
        return [{k: v for k, v in r.items() if k not in VARYING} for r in rows]
    assert table(out / "study.csv") == table(local / "study.csv")
    header = (out / "study.csv").read_text().splitlines()[0].split(",")
    assert header == (local / "study.csv").read_text().splitlines()[0].split(",") and "worker" in header


def test_cli_scheduler_scans_on_the_cluster_workers_with_the_local_results(cluster, local_run, tmp_path,
                                                                            monkeypatch, capsys):
    monkeypatch.setattr(study, "paper_grid", lambda: [list(g) for g in GRID])  # the CLI's grid
    out = tmp_path / "study"
    rc = main(["study", str(SCENE), "--out", str(out), "--scheduler", cluster.scheduler_address])
    assert rc == 0, capsys.readouterr().err
    workers = {r["worker"] for r in _rows(out).values()}
    assert workers and workers <= _workers(cluster)  # every orchard ran on one of the cluster's workers
    assert all(w.startswith("local:") for w in (r["worker"] for r in _rows(local_run).values()))
    _assert_same_as_local(out, local_run)
    with open(out / "study.csv") as f:
        assert {r["worker"] for r in csv.DictReader(f)} == workers


def test_an_active_client_is_used_and_left_open(cluster, local_run, tmp_path):
    out = tmp_path / "study"
    with distributed.Client(cluster.scheduler_address) as client:  # the default client, as in a notebook
        res = run_study(SCENE, out, GRID)
        assert client.status == "running"
        workers = set(client.scheduler_info(n_workers=-1)["workers"])
    assert {r["worker"] for r in res.rows} <= workers and len(res.rows) == len(GRID)
    _assert_same_as_local(out, local_run)


def test_env_address_then_local_resume_of_one_row(cluster, local_run, tmp_path, monkeypatch):
    monkeypatch.setenv(_dask.ENV, cluster.scheduler_address)
    out = tmp_path / "study"
    first = run_study(SCENE, out, GRID)
    assert {r["worker"] for r in first.rows} <= _workers(cluster)
    # One row lost; 'local' overrides the environment, and resuming computes only that row here.
    files = sorted((out / "rows").glob("*.json"))
    kept = {f.name: f.stat().st_mtime_ns for f in files[1:]}
    files[0].unlink()
    again = run_study(SCENE, out, GRID, scheduler="local")
    assert {f.name: f.stat().st_mtime_ns for f in files[1:]} == kept
    by_worker = [r["worker"].startswith("local:") for r in again.rows]
    assert sum(by_worker) == 1 and json.loads(files[0].read_text())["worker"].startswith("local:")
    _assert_same_as_local(out, local_run)


def test_ctrl_c_on_a_cluster_keeps_the_rows_already_back(cluster, local_run, tmp_path, monkeypatch):
    out = tmp_path / "study"
    save = study._save_row

    def save_then_interrupt(rows_dir, row):  # Ctrl-C lands just after the first row arrived
        save(rows_dir, row)
        raise KeyboardInterrupt
    monkeypatch.setattr(study, "_save_row", save_then_interrupt)
    with pytest.raises(KeyboardInterrupt):
        run_study(SCENE, out, GRID, scheduler=cluster.scheduler_address)
    monkeypatch.undo()
    saved = {f.name: f.stat().st_mtime_ns for f in (out / "rows").glob("*.json")}
    assert len(saved) == 1 and not (out / "study.csv").exists()
    run_study(SCENE, out, GRID, scheduler=cluster.scheduler_address)
    assert {n: (out / "rows" / n).stat().st_mtime_ns for n in saved} == saved  # reused, not rescanned
    _assert_same_as_local(out, local_run)


def test_a_failing_orchard_raises_its_error_and_keeps_finished_rows(cluster, tmp_path):
    out = tmp_path / "study"
    # Valid as a scene, refused by the study's task on the worker (it scans with the tractor).
    bad = GRID[0][:-1] + ['platform.kind="static"']
    with pytest.raises(ConfigError) as err:
        run_study(SCENE, out, GRID[:2] + [bad], scheduler=cluster.scheduler_address, readings=False)
    # The worker's ConfigError arrives whole (file, key, value), not as a bare message.
    assert err.value.key == "platform.kind" and err.value.value == "static"
    assert "scans with the tractor" in str(err.value)
    # The bad orchard waits for a free worker, so at least one good one finished first.
    saved = {f.name: f.stat().st_mtime_ns for f in (out / "rows").glob("*.json")}
    assert 1 <= len(saved) <= 2
    res = run_study(SCENE, out, GRID[:2], scheduler=cluster.scheduler_address, readings=False)
    assert {n: (out / "rows" / n).stat().st_mtime_ns for n in saved} == saved and len(res.rows) == 2


def _closed_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_unreachable_scheduler_is_one_line_naming_it(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(_dask, "CONNECT_TIMEOUT_S", 2)
    monkeypatch.setattr(study, "paper_grid", lambda: [list(GRID[0])])
    address = f"tcp://127.0.0.1:{_closed_port()}"
    rc = main(["study", str(SCENE), "--out", str(tmp_path / "o"), "--scheduler", address])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1, err
    assert err.startswith(f"simlidar-mi study: error: key 'scheduler', value '{address}': cannot reach")
    with pytest.raises(ConfigError, match="scheduler"):
        with _dask.cluster_client(8786):  # type: ignore[arg-type]
            pass


def test_obj_files_travel_with_the_scene_as_data(tmp_path):
    # A worker without this machine's files: the OBJ is gone by the time the task runs.
    obj = tmp_path / "post.obj"
    obj.write_text("v 2.4 0.5 0\nv 2.6 0.5 0\nv 2.5 0.5 1.5\nf 1 2 3\n")
    scene = tmp_path / "orchard.toml"
    scene.write_text(SCENE.read_text() + '\n[[primitive]]\ntype = "obj"\npath = "post.obj"\n')
    o = GRID[0] + study.scan_overrides()
    here = run_one(str(scene), o, None, False, code_version())
    bundle = _scene_bundle(str(scene), [load_scene(scene, o)])
    obj.unlink()
    there = _cluster_task(bundle, o, False, code_version())
    assert here["key"] == there["key"]
    assert {k: v for k, v in here.items() if k not in VARYING} == \
        {k: v for k, v in there.items() if k not in VARYING}


def test_a_worker_with_other_code_refuses_before_scanning(tmp_path):
    o = GRID[0] + study.scan_overrides()
    bundle = _scene_bundle(str(SCENE), [load_scene(SCENE, o)])
    assert bundle["text"] == SCENE.read_text() and bundle["objs"] == {}
    other = "0.0.0+other mitsuba ? drjit ?"
    with pytest.raises(ConfigError, match=r"Dask worker local:\S+ runs other code \(.+\) than the study "
                       r"\(0\.0\.0\+other .*\): install the same simlidar-mi"):
        _cluster_task(bundle, o, False, other)


def test_code_version_is_the_same_from_an_installed_wheel_layout(tmp_path):
    # In a wheel the plugins sit in simlidar_mi/plugins/; in a checkout, in plugins/. A cluster
    # worker with the wheel must agree with a study run from the checkout.
    pkg = tmp_path / "simlidar_mi"
    shutil.copytree(REPO / "simlidar_mi", pkg, ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copytree(REPO / "plugins", pkg / "plugins", ignore=shutil.ignore_patterns("__pycache__"))
    code = "import simlidar_mi.lidar.study as s; print(s.__file__); print(s.code_version())"
    env = {**os.environ, "PYTHONPATH": str(tmp_path)}
    out = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=env, capture_output=True,
                         text=True, check=True).stdout.splitlines()
    assert out[0].startswith(str(pkg)) and out[1] == code_version()
    (pkg / "plugins" / "range_integrator.py").write_text("# edited\n")
    edited = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=env, capture_output=True,
                            text=True, check=True).stdout.splitlines()
    assert edited[1] != code_version()  # the plugins count
