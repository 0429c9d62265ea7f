"""simlidar-mi: virtual orchards, canopies and forests seen by simulated sensors on Mitsuba 3.

Importing the package picks a libLLVM >= 17 for Dr.Jit (setting DRJIT_LIBLLVM_PATH
unless the user already did) but does not import Mitsuba: geometry, grammars and
measures work without it.
"""
from __future__ import annotations

from . import _llvm
from .errors import (ConfigError, DerivationTooLarge, GrammarError, LLVMNotFound,
                     PhotoError, SimlidarError)
from .geometry import Branches, Leaves, Primitive

__version__ = "0.1.0"

try:
    _llvm.ensure_libllvm()
except LLVMNotFound:
    pass  # raised again, with the install hint, when Mitsuba is first needed

__all__ = [
    "Branches", "Leaves", "Primitive",
    "SimlidarError", "ConfigError", "GrammarError", "DerivationTooLarge", "LLVMNotFound",
    "PhotoError", "__version__",
]
