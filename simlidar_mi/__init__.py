"""simlidar-mi: virtual orchards, canopies and forests seen by simulated sensors on Mitsuba 3.

The package is laid out by workflow over a shared base (imports point down only)::

    errors, geometry   shared base: one exception family, plain-data geometry
    config/    the scene-file schema (one key table per feature), loader, sensor presets
    _runtime/  how a run runs: libLLVM and Mitsuba loading, signals, progress, forks, Dask
    io/        writers and readers (EXR, LAS, PNG, CSV, meshes)
    lsystem/   grammars, derivation, turtles
    plants/    generators -> plain geometry (apple, strawberry, random leaves and trees, vineyards)
    scene/     geometry -> Mitsuba shapes
    forest/    Poisson placement, stands and their outputs
    lidar/     platforms, scans, surveys, the SIMLIDAR study, the float64 reference
    canopy/    gap fraction, photo classifiers, comparison, synthetic photos
    cli.py     one thin command per API call

What a notebook needs is importable from here. Importing the package picks a libLLVM
>= 17 for Dr.Jit (setting DRJIT_LIBLLVM_PATH unless the user already did) but loads
neither numpy, Mitsuba nor a workflow until one of its names is first used, and changes no
process-wide setting (signal handlers, thread pools): the command line does that in ``main``.

Examples
--------
>>> import simlidar_mi as sm
>>> tree = sm.orchard(sm.AppleTreeParams(iterations=4), n_trees=1, spacing_m=2.0)
>>> m = sm.wood_measures(tree).to_dict()        # geometry only: no Mitsuba
>>> m["n_branches"], round(m["A_PR_m2"], 5)
(280, 0.18725)
>>> cfg = sm.load_scene("scenes/calibration_cylinder.toml")
>>> geometry = sm.generate(cfg)
>>> settings = sm.resolve_settings(cfg["scan"], cfg["ground"], *geometry.bounds_m())
>>> result = sm.scan(sm.build(cfg, geometry), settings)
>>> round(result.impacted_area_yz_m2(), 3)      # d·h of the 0.05 m x 1 m target
0.05

A whole run, as the command line does it: ``sm.run_scan("scenes/apple_orchard.toml", "out/")``;
gap fraction: ``sm.run_gapfraction("scenes/strawberry_plot.toml", "out/")``; forests:
``sm.run_forest("scenes/forest_small.toml", "out/")``.
"""
from __future__ import annotations

import importlib

from ._runtime import llvm as _llvm
from .errors import (ConfigError, DerivationTooLarge, GrammarError, LLVMNotFound,
                     PhotoError, SimlidarError)
from ._version import __version__

try:
    _llvm.ensure_libllvm()
except LLVMNotFound:
    pass  # raised again, with the install hint, when Mitsuba is first needed

# name -> module that defines it; loaded on first use (PEP 562) so that importing the
# package stays cheap and the workflows below never import this file's names.
_API = {
    "Branches": "geometry", "Leaves": "geometry", "Primitive": "geometry",
    "load_scene": "config", "SceneConfig": "config",
    "generate": "lidar.survey", "build": "lidar.survey", "measure": "lidar.survey",
    "run_scan": "lidar.survey", "preview": "lidar.preview",
    "resolve_settings": "lidar.scan", "scan": "lidar.scan", "ScanResult": "lidar.scan",
    "ScanSettings": "lidar.scan", "read_scan_exr": "lidar.scan",
    "run_study": "lidar.study",
    "AppleTreeParams": "plants.apple", "apple_tree": "plants.apple", "orchard": "plants.apple",
    "wood_measures": "plants.measures", "preset_geometry": "plants.presets",
    "build_scene": "scene.build",
    "VineyardParams": "plants.vineyard", "vineyard": "plants.vineyard",
    "gap_images": "canopy.gapfraction", "run_gapfraction": "canopy.gapfraction",
    "photo_gap": "canopy.photo", "compare": "canopy.compare",
    "make_forest": "forest.stand", "run_forest": "truth.forest_truth",
    "write_scan_exr": "io.exr", "write_scan_las": "io.las",
}


def __getattr__(name: str):
    try:
        module = _API[name]
    except KeyError:
        raise AttributeError(f"module 'simlidar_mi' has no attribute {name!r}") from None
    value = getattr(importlib.import_module(f".{module}", __name__), name)
    globals()[name] = value  # later look-ups skip this function
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_API))


__all__ = [
    "SimlidarError", "ConfigError", "GrammarError", "DerivationTooLarge", "LLVMNotFound",
    "PhotoError", "__version__", *_API,
]
