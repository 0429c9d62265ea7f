"""Choose a libLLVM that Dr.Jit's llvm backend can use (>= 17).

Dr.Jit 1.5 emits llvm.minimum/maximum intrinsics that libLLVM 15/16 cannot
select: the process aborts instead of raising.  So before drjit is imported we
look for a libLLVM >= 17 and set DRJIT_LIBLLVM_PATH, unless the user set it.

Standard library only, so ``make llvm`` can run this file as a script with the
system python3 before the venv exists (``python3 simlidar_mi/_runtime/llvm.py``; exit 0
when a usable libLLVM is found, 3 when none is).
"""
from __future__ import annotations

import glob
import os
import re
import sys

MIN_VERSION = 17
_SEARCH_DIRS = (
    "/usr/lib/x86_64-linux-gnu", "/usr/lib/aarch64-linux-gnu", "/usr/lib64", "/usr/lib",
    "/usr/local/lib", "/opt/homebrew/opt/llvm/lib", "/usr/local/opt/llvm/lib",
)
INSTALL_HINT = (
    "Dr.Jit's LLVM backend needs libLLVM >= 17 and none was found. "
    "On Debian 12 / Ubuntu: 'sudo apt-get install -y libllvm19' (or run 'make' as root, "
    "which installs it). Elsewhere install LLVM >= 17 and set "
    "DRJIT_LIBLLVM_PATH=/path/to/libLLVM.so before importing simlidar_mi."
)


def _version_of(path: str) -> int | None:
    name = os.path.basename(path)
    m = re.search(r"LLVM[-.]?(?:so\.)?(\d+)", name) or re.search(r"llvm-(\d+)", path)
    return int(m.group(1)) if m else None


def candidates() -> list[tuple[int, str]]:
    """All libLLVM shared libraries found on this machine, newest first."""
    found: dict[str, int] = {}
    patterns = ["libLLVM*.so*", "libLLVM*.dylib"]
    dirs = list(_SEARCH_DIRS) + sorted(glob.glob("/usr/lib/llvm-*/lib"))
    for d in dirs:
        for pat in patterns:
            for p in glob.glob(os.path.join(d, pat)):
                v = _version_of(p)
                if v is not None and os.path.isfile(p):
                    found.setdefault(os.path.realpath(p), v)
    return sorted(((v, p) for p, v in found.items()), reverse=True)


def find_libllvm() -> str | None:
    """The libLLVM Dr.Jit should use: the user's DRJIT_LIBLLVM_PATH, else the newest >= 17."""
    user = os.environ.get("DRJIT_LIBLLVM_PATH")
    if user:
        return user
    for version, path in candidates():
        if version >= MIN_VERSION:
            return path
    return None


def ensure_libllvm() -> str:
    """Set DRJIT_LIBLLVM_PATH to a usable libLLVM and return it.

    A value already set by the user wins.  Raises LLVMNotFound with the exact
    install command when nothing suitable exists.
    """
    path = find_libllvm()
    if path is None:
        from ..errors import LLVMNotFound  # noqa: PLC0415  (late: this file also runs as a script)
        raise LLVMNotFound(INSTALL_HINT)
    os.environ["DRJIT_LIBLLVM_PATH"] = path
    return path


def main() -> int:
    """``make llvm``'s check: 0 and the library when one is usable, 3 when none is."""
    path = find_libllvm()
    if path is None:
        print(INSTALL_HINT, file=sys.stderr)
        return 3
    how = "DRJIT_LIBLLVM_PATH" if os.environ.get("DRJIT_LIBLLVM_PATH") else "found"
    print(f"libLLVM >= {MIN_VERSION} {how}: {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
