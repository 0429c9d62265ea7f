"""A full disk: one line naming the output folder and "no space left", exit 2, the earlier
outputs unchanged and nothing staged or locked left.  On a real full filesystem (a small
tmpfs, where this runs as root and may mount one), and by an injected ENOSPC elsewhere."""
from __future__ import annotations

import errno
import os
import subprocess
from pathlib import Path

import pytest

from simlidar_mi.cli import main
from simlidar_mi.lidar import study
from tests.conftest import SCENES

CYLINDER = str(SCENES / "calibration_cylinder.toml")
GRID = [["orchard.tree.iterations=4", "orchard.n_trees=1", "scan.dtheta_deg=2.0", "scan.dy_m=0.05"]]
LEFT_FREE = 64 * 1024  # bytes left on the small disk before the run that must fail


@pytest.fixture
def small_disk(tmp_path):
    """An 8 MiB tmpfs at tmp_path/disk (skipped where mounting is not permitted)."""
    disk = tmp_path / "disk"
    disk.mkdir()
    mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=8m", "tmpfs", str(disk)],
                             capture_output=True, text=True) if os.geteuid() == 0 else None
    if mounted is None or mounted.returncode != 0:
        pytest.skip("cannot mount a small tmpfs here (needs root)")
    try:
        yield disk
    finally:
        subprocess.run(["umount", "-l", str(disk)], check=False)


def _fill(disk: Path) -> None:
    """Leave LEFT_FREE bytes free on ``disk``."""
    st = os.statvfs(disk)
    with open(disk / "filler", "wb") as fh:
        fh.write(b"\0" * (st.f_bavail * st.f_frsize - LEFT_FREE))


def _contents(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def _says_no_space(err: str, out: Path) -> None:
    lines = [ln for ln in err.splitlines() if ": error: " in ln or "Traceback" in ln]
    assert len(lines) == 1, err
    assert f"no space left on the device of output folder {out}" in lines[0]


@pytest.mark.parametrize("command, argv, changed", [
    ("scan", [CYLINDER], ["--set", "scan.dtheta_deg=0.4"]),
    ("scan", [CYLINDER, "--set", "scan.chunk_beams=20000"],            # streamed, chunk by chunk
     ["--set", "scan.chunk_beams=20000", "--set", "scan.dtheta_deg=0.4"]),
    ("truth", [CYLINDER, "--voxel", "0.1"], ["--voxel", "0.01"]),     # the NetCDF write fails
])
def test_a_full_disk_is_one_line_and_keeps_the_earlier_outputs(small_disk, capsys, command, argv, changed):
    out = small_disk / "out"
    assert main([command, *argv, "--out", str(out)]) == 0
    before = _contents(out)
    _fill(small_disk)
    capsys.readouterr()
    assert main([command, argv[0], *changed, "--out", str(out)]) == 2
    _says_no_space(capsys.readouterr().err, out)
    assert _contents(out) == before and sorted(p.name for p in out.iterdir()) == sorted(before)


def test_a_full_disk_during_a_study_is_one_line(small_disk, capsys, monkeypatch):
    monkeypatch.setattr(study, "paper_grid", lambda: GRID)
    out = small_disk / "study"
    assert main(["study", str(SCENES / "apple_orchard.toml"), "--out", str(out), "--no-readings"]) == 0
    before = _contents(out)
    _fill(small_disk)
    capsys.readouterr()
    # another orchard: its row, then the final files, do not fit
    monkeypatch.setattr(study, "paper_grid", lambda: [GRID[0][:-1] + ["scan.dy_m=0.02"]])
    assert main(["study", str(SCENES / "apple_orchard.toml"), "--out", str(out), "--no-readings"]) == 2
    _says_no_space(capsys.readouterr().err, out)
    after = _contents(out)
    assert {k: after.get(k) for k in before} == before  # new rows may stay: each is whole


def test_enospc_from_a_writer_is_one_line(tmp_path, capsys, monkeypatch):
    """Without a small disk: a real OSError(ENOSPC) raised by the EXR writer."""
    from simlidar_mi.io import exr

    out = tmp_path / "o"
    assert main(["scan", CYLINDER, "--out", str(out), "--no-las"]) == 0
    before = _contents(out)

    def full(result, path, **kwargs):
        Path(path).write_bytes(b"\0" * 100)
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))
    monkeypatch.setattr(exr, "write_scan_exr", full)
    capsys.readouterr()
    assert main(["scan", CYLINDER, "--out", str(out), "--no-las", "--set", "scan.dtheta_deg=0.4"]) == 2
    err = capsys.readouterr().err
    _says_no_space(err, out)
    assert "No space left on device" in err
    assert _contents(out) == before and sorted(p.name for p in out.iterdir()) == sorted(before)


def test_a_library_error_on_a_full_disk_says_no_space(small_disk, capsys, monkeypatch):
    """HDF5 reports a full disk as "NetCDF: HDF error" (a RuntimeError, no errno): on a disk
    that is full it is still the no-space line."""
    from simlidar_mi.truth import run

    out = small_disk / "out"
    assert main(["truth", CYLINDER, "--out", str(out), "--voxel", "0.1"]) == 0
    before = _contents(out)

    def hdf_error(ds, path):
        with open(path, "wb") as fh:  # fills the disk, as the real write did
            try:
                while True:
                    fh.write(b"\0" * 65536)
                    fh.flush()
            except OSError:
                pass
        raise RuntimeError("NetCDF: HDF error")
    monkeypatch.setattr(run, "write_grid", hdf_error)
    capsys.readouterr()
    assert main(["truth", CYLINDER, "--out", str(out), "--voxel", "0.05"]) == 2
    err = capsys.readouterr().err
    _says_no_space(err, out)
    assert "(NetCDF: HDF error)" in err
    assert _contents(out) == before
