"""libLLVM selection: the user's choice wins; a missing library gives one clear message."""
from __future__ import annotations

import os
import shutil
import subprocess
import sys

import pytest

from simlidar_mi._runtime import llvm as _llvm
from simlidar_mi.errors import LLVMNotFound
from tests.conftest import REPO


def test_user_setting_wins(monkeypatch):
    monkeypatch.setenv("DRJIT_LIBLLVM_PATH", "/opt/my/libLLVM.so")
    assert _llvm.ensure_libllvm() == "/opt/my/libLLVM.so"


def test_old_llvm_only_gives_install_hint(monkeypatch):
    monkeypatch.delenv("DRJIT_LIBLLVM_PATH", raising=False)
    monkeypatch.setattr(_llvm, "candidates", lambda: [(15, "/usr/lib/x86_64-linux-gnu/libLLVM-15.so")])
    with pytest.raises(LLVMNotFound, match="apt-get install -y libllvm19"):
        _llvm.ensure_libllvm()


def test_version_parsing():
    assert _llvm._version_of("/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1") == 19
    assert _llvm._version_of("/usr/lib/x86_64-linux-gnu/libLLVM-15.so.1") == 15
    assert _llvm._version_of("/usr/lib/llvm-18/lib/libLLVM.so") == 18


def test_chosen_llvm_runs_the_kernel_that_aborts_on_llvm_15():
    """dr.maximum compiles to llvm.maximum, which LLVM 15 cannot select (process abort)."""
    code = ("import simlidar_mi, os; from simlidar_mi._runtime.mitsuba import mitsuba; mi = mitsuba(); "
            "import drjit as dr; print(dr.maximum(dr.arange(mi.Float, 10), 3.0)[0], "
            "os.environ['DRJIT_LIBLLVM_PATH'])")
    env = {k: v for k, v in os.environ.items() if k != "DRJIT_LIBLLVM_PATH"}
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env)
    assert proc.returncode == 0, proc.stderr
    value, path = proc.stdout.split()
    assert float(value) == 3.0 and _llvm._version_of(path) >= 17


# --- `make llvm`: detect with the package's finder, run apt-get only when it finds none ---

MAKE = shutil.which("make")
needs_make = pytest.mark.skipif(MAKE is None, reason="make is not installed")


def _fake_bin(tmp_path, apt_rc: int, finder_rcs: tuple[int, ...] | None = None) -> dict:
    """A PATH with a recording apt-get (exit ``apt_rc``) and `id -u` = 0 (root, so the
    Makefile would install); with ``finder_rcs``, a fake python3 whose k-th run exits
    ``finder_rcs[k]``. Returns make's environment."""
    bin_ = tmp_path / "bin"
    bin_.mkdir()
    log = tmp_path / "apt.log"
    (bin_ / "apt-get").write_text(f'#!/bin/sh\necho "$@" >> {log}\nexit {apt_rc}\n')
    (bin_ / "id").write_text("#!/bin/sh\necho 0\n")
    if finder_rcs is not None:
        count = tmp_path / "finder.count"
        rcs = " ".join(map(str, finder_rcs))
        (bin_ / "python3").write_text(
            f'#!/bin/sh\necho x >> {count}\nn=$(wc -l < {count})\n'
            f'set -- {rcs}\nshift $((n - 1))\nexit $1\n')
    for f in bin_.iterdir():
        f.chmod(0o755)
    env = {k: v for k, v in os.environ.items() if k not in ("DRJIT_LIBLLVM_PATH", "MAKEFLAGS")}
    env["PATH"] = f"{bin_}:{env['PATH']}"
    return env


def _make_llvm(env, *args):
    return subprocess.run([MAKE, "-s", "-C", str(REPO), "llvm", *args], capture_output=True,
                          text=True, env=env, timeout=60)


@needs_make
def test_make_llvm_finds_installed_libllvm_and_skips_apt(tmp_path, monkeypatch):
    monkeypatch.delenv("DRJIT_LIBLLVM_PATH", raising=False)
    if _llvm.find_libllvm() is None:
        pytest.skip("no libLLVM >= 17 on this machine")
    env = _fake_bin(tmp_path, apt_rc=100)
    proc = _make_llvm(env, "PY=python3")
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "libLLVM >= 17 found" in proc.stdout
    assert not (tmp_path / "apt.log").exists(), "apt-get ran although libLLVM >= 17 is installed"


@needs_make
def test_make_llvm_installs_only_when_the_finder_finds_none(tmp_path):
    # finder: none (3), then found after the install (0)
    env = _fake_bin(tmp_path, apt_rc=0, finder_rcs=(3, 0))
    proc = _make_llvm(env, f"PY={tmp_path / 'bin' / 'python3'}")
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert (tmp_path / "apt.log").read_text().split("\n")[0].startswith("install -y")


@needs_make
def test_make_llvm_failed_install_says_so(tmp_path):
    env = _fake_bin(tmp_path, apt_rc=100, finder_rcs=(3, 3))   # dpkg locked / offline
    proc = _make_llvm(env, f"PY={tmp_path / 'bin' / 'python3'}")
    assert proc.returncode != 0
    assert "could not install libllvm19" in proc.stdout
    assert "update" in (tmp_path / "apt.log").read_text()   # retried after apt-get update


@needs_make
def test_make_llvm_finder_crash_does_not_run_apt(tmp_path):
    env = _fake_bin(tmp_path, apt_rc=100, finder_rcs=(1,))
    proc = _make_llvm(env, f"PY={tmp_path / 'bin' / 'python3'}")
    assert proc.returncode == 0 and "could not check" in proc.stdout
    assert not (tmp_path / "apt.log").exists()


def test_finder_script_runs_without_the_package(tmp_path):
    """`python3 -I simlidar_mi/_runtime/llvm.py`: no venv, no package import, exit 0 or 3."""
    proc = subprocess.run([sys.executable, "-I", str(REPO / "simlidar_mi" / "_runtime" / "llvm.py")],
                          capture_output=True, text=True, cwd=tmp_path, timeout=60)
    found = _llvm.find_libllvm() is not None or "DRJIT_LIBLLVM_PATH" in os.environ
    assert proc.returncode == (0 if found else 3), proc.stderr


def test_finder_main_exit_codes(monkeypatch, capsys):
    monkeypatch.delenv("DRJIT_LIBLLVM_PATH", raising=False)
    monkeypatch.setattr(_llvm, "candidates", lambda: [(15, "/usr/lib/x86_64-linux-gnu/libLLVM-15.so")])
    assert _llvm.main() == 3
    assert "apt-get install -y libllvm19" in capsys.readouterr().err
    monkeypatch.setattr(_llvm, "candidates", lambda: [(19, "/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1"),
                                                      (15, "/usr/lib/x86_64-linux-gnu/libLLVM-15.so")])
    assert _llvm.main() == 0
    assert capsys.readouterr().out.strip().endswith("libLLVM.so.19.1")


@needs_make
def test_make_install_prints_one_line_per_stage_when_piped(tmp_path):
    """The venv install (minutes on a fresh machine) says what it is doing, stage by stage;
    piped, pip runs quietly. A fake python3 stands in for venv and pip."""
    (tmp_path / "Makefile").write_text((REPO / "Makefile").read_text())
    (tmp_path / "pyproject.toml").write_text("")
    fake = tmp_path / "python3"
    fake.write_text(
        '#!/bin/sh\n'
        'if [ "$1" = "-m" ] && [ "$2" = "venv" ]; then\n'
        '  mkdir -p "$3/bin"\n'
        '  printf \'#!/bin/sh\\necho "$@" >> "$(dirname "$0")/../calls.log"\\n'
        '[ "$1" = "-c" ] && echo 9.9.9\\nexit 0\\n\' > "$3/bin/python"\n'
        '  chmod +x "$3/bin/python"; exit 0\n'
        'fi\nexit 1\n')
    fake.chmod(0o755)
    proc = subprocess.run([MAKE, "-s", ".venv/.installed", f"PY={fake}"], cwd=tmp_path,
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    lines = proc.stdout.splitlines()
    assert [x.split(" ", 1)[0] for x in lines] == ["[1/3]", "[2/3]", "[3/3]", "installed:"]
    assert lines[-1] == "installed: 9.9.9 in .venv"
    calls = (tmp_path / ".venv" / "calls.log").read_text().splitlines()
    assert "-m pip install -q -e ." in calls                  # quiet when piped; no test extras
    assert not any("[test]" in c for c in calls)               # `make demo` does not wait for them
    assert (tmp_path / ".venv" / ".installed").exists()
    proc = subprocess.run([MAKE, "-s", ".venv/.installed-test", f"PY={fake}"], cwd=tmp_path,
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert proc.stdout.splitlines()[0].startswith("installing the test extras (pytest")
    assert (tmp_path / ".venv" / "calls.log").read_text().splitlines()[-1] == "-m pip install -q -e .[test]"
