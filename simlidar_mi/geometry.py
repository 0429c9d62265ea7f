"""Plain-data geometry shared by every generator, measure and scene builder.

Nothing here imports Mitsuba. Lengths are metres, coordinates are float64 in the
scene's real frame (the scene builder subtracts a float64 origin later).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .errors import ConfigError

# What a beam or pixel met, as stored in scan products (EXR ``class`` channel, LAS classes).
CLASS_CODES = {"escape": 0, "ground": 1, "wood": 2, "leaf": 3}
#: "no element / no plant" in uint32 id columns (EXR ids, the LAS extra bytes' declared no_data).
NO_ID = 0xFFFFFFFF


@dataclass(frozen=True)
class Branches:
    """Woody cylinders: one row per segment.

    Attributes
    ----------
    p0, p1 : (n, 3) float64, segment end points in metres.
    diameter : (n,) float64, metres.
    order : (n,) int32, axis order (1 = trunk).
    tree_id : (n,) int32, which plant the segment belongs to.
    """

    p0: np.ndarray
    p1: np.ndarray
    diameter: np.ndarray
    order: np.ndarray
    tree_id: np.ndarray

    def __post_init__(self) -> None:
        n = len(self.diameter)
        for name in ("p0", "p1"):
            a = getattr(self, name)
            if a.shape != (n, 3):
                raise ConfigError(f"Branches.{name} must have shape ({n}, 3), got {a.shape}")
        for name in ("order", "tree_id"):
            if getattr(self, name).shape != (n,):
                raise ConfigError(f"Branches.{name} must have shape ({n},)")

    @classmethod
    def empty(cls) -> "Branches":
        return cls(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0),
                   np.zeros(0, np.int32), np.zeros(0, np.int32))

    @classmethod
    def concat(cls, parts: "list[Branches]") -> "Branches":
        parts = [p for p in parts if len(p)]
        if not parts:
            return cls.empty()
        return cls(*(np.concatenate([getattr(p, f) for p in parts])
                     for f in ("p0", "p1", "diameter", "order", "tree_id")))

    def __len__(self) -> int:
        return len(self.diameter)

    @property
    def length(self) -> np.ndarray:
        """Segment lengths h in metres."""
        return np.linalg.norm(self.p1 - self.p0, axis=1)

    def subset(self, mask: np.ndarray) -> "Branches":
        return Branches(self.p0[mask], self.p1[mask], self.diameter[mask],
                        self.order[mask], self.tree_id[mask])

    def translated(self, offset) -> "Branches":
        off = np.asarray(offset, dtype=np.float64)
        return Branches(self.p0 + off, self.p1 + off, self.diameter, self.order, self.tree_id)


@dataclass(frozen=True)
class Leaves:
    """Flat leaf triangles.

    Attributes
    ----------
    vertices : (n, 3, 3) float64, triangle corners in metres.
    leaf_id : (n,) int32, leaf each triangle belongs to (12 triangles a strawberry leaf).
    plant_id : (n,) int32, plant each triangle belongs to.
    """

    vertices: np.ndarray
    leaf_id: np.ndarray
    plant_id: np.ndarray

    def __len__(self) -> int:
        return len(self.leaf_id)

    @classmethod
    def empty(cls) -> "Leaves":
        return cls(np.zeros((0, 3, 3)), np.zeros(0, np.int32), np.zeros(0, np.int32))

    @classmethod
    def concat(cls, parts: "list[Leaves]") -> "Leaves":
        """The triangles of several ``Leaves`` in order (ids kept)."""
        parts = [p for p in parts if len(p)]
        if not parts:
            return cls.empty()
        return cls(*(np.concatenate([getattr(p, f) for p in parts]) for f in ("vertices", "leaf_id", "plant_id")))

    @property
    def triangle_area(self) -> np.ndarray:
        """One-sided area of each triangle in m²."""
        v = self.vertices
        return 0.5 * np.linalg.norm(np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]), axis=1)

    def subset(self, mask: np.ndarray) -> "Leaves":
        return Leaves(self.vertices[mask], self.leaf_id[mask], self.plant_id[mask])


@dataclass(frozen=True)
class Mesh:
    """A triangle mesh read from a file (OBJ or PLY primitive).

    Attributes
    ----------
    vertices : (n, 3) float64, metres, as written in the file.
    faces : (m, 3) uint32, 0-based vertex indices, in the file's face order (polygons as fans).
    face_class : (m,) uint8 class code (:data:`CLASS_CODES`) per triangle, or None: every
        triangle has the primitive's label.
    """

    vertices: np.ndarray
    faces: np.ndarray
    face_class: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.faces)


@dataclass(frozen=True)
class Primitive:
    """An explicit shape from a scene file (calibration targets, meshes users bring).

    kind is 'cylinder' (p0, p1, diameter), 'box' (min, max corners) or 'obj'/'ply' (path).
    The class label says what the scanner reports on a hit ('wood' or 'leaf'; a mesh's
    faces may carry their own classes). ``mesh``: the file's triangles once read
    (:func:`simlidar_mi.io.mesh_import.read_mesh`), so bounds, build and sensor reuse them.
    """

    kind: str
    params: dict = field(default_factory=dict)
    label: str = "wood"
    mesh: Mesh | None = None
