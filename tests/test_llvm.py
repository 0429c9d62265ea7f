"""libLLVM selection: the user's choice wins; a missing library gives one clear message."""
from __future__ import annotations

import subprocess
import sys

import pytest

from simlidar_mi import _llvm
from simlidar_mi.errors import LLVMNotFound


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
    code = ("import simlidar_mi, os; from simlidar_mi._mitsuba import mitsuba; mi = mitsuba(); "
            "import drjit as dr; print(dr.maximum(dr.arange(mi.Float, 10), 3.0)[0], "
            "os.environ['DRJIT_LIBLLVM_PATH'])")
    env = {k: v for k, v in __import__("os").environ.items() if k != "DRJIT_LIBLLVM_PATH"}
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env)
    assert proc.returncode == 0, proc.stderr
    value, path = proc.stdout.split()
    assert float(value) == 3.0 and _llvm._version_of(path) >= 17
