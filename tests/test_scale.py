"""Issue #8 speed work that must not change results: LAS points of the kept beams only, and
no Dask import on a local run without Dask configuration."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from simlidar_mi._runtime.cluster import _dask_config_dirs
from simlidar_mi.geometry import CLASS_CODES
from simlidar_mi.io.las import BeamGeometry
from simlidar_mi.lidar.platforms import airborne_pattern, rosette_patterns, rotating_patterns
from simlidar_mi.lidar.scan import ScanResult

REPO = Path(__file__).resolve().parents[1]


def _patterns():
    """A swath (yaw per line), a moving spinning head (origins move within a row), and a
    moving rosette (a direction per beam)."""
    yield airborne_pattern([0, 0], [3, 5], 100.0, 30.0, 10.0, 1000.0, 20)
    yield rotating_patterns(waypoints_m=[[0.0, 0.0, 1.0], [2.0, 0.5, 1.0]], speed_m_s=2.0,
                            azimuth_range_deg=[-120.0, -60.0], ground=False)[0]
    yield rosette_patterns(position_m=None, waypoints_m=[[0.0, 0.0, 1.0], [0.0, 1.0, 1.0]],
                           speed_m_s=5.0, look_deg=(-90.0, 0.0), ground=False)[0]


@pytest.mark.parametrize("pattern", list(_patterns()), ids=["airborne", "rotating-moving", "rosette-moving"])
def test_kept_points_are_the_full_points_array_picked_bit_for_bit(pattern):
    n, m = pattern.n_rows, pattern.n_cols
    rng = np.random.default_rng(3)
    cls = rng.choice(np.array([CLASS_CODES["escape"], CLASS_CODES["wood"], CLASS_CODES["ground"]], np.uint8),
                     size=(n, m))
    rng_m = rng.uniform(0.3, 80.0, (n, m)).astype(np.float32)
    res = ScanResult(None, rng_m, cls, np.zeros((n, m), np.uint32), np.ones((n, m), np.float32),
                     np.zeros(3), pattern=pattern)
    keep = cls != CLASS_CODES["escape"]
    i, k = np.nonzero(keep)
    assert 0 < len(i) < n * m
    fast = BeamGeometry(pattern).points_m(i, k, rng_m[i, k]).T
    assert fast.dtype == np.float64 and fast.shape == (len(i), 3)
    assert fast.tobytes() == res.points_m()[keep].tobytes()  # the same float64 operations


def _probe(tmp_path: Path, files: dict[str, str]) -> dict:
    """configured_address() in a fresh process whose home holds ``files`` and whose
    environment has no DASK_* variable: the address, and whether dask was imported."""
    home = tmp_path / "home"
    for rel, text in files.items():
        (home / rel).parent.mkdir(parents=True, exist_ok=True)
        (home / rel).write_text(text)
    home.mkdir(exist_ok=True)
    env = {k: v for k, v in os.environ.items() if not k.startswith("DASK_")}
    env.update(HOME=str(home), PYTHONPATH=str(REPO))
    code = ("import json, sys; from simlidar_mi._runtime.cluster import configured_address; "
            "a = configured_address(); print(json.dumps([a, 'dask' in sys.modules]))")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    return dict(zip(("address", "dask_imported"), json.loads(out.stdout.strip().splitlines()[-1])))


def test_no_dask_config_means_no_dask_import(tmp_path):
    system_dirs = [d for d in _dask_config_dirs()[:-1] if d.is_dir() and any(d.iterdir())]
    if system_dirs:
        pytest.skip(f"this machine has Dask config in {system_dirs[0]}")
    r = _probe(tmp_path, {})
    assert r == {"address": None, "dask_imported": False}


def test_a_dask_config_file_is_still_honoured(tmp_path):
    r = _probe(tmp_path, {".config/dask/cluster.yaml": "scheduler-address: tcp://10.1.2.3:8786\n"})
    assert r == {"address": "tcp://10.1.2.3:8786", "dask_imported": True}
