"""What the command line prints when it cannot do the job: one line on stderr, nothing
half-made on stdout (a missing GPU, photos that do not exist)."""
from __future__ import annotations

import json
import subprocess
import sys

import pytest

from tests.conftest import SCENES


def _cli(*args, cwd):
    return subprocess.run([sys.executable, "-m", "simlidar_mi.cli", *map(str, args)],
                          capture_output=True, text=True, cwd=cwd, timeout=300)


def _has_cuda() -> bool:
    import drjit as dr
    return bool(dr.has_backend(dr.JitBackend.CUDA))


@pytest.mark.skipif(_has_cuda(), reason="this machine has a CUDA device")
@pytest.mark.parametrize("command", ["scan", "gapfraction", "preview"])
def test_cuda_variant_without_gpu_is_one_line(tmp_path, command):
    scene = SCENES / ("random_leaves_spherical.toml" if command == "gapfraction"
                      else "calibration_cylinder.toml")
    out = tmp_path / ("p.png" if command == "preview" else "out")
    proc = _cli(command, scene, "--out", out, "--variant", "cuda_ad_mono", cwd=tmp_path)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in proc.stderr, proc.stderr
    assert lines[0].startswith(f"simlidar-mi {command}: error: ")
    assert "no CUDA device was found" in lines[0] and "cuda_ad_mono" in lines[0]
    assert not out.exists()


def test_mitsuba_cuda_variant_raises_config_error():
    if _has_cuda():
        pytest.skip("this machine has a CUDA device")
    from simlidar_mi._runtime.mitsuba import mitsuba
    from simlidar_mi.errors import ConfigError
    with pytest.raises(ConfigError, match="no CUDA device was found"):
        mitsuba("cuda_ad_rgb")
    assert mitsuba("llvm_ad_mono").variant() == "llvm_ad_mono"   # the CPU still works
