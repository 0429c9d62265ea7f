"""The one place that imports Mitsuba: picks libLLVM, sets the variant, registers plugins."""
from __future__ import annotations

import importlib
from types import ModuleType

from .llvm import ensure_libllvm
from .signals import interrupts_deferred
from ..errors import ConfigError

DEFAULT_VARIANT = "llvm_ad_mono"
_PLUGIN_MODULES = ("tractor_lidar", "range_integrator", "coverage_integrator")
_state: dict = {}


def mitsuba(variant: str | None = None) -> ModuleType:
    """Import mitsuba with ``variant`` set and our plugins registered; return the module.

    The first call fixes the variant for the process; a later call asking for a
    different one switches it (Mitsuba allows that) and re-registers the plugins.
    Ctrl-C is held back until this is done: an interrupt inside the extension modules'
    initialisation leaves them broken (ImportError, SystemError, or an abort at exit).
    """
    with interrupts_deferred():
        return _mitsuba(variant)


def _mitsuba(variant: str | None) -> ModuleType:
    variant = variant or _state.get("variant") or DEFAULT_VARIANT
    if variant.startswith("llvm"):
        ensure_libllvm()
    import mitsuba as mi  # noqa: PLC0415  (deliberately late: libLLVM must be chosen first)

    if variant not in mi.variants():
        raise ConfigError(f"unknown Mitsuba variant; available: {', '.join(mi.variants())}",
                          key="variant", value=variant)
    if _state.get("variant") != variant:
        if variant.startswith("cuda"):
            _require_cuda(variant)
        try:
            mi.set_variant(variant)
        except ImportError as exc:  # e.g. the backend failed to start: one line, not a traceback
            raise ConfigError(f"Mitsuba could not load this variant: {exc}", key="variant",
                              value=variant) from None
        for name in _PLUGIN_MODULES:
            try:
                mod = importlib.import_module(f"simlidar_mi.plugins.{name}")
            except ModuleNotFoundError as exc:
                if exc.name == f"simlidar_mi.plugins.{name}":
                    continue  # plugin not written yet in this checkout
                raise
            mod.register()
        _state["variant"] = variant
    return mi


def variant_ready(variant: str | None = None) -> bool:
    """Whether this process has already imported Mitsuba with ``variant`` set (no import)."""
    return _state.get("variant") is not None and _state["variant"] == (variant or _state["variant"])


def check_variant(variant: str | None, file: str | None = None) -> None:
    """Refuse, before any work, a variant this machine cannot run (cuda_* without a GPU).

    Cheap: imports Dr.Jit only for a CUDA variant, never Mitsuba."""
    if variant and variant.startswith("cuda"):
        _require_cuda(variant, file, "scene.variant")


def _require_cuda(variant: str, file: str | None = None, key: str = "variant") -> None:
    """Refuse a cuda_* variant in one line when Dr.Jit finds no CUDA device (else ImportError)."""
    import drjit as dr  # noqa: PLC0415

    if not dr.has_backend(dr.JitBackend.CUDA):
        raise ConfigError("no CUDA device was found (an NVIDIA GPU with its driver is needed); "
                          f"use the default {DEFAULT_VARIANT} on the CPU", file=file, key=key,
                          value=variant)
