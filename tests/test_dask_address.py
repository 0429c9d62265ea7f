"""Bad Dask scheduler addresses end in one line within the stated wait: a server that is not a
scheduler (HTTP), nothing listening, tls:// without TLS settings, an empty address.  Only
127.0.0.1 is ever contacted."""
from __future__ import annotations

import http.server
import os
import socket
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from simlidar_mi._runtime import cluster as _dask
from simlidar_mi.cli import main
from simlidar_mi.errors import ConfigError
from tests.conftest import REPO, SCENES

pytest.importorskip("distributed")
CYLINDER = str(SCENES / "calibration_cylinder.toml")
CLI = Path(sys.executable).with_name("simlidar-mi")
WAIT_S = "2"


@pytest.fixture
def http_port():
    """A tiny HTTP server on 127.0.0.1: it accepts the connection, then never answers as a
    Dask scheduler would."""
    class Quiet(http.server.SimpleHTTPRequestHandler):
        def log_message(self, *args):
            pass
    srv = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Quiet)
    threading.Thread(target=srv.serve_forever, daemon=True).start()
    try:
        yield srv.server_address[1]
    finally:
        srv.shutdown()
        srv.server_close()


def _closed_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _scan(tmp_path: Path, address: str, command: str = "scan") -> subprocess.CompletedProcess:
    argv = [str(CLI), command, CYLINDER if command == "scan" else str(SCENES / "apple_orchard.toml"),
            "--out", str(tmp_path / "o"), "--scheduler", address]
    return subprocess.run(argv, capture_output=True, text=True, timeout=300, cwd=REPO,
                          env={**os.environ, _dask.TIMEOUT_ENV: WAIT_S})


def _one_error_line(proc: subprocess.CompletedProcess, command: str, address: str) -> str:
    errors = [ln for ln in proc.stderr.splitlines() if not ln.startswith(f"{command}: ")]
    assert proc.returncode == 2 and len(errors) == 1, proc.stderr
    assert errors[0].startswith(f"simlidar-mi {command}: error: key 'scheduler', value '{address}': ")
    return errors[0]


@pytest.mark.parametrize("command", ["scan", "study"])
def test_a_server_that_is_not_a_scheduler_is_one_line_within_the_wait(tmp_path, http_port, command):
    address = f"tcp://127.0.0.1:{http_port}"
    line = _one_error_line(_scan(tmp_path, address, command), command, address)
    assert f"no answer as a Dask scheduler within {WAIT_S} s" in line and _dask.TIMEOUT_ENV in line
    assert not [p for p in (tmp_path / "o").rglob("*") if not p.is_dir()]  # no file, no lock


def test_nothing_listening_is_one_line(tmp_path):
    address = f"tcp://127.0.0.1:{_closed_port()}"
    line = _one_error_line(_scan(tmp_path, address), "scan", address)
    assert f"after {WAIT_S} s" in line and "cannot reach the Dask scheduler" in line


def test_tls_without_tls_settings_is_one_line_at_once(tmp_path):
    address = f"tls://127.0.0.1:{_closed_port()}"
    line = _one_error_line(_scan(tmp_path, address), "scan", address)
    assert "a tls:// address needs Dask's TLS settings" in line


@pytest.mark.parametrize("command", ["scan", "study"])
@pytest.mark.parametrize("address", ["", "  "])
def test_an_empty_address_is_an_error_before_any_work(tmp_path, capsys, command, address):
    scene = CYLINDER if command == "scan" else str(SCENES / "apple_orchard.toml")
    assert main([command, scene, "--out", str(tmp_path / "o"), "--scheduler", address]) == 2
    err = capsys.readouterr().err
    assert err == (f"simlidar-mi {command}: error: key 'scheduler', value '{address}': is empty: give a "
                   "scheduler address such as 'tcp://host:8786', or 'local' for this machine's processes\n")
    assert not (tmp_path / "o").exists()


def test_the_wait_is_checked(monkeypatch):
    monkeypatch.setenv(_dask.TIMEOUT_ENV, "-1")
    with pytest.raises(ConfigError, match=f"key '{_dask.TIMEOUT_ENV}', value '-1': must be"):
        _dask.connect_timeout_s()
    monkeypatch.setenv(_dask.TIMEOUT_ENV, "0.5")
    assert _dask.connect_timeout_s() == 0.5
    monkeypatch.delenv(_dask.TIMEOUT_ENV)
    assert _dask.connect_timeout_s() == _dask.CONNECT_TIMEOUT_S
