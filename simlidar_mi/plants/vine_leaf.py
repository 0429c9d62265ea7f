"""The grapevine leaf: a five-lobed (palmate) blade of eight triangles, and its placement.

Outline
-------
In the blade's own frame the outline is a star of nine points around the petiole
junction O (the point where the petiole meets the blade and the main veins start),
given as (angle α from the midrib, distance r in units of the midrib length L):
the terminal lobe tip (0°, 1), the superior lateral lobe tips (±60°, 0.85), the
inferior lobe tips (±120°, 0.60), and between them the upper (±30°, 0.55) and lower
(±95°, 0.45) lateral sinuses.  The 120° wedge behind O is the open petiolar sinus.
The blade is the fan of eight triangles (O, v_j, v_j+1), so its one-sided area is the
closed form

    A = K·L²,  K = Σ_j ½·r_j·r_j+1·sin(α_j+1 − α_j) = 0.8422 (:data:`OUTLINE_AREA_FACTOR`),

and its width across the midrib is 2·0.85·sin 60°·L = 1.47·L.  The numbers draw the
ampelographic shape (five lobes, a U-shaped open petiolar sinus, OIV descriptors
067/068/079 in OIV 2009, *Descriptor list for grape varieties and Vitis species*, 2nd
ed.) as a schematic outline; they are not fitted to a cultivar.  With the default mean
area 0.0095 m², L = 10.6 cm.

Placement
---------
A leaf at a shoot node has a petiole of length ``petiole_length_ratio``·L leaving the
node at azimuth ψ (distichous: alternate nodes on opposite sides, plus a random
deviation) and ``petiole_elevation_deg`` above the horizontal; the blade hangs from the
petiole's end O.  The blade's upper-side normal n has inclination θ_L from the vertical
and the petiole's azimuth ψ (it faces away from the shoot); the midrib starts along the
blade's down-slope direction h₀ = (cos θ_L·cos ψ, cos θ_L·sin ψ, −sin θ_L) and is turned
about n by a random roll.  Vertex j lies at O + r_j·L·(cos α_j·h + sin α_j·s) with
s = n × h, so every triangle's normal is n.
"""
from __future__ import annotations

import math

import numpy as np

from ..geometry import Leaves
from .tree_leaves import LeafTable, _rotate

__all__ = ["OUTLINE_DEG", "OUTLINE_R", "OUTLINE_AREA_FACTOR", "OUTLINE_WIDTH_FACTOR", "blades"]

#: Outline points (angle from the midrib in degrees, distance / midrib length), in order.
OUTLINE_DEG = np.array([-120.0, -95.0, -60.0, -30.0, 0.0, 30.0, 60.0, 95.0, 120.0])
OUTLINE_R = np.array([0.60, 0.45, 0.85, 0.55, 1.00, 0.55, 0.85, 0.45, 0.60])
TRIANGLES_PER_LEAF = len(OUTLINE_DEG) - 1
#: One-sided blade area / L² (the closed form in the module docstring).
OUTLINE_AREA_FACTOR = float(0.5 * np.sum(OUTLINE_R[:-1] * OUTLINE_R[1:]
                                         * np.sin(np.deg2rad(np.diff(OUTLINE_DEG)))))
#: Blade width across the midrib / L.
OUTLINE_WIDTH_FACTOR = float(np.ptp(OUTLINE_R * np.sin(np.deg2rad(OUTLINE_DEG))))


def blades(origin_m: np.ndarray, psi_rad: np.ndarray, incl_rad: np.ndarray, roll_rad: np.ndarray,
           length_m: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Triangles of n blades hanging from their petiole ends ``origin_m`` (n, 3).

    Returns (triangles (n, 8, 3, 3), upper normal (n, 3), midrib heading (n, 3))."""
    n = np.stack([np.sin(incl_rad) * np.cos(psi_rad), np.sin(incl_rad) * np.sin(psi_rad),
                  np.cos(incl_rad)], axis=1)
    h0 = np.stack([np.cos(incl_rad) * np.cos(psi_rad), np.cos(incl_rad) * np.sin(psi_rad),
                   -np.sin(incl_rad)], axis=1)
    h = _rotate(h0, n, roll_rad)
    s = np.cross(n, h)
    a = np.deg2rad(OUTLINE_DEG)
    ring = origin_m[:, None, :] + length_m[:, None, None] * OUTLINE_R[None, :, None] * (
        np.cos(a)[None, :, None] * h[:, None, :] + np.sin(a)[None, :, None] * s[:, None, :])
    o = np.broadcast_to(origin_m[:, None, :], ring[:, 1:].shape)
    return np.stack([o, ring[:, :-1], ring[:, 1:]], axis=2), n, h


def leaf_records(tri: np.ndarray, normal: np.ndarray, heading: np.ndarray, length_m: np.ndarray,
                 plant_id: np.ndarray, leaf_id: np.ndarray) -> tuple[Leaves, LeafTable]:
    """Leaves (8 triangles a leaf) and the per-leaf table of placed blades."""
    n = len(length_m)
    leaves = Leaves(tri.reshape(-1, 3, 3), np.repeat(leaf_id, TRIANGLES_PER_LEAF).astype(np.int32),
                    np.repeat(plant_id, TRIANGLES_PER_LEAF).astype(np.int32))
    origin = tri[:, 0, 0]
    table = LeafTable(plant_id.astype(np.int32), leaf_id.astype(np.int32),
                      origin + 0.5 * length_m[:, None] * heading, length_m,
                      OUTLINE_WIDTH_FACTOR * length_m, OUTLINE_AREA_FACTOR * length_m ** 2,
                      normal, heading) if n else LeafTable.empty()
    return leaves, table


def lognormal_areas(rng: np.random.Generator, n: int, mean_m2: float, sd_m2: float,
                    max_m2: float) -> np.ndarray:
    """n blade areas from the log-normal of this mean and SD, capped at ``max_m2``."""
    if sd_m2 == 0:
        return np.full(n, min(mean_m2, max_m2))
    s2 = math.log1p((sd_m2 / mean_m2) ** 2)
    return np.minimum(rng.lognormal(math.log(mean_m2) - 0.5 * s2, math.sqrt(s2), n), max_m2)
