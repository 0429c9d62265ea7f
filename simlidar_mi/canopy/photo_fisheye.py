"""Real hemispherical (fisheye) photographs → the ring/sector gap table of the virtual camera.

A field DHP goes through the same :class:`~simlidar_mi.canopy.fisheye.GapTable` as a rendered
one: each pixel's θ and φ come from the lens's exact inverse projection about the photo's own
image circle, and rings, sectors and weights are those of :mod:`simlidar_mi.canopy.fisheye`.

Image circle:
    ``circular`` photos: given as (xc, yc, r) in pixels — x to the right and y down from the
    photo's top-left corner, as hemispheR's ``camera_fisheye`` table gives them (e.g.
    Coolpix4500 + FC-E8: 1136, 852, 754) — or detected (:func:`detect_circle`).  ``fullframe``:
    centred, r = half the diagonal (the diagonal spans 180°).
Classification:
    ``blue-otsu`` (looking up): gap = sky, blue > Otsu's threshold of the blue channel of the
    pixels inside the circle (Macfarlane et al. 2007; the blue-channel Otsu default of hemispheR's
    ``binarize_fisheye``); ``canopeo`` (looking down): plant = Canopeo's green rule
    (:mod:`simlidar_mi.canopy.photo`).  A pixel is plant (1) or gap (0): coverage is binary.
Orientation:
    φ assumes the photo's top points to scene azimuth ``heading_deg`` (90°: north at the top when
    +y is north); looking up, east then lies on the left, as the camera sees the sky.

Photos are read and classified in strips (:data:`~simlidar_mi.canopy.photo.TILE_PIXELS`), so a
24 Mpx photo never holds float64 copies of itself.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import PhotoError
from ..io.atomic import staged_dir, write_csv, writes_output
from .fisheye import DEFAULT_RINGS_DEG, FORMATS, TABLE_COLUMNS, FisheyeCamera, GapTable, TableSums
from .fisheye_lens import Lens, lens as make_lens
from .photo import MIN_PIXELS, TILE_PIXELS, _canopeo, _otsu_from_hist
from .photo_read import open_photo

__all__ = ["PHOTO_METHODS", "FisheyePhoto", "fisheye_photo_gap", "detect_circle", "run_fisheye_photos"]

PHOTO_METHODS = ("blue-otsu", "canopeo")
GAP_RGB, PLANT_RGB, OUTSIDE_RGB = (255, 255, 255), (0, 128, 0), (0, 0, 0)


@dataclass
class FisheyePhoto:
    """One classified fisheye photo: its gap table and how it was obtained."""

    path: Path
    table: GapTable
    camera: FisheyeCamera      # the photo's geometry: lens, size, circle, heading
    method: str
    threshold: float | None    # Otsu's blue level (0–255), None for Canopeo
    circle_px: tuple[float, float, float]
    detected: bool             # the circle was detected, not given
    n_inside: int              # pixels whose centre lies inside the circle
    gap_fraction: float        # gap share of the inside pixels (every pixel alike)
    labels: np.ndarray | None = None  # uint8 (H, W): 0 gap, 1 plant, 2 outside; with keep_labels
    lai_table: GapTable | None = None  # on the LAI methods' rings (``lai_spec``), same pass
    lai: dict | None = None  # each method's LAI (run_fisheye_photos(..., lai=True))


def _strips(height: int, width: int):
    rows = max(1, TILE_PIXELS // max(1, width))
    return [(a, min(height, a + rows)) for a in range(0, height, rows)]


def detect_circle(path: str | os.PathLike[str], *, downscale: int = 1, level: float | None = None,
                  ) -> tuple[float, float, float]:
    """The image circle (xc, yc, r) of a circular fisheye photo, pixels of the photo as stored.

    A pixel is lit when its brightest channel exceeds ``level`` (default: midway between the
    corners' darkness and 64, the black surround's ceiling); the circle is fitted (Kåsa's
    algebraic least squares) to the first and last lit pixel of every row and column that does
    not touch the frame.  Dark foliage at the rim puts such points inside the circle, never
    outside it, so points more than 2 px inside the fit are dropped and the fit repeated."""
    with open_photo(path, downscale) as photo:
        w, h = photo.size
        f = photo.downscale
        first_c = np.full(w, -1)
        last_c = np.full(w, -1)
        rows = []
        corner = []
        for a, b in _strips(h, w):
            rgb, _ = photo.strip(a, b)
            bright = rgb.max(axis=2)
            if a == 0:
                corner.append(bright[:8, :8].max())
                corner.append(bright[:8, -8:].max())
            if b == h:
                corner.append(bright[-8:, :8].max())
                corner.append(bright[-8:, -8:].max())
            lv = level if level is not None else 0.5 * (float(max(corner)) + 64.0)
            lit = bright > lv
            any_row = lit.any(axis=1)
            for i in np.nonzero(any_row)[0]:
                cols = np.nonzero(lit[i])[0]
                rows.append((a + i, cols[0], cols[-1]))
            has = lit.any(axis=0)
            top = np.argmax(lit, axis=0)
            bottom = lit.shape[0] - 1 - np.argmax(lit[::-1], axis=0)
            new = has & (first_c < 0)
            first_c[new] = a + top[new]
            last_c[has] = a + bottom[has]
    if len(rows) < 8:
        raise PhotoError(f"{path}: no image circle found (fewer than 8 lit rows); give the circle")
    pts = []
    for y, x0, x1 in rows:
        if x0 > 0:
            pts.append((x0, y + 0.5))
        if x1 < w - 1:
            pts.append((x1 + 1.0, y + 0.5))
    for x in np.nonzero(first_c >= 0)[0]:
        if first_c[x] > 0:
            pts.append((x + 0.5, float(first_c[x])))
        if last_c[x] < h - 1:
            pts.append((x + 0.5, last_c[x] + 1.0))
    p = np.asarray(pts, np.float64).reshape(-1, 2)
    if len(p) < 8:  # every lit row and column touches the frame: a photo without a dark surround
        raise PhotoError(f"{path}: no image circle found (the photo is lit up to its frame, with no dark "
                         "surround); give the circle (--circle XC,YC,R), or --format fullframe")
    keep = np.ones(len(p), bool)
    for _ in range(6):
        xc, yc, r = _kasa(p[keep])
        res = np.hypot(p[:, 0] - xc, p[:, 1] - yc) - r
        new = res > -2.0
        if new.sum() < 8 or np.array_equal(new, keep):
            break
        keep = new
    if not (math.isfinite(xc) and math.isfinite(yc) and math.isfinite(r) and r > 0):
        raise PhotoError(f"{path}: no image circle found (the lit pixels' edges fit no circle); give the "
                         "circle (--circle XC,YC,R)")
    return xc * f, yc * f, r * f


def _kasa(p: np.ndarray) -> tuple[float, float, float]:
    """Algebraic circle fit: x² + y² + D x + E y + F = 0 in least squares."""
    x, y = p[:, 0], p[:, 1]
    m = np.column_stack([x, y, np.ones_like(x)])
    d, e, f = np.linalg.lstsq(m, -(x * x + y * y), rcond=None)[0]
    xc, yc = -d / 2, -e / 2
    return float(xc), float(yc), float(np.sqrt(xc * xc + yc * yc - f))


def fisheye_photo_gap(path: str | os.PathLike[str], lens: str | Lens = "equidistant", *, coeffs=None,
                      circle=None, format: str = "circular", method: str = "blue-otsu",
                      rings_deg=DEFAULT_RINGS_DEG, n_sectors: int = 8, heading_deg: float = 90.0,
                      looking: str = "up", downscale: int = 1, keep_labels: bool = False,
                      mask_path: str | os.PathLike[str] | None = None, lai_spec=None) -> FisheyePhoto:
    """Classify a fisheye photo and tabulate its ring and sector gap fractions.

    ``lens``: a projection or named lens (:mod:`simlidar_mi.canopy.fisheye_lens`), or
    ``"polynomial"`` with ``coeffs``.  ``circle``: (xc, yc, r) pixels of the stored photo, or
    None to detect it (circular) / use the frame (fullframe).  ``mask_path``: also write the
    binary image as a PNG (gap white, plant green, outside black).  ``lai_spec``: (rings,
    sectors) of a second table tabulated in the same pass (:func:`lai_spec`, for :func:`photo_lai`)."""
    p = Path(path)
    ln = make_lens(lens, coeffs, key="lens", coeffs_key="coeffs")
    if format not in FORMATS:
        raise PhotoError(f"{p}: format {format!r} must be one of {', '.join(FORMATS)}")
    if method not in PHOTO_METHODS:
        raise PhotoError(f"{p}: method {method!r} must be one of {', '.join(PHOTO_METHODS)}")
    detected = circle is None and format == "circular"
    if detected:
        circle = detect_circle(p, downscale=downscale)
    with open_photo(p, downscale) as photo:
        w, h = photo.size
        f = photo.downscale
        if circle is None:  # full frame: centred, the half-diagonal spans 90°
            circle_full = (photo.full_size[0] / 2, photo.full_size[1] / 2, 0.5 * np.hypot(*photo.full_size))
        else:
            circle_full = tuple(float(v) for v in circle)
            if len(circle_full) != 3 or not all(map(math.isfinite, circle_full)) or not circle_full[2] > 0:
                raise PhotoError(f"{p}: circle (--circle XC,YC,R) must be three finite numbers xc, yc, r in "
                                 f"pixels with r > 0, got {list(circle)!r}")
        xc, yc, r = (v / f for v in circle_full)
        cam = FisheyeCamera(ln, w, h, np.zeros(3), format, looking, heading_deg=float(heading_deg),
                            centre_px=(xc, yc), circle_radius_px=r)
        threshold = _blue_threshold(photo, cam, p) if method == "blue-otsu" else None
        acc = TableSums(rings_deg, n_sectors)
        acc_lai = TableSums(*lai_spec) if lai_spec is not None else None
        labels = np.empty((h, w), np.uint8) if keep_labels or mask_path is not None else None
        n_in = n_gap = 0
        for a, b in _strips(h, w):
            rgb, opaque = photo.strip(a, b)
            ang = cam.pixel_angles(a, b)
            if opaque is not None:
                ang.inside &= opaque
            plant = rgb[..., 2] <= threshold if threshold is not None else _canopeo(rgb, 0.95, 0.95, 20.0)
            cov = np.where(ang.inside, plant.astype(np.float64), np.nan)
            acc.add(cov, ang)
            if acc_lai is not None:
                acc_lai.add(cov, ang)
            n_in += int(ang.inside.sum())
            n_gap += int((ang.inside & ~plant).sum())
            if labels is not None:
                labels[a:b] = np.where(ang.inside, plant.astype(np.uint8), 2)
    if n_in < MIN_PIXELS:
        raise PhotoError(f"{p}: only {n_in} pixels inside the image circle {circle_full}; at least "
                         f"{MIN_PIXELS} are needed")
    if mask_path is not None:
        from ..io.png import write_label_png  # noqa: PLC0415
        write_label_png(mask_path, labels, (GAP_RGB, PLANT_RGB, OUTSIDE_RGB))
    return FisheyePhoto(p, acc.table(), cam, method, threshold, circle_full, detected, n_in,
                        n_gap / n_in, labels if keep_labels else None,
                        acc_lai.table() if acc_lai is not None else None)


def _blue_threshold(photo, cam: FisheyeCamera, p: Path) -> float:
    """Otsu's threshold of the blue channel over the pixels inside the circle (one bin a level)."""
    w, h = photo.size
    counts = np.zeros(256, np.int64)
    for a, b in _strips(h, w):
        rgb, opaque = photo.strip(a, b)
        rows, cols = np.mgrid[a:b, 0:w]
        x, y = cam.image_xy(cols + 0.5, rows + 0.5)
        inside = np.hypot(x, y) <= cam.radius_px
        if opaque is not None:
            inside &= opaque
        counts += np.bincount(rgb[..., 2][inside], minlength=256)
    levels = np.flatnonzero(counts)
    if len(levels) < 2:
        raise PhotoError(f"{p}: the blue channel is uniform inside the image circle; Otsu's "
                         "threshold is undefined")
    lo, hi = int(levels[0]), int(levels[-1])
    return _otsu_from_hist(counts[lo:hi + 1], np.arange(lo, hi + 1))


PHOTO_CSV_COLUMNS = ("photo", "lens", "method", "threshold", "xc_px", "yc_px", "r_px") + TABLE_COLUMNS
PHOTO_OUTPUTS = (r"fisheye_photo_gap\.csv", r"fisheye_photo_lai\.csv", r".+_fisheye_mask\.png")
LAI_CSV_COLUMNS = ("photo", "method", "lai", "lai2200_acf", "lai2200_le", "lai2200_difn")


def _lai_settings(settings: dict | None) -> dict:
    from ..config.keys import SECTIONS  # noqa: PLC0415
    return {**{k: key.default for k, key in SECTIONS["lai_methods"].items()}, **(settings or {})}


def lai_spec(settings: dict | None = None) -> tuple[list, int]:
    """(rings, sectors) the LAI methods read, for ``fisheye_photo_gap(..., lai_spec=...)``."""
    from .lai_table import method_rings  # noqa: PLC0415
    s = _lai_settings(settings)
    return method_rings(s["rings_deg"]), int(s["n_sectors"])


def photo_lai(photo: FisheyePhoto, settings: dict | None = None) -> dict[str, float]:
    """The gap-fraction LAI methods on one classified photo (tabulated with ``lai_spec``), by
    the code ``evaluate-photo`` runs on virtual images (:mod:`simlidar_mi.canopy.lai_table`).

    ``settings``: ``[lai_methods]`` keys; default the schema's defaults (rings 0–70° by 10°,
    8 sectors, the PAI-10 floor, no wood correction, the LAI-2200 without a view cap)."""
    from .lai_table import estimate_methods, lai2200_of  # noqa: PLC0415
    s = _lai_settings(settings)
    table = photo.lai_table
    want_rings, want_sectors = lai_spec(s)
    if table is None or table.gap.shape != (len(want_rings), want_sectors) or not np.array_equal(
            np.stack([table.ring_lo_deg, table.ring_hi_deg], 1), np.asarray(want_rings, float)):
        raise PhotoError(f"{photo.path}: classify with lai_spec=lai_spec(settings) to run the LAI methods")
    est, readings, read_px = estimate_methods(table.gap[None], table.n_pixels[None].astype(float), s)
    out = dict(est[0])
    ins = lai2200_of(readings, read_px, s)
    out.update(lai2200_acf=ins.acf, lai2200_le=ins.lai_effective, lai2200_difn=ins.difn)
    return out


@writes_output("out_dir")
def run_fisheye_photos(paths, out_dir: str | os.PathLike[str] | None = None, *, write_masks: bool = True,
                       lai: bool = False, **options) -> list[FisheyePhoto]:
    """:func:`fisheye_photo_gap` on every photo (same ``options``); with ``out_dir`` write
    ``fisheye_photo_gap.csv`` (the virtual camera's table columns, one block per photo) and, with
    ``write_masks``, ``<stem>_fisheye_mask.png`` per photo, atomically; with ``lai``,
    ``fisheye_photo_lai.csv``: each photo's LAI by each method (:func:`photo_lai`)."""
    if lai:
        options["lai_spec"] = lai_spec()
    if out_dir is None:
        return [fisheye_photo_gap(p, **options) for p in paths]
    out, results = Path(out_dir), []
    with staged_dir(out, PHOTO_OUTPUTS) as stage:
        for p in paths:
            mask = stage / f"{Path(p).stem}_fisheye_mask.png" if write_masks else None
            results.append(fisheye_photo_gap(p, mask_path=mask, **options))
        rows = []
        for r in results:
            xc, yc, rad = r.circle_px
            lens_name = r.camera.lens.name or r.camera.lens.projection
            rows += r.table.rows(photo=r.path.name, lens=lens_name, method=r.method,
                                 threshold="" if r.threshold is None else r.threshold,
                                 xc_px=xc, yc_px=yc, r_px=rad)
        write_csv(stage / "fisheye_photo_gap.csv", PHOTO_CSV_COLUMNS, rows)
        if lai:
            lai_rows = []
            for r in results:
                est = photo_lai(r)
                extra = {k: est.pop(k) for k in ("lai2200_acf", "lai2200_le", "lai2200_difn")}
                lai_rows += [{"photo": r.path.name, "method": m, "lai": v,
                              **(extra if m == "lai2200" else {})} for m, v in est.items()]
                r.lai = {**est, **extra}
            write_csv(stage / "fisheye_photo_lai.csv", LAI_CSV_COLUMNS, lai_rows)
    return results
