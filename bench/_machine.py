"""The machine line every benchmark table starts with."""
from __future__ import annotations

import os
import platform


def machine() -> str:
    """CPU model, cores, OS, Python, Mitsuba/Dr.Jit versions and the libLLVM in use."""
    cpu = "unknown CPU"
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    import simlidar_mi  # noqa: F401  (chooses libLLVM, sets DRJIT_LIBLLVM_PATH)
    import drjit
    import mitsuba
    return (f"{cpu}, {os.cpu_count()} cores, {platform.system()} {platform.release()}, "
            f"Python {platform.python_version()}, mitsuba {mitsuba.__version__}, drjit {drjit.__version__}, "
            f"libLLVM {os.environ.get('DRJIT_LIBLLVM_PATH', '?')}")
