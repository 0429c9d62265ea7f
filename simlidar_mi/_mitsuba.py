"""The one place that imports Mitsuba: picks libLLVM, sets the variant, registers plugins."""
from __future__ import annotations

import importlib
from types import ModuleType

from ._llvm import ensure_libllvm
from ._signals import sigint_deferred
from .errors import ConfigError

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
    with sigint_deferred():
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
        mi.set_variant(variant)
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
