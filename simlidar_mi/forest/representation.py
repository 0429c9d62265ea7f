"""How a forest's foliage is represented: decided here, described to the scene builder and the truth.

A forest is either **instanced** (``forest.instancing = true``: K prototype trees per
species, each a flat mesh of individual leaves, placed by a per-tree transform — the
default, ``prototypes_per_species = 12``) or **explicit** (every tree its own draw and its own
mesh). :func:`scene_parts` turns a :class:`~simlidar_mi.forest.stand.Forest` into what both
the Mitsuba scene builder (:func:`simlidar_mi.scene.build.build_scene`) and the truth
(:func:`simlidar_mi.truth.compute.compute_truth`) read — the same ``SceneGeometry`` object —
so the truth always integrates the prototypes × transforms the sensor sees, exactly
(float64, one tree at a time).

Why prototypes and not leaf clusters: Mitsuba 3 (3.9.1, llvm variants) refuses a
``shapegroup`` that holds an ``instance`` ("[ShapeGroup] Nested instancing is not
permitted"; ``tests/test_forest_repr.py`` keeps that finding), so a shoot or twig instanced
inside a tree cannot reach the sensor as such: it would be flattened into the tree's mesh,
which is a prototype again. Memory then grows with the leaf triangles *built* (K × species ×
triangles per tree), not with the trees placed: a 300 m stand of ~700 trees carrying
15–25× today's leaf area holds ~6 M built leaf triangles with K = 12 against ~105 M placed
(BENCHMARKS.md §16). A turbid-medium (voxel) representation is not offered: its truth would
no longer be the leaves the sensor sees.

Memory guard (``forest.memory_limit_gb``, ``"auto"``: 90 % of the machine's physical memory):
what a run holds is estimated from the triangles it is about to hold, *before* growing or
expanding them, and a run over the limit stops with one line naming the key
(:func:`check_memory`). The per-triangle costs are measured (BENCHMARKS.md §16).
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Any

from ..errors import ConfigError
from ..geometry import Branches, Leaves

__all__ = ["Representation", "representation", "scene_parts", "memory_limit_bytes", "check_memory",
           "GROWN_BYTES_PER_TRIANGLE", "SCENE_BYTES_PER_TRIANGLE", "NESTED_INSTANCING",
           "DEFAULT_PROTOTYPES_PER_SPECIES"]

#: K of ``forest.prototypes_per_species`` by default (BENCHMARKS.md §16: the accuracy it costs).
DEFAULT_PROTOTYPES_PER_SPECIES = 12

#: Mitsuba 3.9.1 refuses an instance inside a shapegroup (checked by tests/test_forest_repr.py).
NESTED_INSTANCING = False

#: Bytes a grown tree holds per leaf triangle in numpy (float64 vertices 72 B, ids 8 B, its
#: share of the leaf table ~30 B at ~3.4 triangles a leaf), rounded up; branches are ~1 % of
#: the triangles of a leafy tree and ride in the margin. Measured: BENCHMARKS.md §16.
GROWN_BYTES_PER_TRIANGLE = 120

#: Bytes the Mitsuba scene adds per built triangle (float32 vertices and faces, Embree's BVH,
#: the hit tables), rounded up from BENCHMARKS.md §16.
SCENE_BYTES_PER_TRIANGLE = 170

_KEY = "forest.memory_limit_gb"


@dataclass(frozen=True)
class Representation:
    """What a forest's foliage is, as built for the sensor (and integrated by the truth).

    ``kind``: ``"instanced"`` or ``"explicit"``; ``n_prototypes``: the meshes built
    (0 when explicit); ``triangles_built``: leaf triangles held in memory and built into the
    scene; ``triangles_placed``: leaf triangles the sensor sees (all trees expanded).
    """

    kind: str
    n_prototypes: int
    prototypes_per_species: int | str | None
    triangles_built: int
    triangles_placed: int
    branches_built: int

    def as_dict(self) -> dict[str, Any]:
        return {"kind": self.kind, "n_prototypes": self.n_prototypes,
                "prototypes_per_species": self.prototypes_per_species,
                "leaf_triangles_built": self.triangles_built,
                "leaf_triangles_placed": self.triangles_placed,
                "branches_built": self.branches_built,
                "nested_instancing": NESTED_INSTANCING}


def representation(forest) -> Representation:
    """The representation ``forest`` (a :class:`~simlidar_mi.forest.stand.Forest`; not imported
    here: stand imports this module) was made in (see the module docstring)."""
    if forest.instancing:
        return Representation("instanced", len(forest.prototypes), forest.params.prototypes_per_species,
                              sum(len(t.leaves) for t in forest.prototypes),
                              int(forest.n_leaf_triangles.sum()),
                              sum(len(t.branches) for t in forest.prototypes))
    n = int(forest.n_leaf_triangles.sum())
    return Representation("explicit", 0, None, n, n, int(forest.n_branches.sum()))


def memory_limit_bytes(value: float | str, file: str | None = None) -> float:
    """``forest.memory_limit_gb`` in bytes: a number of GB (10⁹ B), or ``"auto"`` = 90 % of the
    machine's physical memory (``os.sysconf``; unlimited where the platform does not say)."""
    if value == "auto":
        try:
            return 0.9 * os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
        except (ValueError, OSError, AttributeError):  # pragma: no cover - non-POSIX
            return float("inf")
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not value > 0:
        raise ConfigError("must be 'auto' or a number of GB > 0", file=file, key=_KEY, value=value)
    return float(value) * 1e9


def check_memory(need_bytes: float, limit: float | str, what: str, file: str | None = None) -> None:
    """Refuse (ConfigError naming ``forest.memory_limit_gb``) a step that would hold more than
    the limit; called before the step allocates."""
    lim = memory_limit_bytes(limit, file)
    if need_bytes > lim:
        raise ConfigError(f"{what} would hold ~{need_bytes / 1e9:.3g} GB, more than the limit "
                          f"{lim / 1e9:.3g} GB; use instancing with fewer prototypes_per_species, a "
                          "smaller domain_m, or raise the limit", file=file, key=_KEY, value=limit)


def scene_parts(forest, source: str | None = None
                ) -> tuple[Branches, Leaves, Any]:
    """The forest as the scene builder and the truth read it: ``(branches, leaves, instances)``.

    Instanced: empty branches and leaves, and :class:`simlidar_mi.scene.build.Instances` of the
    prototypes and per-tree transforms (:meth:`Forest.instance_arrays`). Explicit: every tree
    expanded into world-frame arrays, ``instances`` None. Either way the memory the scene will
    hold (numpy arrays plus the Mitsuba scene) is checked first against ``forest.memory_limit_gb``.
    """
    rep = representation(forest)
    limit = forest.params.memory_limit_gb
    held = rep.triangles_built * (SCENE_BYTES_PER_TRIANGLE + GROWN_BYTES_PER_TRIANGLE
                                  * (2 if rep.kind == "explicit" else 1))  # explicit: trees + expansion
    check_memory(held, limit, f"the {rep.kind} forest's scene ({rep.triangles_built:,} leaf triangles built)",
                 source)
    if rep.kind == "instanced":
        from ..scene.build import Instances  # noqa: PLC0415  (a plain dataclass; no Mitsuba import)
        return Branches.empty(), Leaves.empty(), Instances(**forest.instance_arrays())
    b, lv = forest.geometry()
    return b, lv, None
