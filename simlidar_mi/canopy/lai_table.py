"""Every gap-fraction LAI method on ring × sector gap tables: one path for virtual and field photos.

``evaluate-photo`` (virtual fisheye images, scored against the truth) and ``fisheye-photo --lai``
(a user's field photographs) both tabulate their images on :func:`method_rings` and call
:func:`estimate_methods`, so the two give the same table by the same code.
"""
from __future__ import annotations

import numpy as np

from . import lai2200 as li
from . import lai_methods as lm

HINGE_RING_DEG = (55.0, 60.0)  # the 57.5° method's ring
POSITION_METHODS = ("miller", "miller_lx", "hinge_57", "lai2200")


def hemisphere_rings(rings_deg) -> list[tuple[float, float]]:
    """Ring edges (0, 10, …, 70) as (lo, hi) pairs: Miller's and Lang–Xiang's rings."""
    e = [float(x) for x in rings_deg]
    return list(zip(e[:-1], e[1:]))


def method_rings(rings_deg) -> list[tuple[float, float]]:
    """The rings every method needs, in this order: the hemisphere's (``rings_deg`` edges), the
    57.5° ring, the LAI-2200's five."""
    return hemisphere_rings(rings_deg) + [HINGE_RING_DEG] + [tuple(r) for r in li.RING_BOUNDS_DEG]


def method_views(rings_deg) -> dict[str, tuple[float, float]]:
    """The zenith range each method's reading comes from (a footprint's θ bounds)."""
    hemi = hemisphere_rings(rings_deg)
    return {"miller": (hemi[0][0], hemi[-1][1]), "miller_lx": (hemi[0][0], hemi[-1][1]),
            "hinge_57": HINGE_RING_DEG, "lai2200": (0.0, li.RING_BOUNDS_DEG[-1][1])}


def estimate_methods(gaps: np.ndarray, n_cells: np.ndarray, settings: dict):
    """Each image's LAI by each method, and the LAI-2200's readings.

    ``gaps`` and ``n_cells`` (n_images, R, S): gap fraction and pixels (or rays) per cell on
    :func:`method_rings`; ``settings``: the ``[lai_methods]`` keys (rings_deg, n_sectors,
    zero_gap, pai_sat, wood_to_total, view_cap_deg, heading_deg).  Returns (per image a dict
    method → LAI, the LAI-2200 readings (n_images, 5), their pixel counts (n_images, 5)).
    """
    s = settings
    hemi = hemisphere_rings(s["rings_deg"])
    n_h = len(hemi)
    n_sec = int(s["n_sectors"])
    floor = {"zero_gap": s["zero_gap"], "pai_sat": float(s["pai_sat"])}
    alpha = float(s["wood_to_total"])
    sector_az = (np.arange(n_sec) + 0.5) * 360.0 / n_sec
    readings = li.ring_transmittance(gaps[:, n_h + 1:], sector_az, view_cap_deg=s["view_cap_deg"],
                                     heading_deg=s["heading_deg"], sector_weights=n_cells[:, n_h + 1:])
    cap = li.cap_mask(sector_az, s["view_cap_deg"], s["heading_deg"])
    read_px = np.where(cap, n_cells[:, n_h + 1:], 0.0).sum(axis=2) if cap.any() else n_cells[:, n_h + 1:, 0]
    pix = pixel_floor(s)
    out = []
    for i in range(len(gaps)):
        g_h = gaps[i, :n_h]
        lx = lm.lang_xiang(hemi, g_h, **floor, **pix(n_cells[i, :n_h]))
        out.append({
            "miller": lm.miller_lai(hemi, g_h, sector_weights=n_cells[i, :n_h], **floor, **pix(n_cells[i, :n_h])),
            "miller_lx": (1.0 - alpha) * lx.lai_lx,
            "hinge_57": lm.hinge_lai(float(lm.ring_gap_fraction(gaps[i, n_h:n_h + 1], n_cells[i, n_h:n_h + 1])[0]),
                                     **floor, **pix(n_cells[i, n_h].sum())),
            "lai2200": float(li.lai2200(readings[i][None], **floor, **pix(read_px[i][None])).lai)})
    return out, readings, read_px


def pixel_floor(settings: dict):
    """Keyword arguments giving the methods the pixel counts when the floor is one pixel's worth."""
    return (lambda a: {"n_pixels": a}) if settings["zero_gap"] == "pixel" else (lambda a: {})


def lai2200_of(readings: np.ndarray, read_px: np.ndarray, settings: dict):
    """The instrument's result over several readings (its log average: LAI, ACF, L_e, DIFN)."""
    floor = {"zero_gap": settings["zero_gap"], "pai_sat": float(settings["pai_sat"])}
    return li.lai2200(readings, **floor, **pixel_floor(settings)(read_px))
