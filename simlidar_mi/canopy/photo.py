"""Gap fraction and canopy cover from real photographs.

Three classifiers, each turning an 8-bit RGB photo into a vegetation mask:

``"canopeo"``
    Canopeo rule for nadir (downward) crop photos (Patrignani & Ochsner 2015,
    Agron. J. 107:2312): green where R/G < 0.95 and B/G < 0.95 and
    2G − R − B > 20, on 0–255 values.
``"exg-otsu"``
    Excess green on chromatic coordinates, ExG = 2g − r − b with
    r = R/(R+G+B) etc., thresholded with Otsu's method (Woebbecke et al. 1995;
    Meyer & Neto 2008). Vegetation = ExG > threshold.
``"blue-otsu"``
    Upward cover photos (Macfarlane et al. 2007; coveR2, Chianucci et al.
    2022): Otsu threshold of the blue channel; gap (sky) = blue > threshold.

Every call also writes a mask PNG (vegetation dark green, background white,
analysed crop outlined in magenta, transparent pixels black) so a person can see
what was counted. Cover is the vegetation fraction of the analysed pixels and
P0 = 1 − cover is the gap fraction.

Large photos are classified in strips (:data:`TILE_PIXELS`), with the same result
as the whole array: the Otsu methods first accumulate the crop's histogram over the
strips. Fully transparent pixels (alpha 0) are not analysed; photos or crops with
fewer than :data:`MIN_PIXELS` pixels to analyse are refused. ``downscale`` trades
exactness for memory (see :func:`photo_gap`); reading is in
:mod:`simlidar_mi.canopy.photo_read`.

Examples
--------
>>> from simlidar_mi.canopy.photo import photo_gap            # doctest: +SKIP
>>> r = photo_gap("IMG1.JPG", "blue-otsu", mask_dir="masks")  # doctest: +SKIP
>>> r.threshold, round(r.p0, 3)                         # doctest: +SKIP
(104.0, 0.435)
"""
from __future__ import annotations

import os
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Literal, Sequence, Union

import numpy as np

from .._runtime.progress import make_progress
from ..errors import PhotoError, SimlidarError
from ..io.png import (BACKGROUND_RGB, FOREGROUND_RGB, WINDOW_RGB, dimmed, write_label_png,
                      write_mask_png)
from .photo_read import DOWNSCALES, UprightPhoto, open_photo, read_rgb

__all__ = ["METHODS", "MIN_PIXELS", "DOWNSCALES", "PhotoGapResult", "photo_gap", "classify_rgb",
           "read_rgb", "parse_crop", "crop_box", "default_mask_path", "write_mask_png"]

Method = Literal["canopeo", "exg-otsu", "blue-otsu"]
METHODS: tuple[str, ...] = ("canopeo", "exg-otsu", "blue-otsu")
#: A crop: central fraction in (0, 1], a pixel box (x0, y0, x1, y1), the CLI
#: string form of either ("0.5", "10,20,300,400"), or None for the whole image.
Crop = Union[float, Sequence[int], str, None]
Box = tuple[int, int, int, int]

#: Default directory for mask PNGs, relative to the current directory (the
#: photos themselves may sit in a read-only folder).
DEFAULT_MASK_DIR = Path("photo_masks")
#: Fewest pixels a photo (or its crop) may offer to be classified: 4 a histogram bin on
#: average for the Otsu methods, and a cover quantised in steps of at most 0.001.
MIN_PIXELS = 1024
#: Pixels per strip a photo is worked on in (bounds the float64 working memory to ~100 MB).
TILE_PIXELS = 1 << 20
#: A photo's progress bar appears only once it has taken this long (small photos stay quiet).
PROGRESS_DELAY_S = 1.0
#: Mask PNG colours by label: background, vegetation, both dimmed outside the crop,
#: the crop's outline, and transparent (not analysed) pixels in black.
MASK_COLOURS = (BACKGROUND_RGB, FOREGROUND_RGB, dimmed(BACKGROUND_RGB), dimmed(FOREGROUND_RGB),
                WINDOW_RGB, (0, 0, 0))


@dataclass(frozen=True)
class PhotoGapResult:
    """Gap fraction of one photo, with what produced it.

    Attributes
    ----------
    file : pathlib.Path
        The photo.
    method : str
        One of :data:`METHODS`.
    threshold : float or None
        Otsu threshold (ExG units for ``"exg-otsu"``, 0–255 blue value for
        ``"blue-otsu"``); None for ``"canopeo"``, whose fixed thresholds are in
        ``params``.
    cover : float
        Vegetation fraction of the analysed pixels, 0–1.
    p0 : float
        Gap fraction, ``1 - cover``.
    n_pixels : int
        Pixels analysed (inside ``crop``, not fully transparent).
    n_vegetation : int
        Of those, pixels classified as vegetation.
    crop : (x0, y0, x1, y1)
        Half-open pixel box analysed, in the (EXIF-upright, downscaled) image.
    image_size : (width, height)
        Size of the whole analysed (upright, downscaled) image in pixels.
    mask_file : pathlib.Path or None
        The mask PNG written.
    params : tuple of (name, value)
        Method parameters (the Canopeo thresholds).
    n_transparent : int
        Pixels inside ``crop`` left out because their alpha is 0.
    downscale : int
        The photo was analysed at 1/downscale of its size in each dimension.
    """

    file: Path
    method: str
    threshold: float | None
    cover: float
    p0: float
    n_pixels: int
    n_vegetation: int
    crop: Box
    image_size: tuple[int, int]
    mask_file: Path | None = None
    params: tuple[tuple[str, float], ...] = field(default=())
    n_transparent: int = 0
    downscale: int = 1

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-ready dict (paths as strings, tuples as lists)."""
        d = asdict(self)
        d["file"] = str(self.file)
        d["mask_file"] = str(self.mask_file) if self.mask_file is not None else None
        d["crop"] = list(self.crop)
        d["image_size"] = list(self.image_size)
        d["params"] = dict(self.params)
        return d


# --- crops -------------------------------------------------------------------

def parse_crop(crop: Crop, *, file: str | os.PathLike[str] | None = None) -> float | Box | None:
    """Normalise a crop given as a number, a 4-sequence or a CLI string.

    ``"0.5"`` or ``0.5`` is a central fraction; ``"x0,y0,x1,y1"`` or a
    4-sequence of integers is a half-open pixel box. Raises :class:`PhotoError`
    (naming ``file`` when given) on anything else.
    """
    where = f"{file}: " if file is not None else ""
    if crop is None:
        return None
    if isinstance(crop, str):
        text = crop.strip()
        parts = [s.strip() for s in text.split(",")]
        try:
            if len(parts) == 1:
                return parse_crop(float(parts[0]), file=file)
            if len(parts) == 4:
                return parse_crop(tuple(int(s) for s in parts), file=file)
        except ValueError:
            pass
        raise PhotoError(f"{where}crop {crop!r}: expected a fraction in (0, 1] such as '0.5' "
                         "or a pixel box 'x0,y0,x1,y1' of integers")
    if isinstance(crop, bool):
        raise PhotoError(f"{where}crop {crop!r}: expected a fraction or a pixel box")
    if isinstance(crop, (int, float, np.integer, np.floating)):
        f = float(crop)
        if not (0.0 < f <= 1.0):
            raise PhotoError(f"{where}crop {crop!r}: a central fraction must be in (0, 1]")
        return f
    try:
        vals = tuple(crop)
    except TypeError:
        raise PhotoError(f"{where}crop {crop!r}: expected a fraction or a pixel box") from None
    if len(vals) != 4 or not all(isinstance(v, (int, np.integer)) and not isinstance(v, bool)
                                 for v in vals):
        raise PhotoError(f"{where}crop {crop!r}: a pixel box is 4 integers (x0, y0, x1, y1)")
    return tuple(int(v) for v in vals)  # type: ignore[return-value]


def crop_box(crop: Crop, width: int, height: int, *,
             file: str | os.PathLike[str] | None = None) -> Box:
    """Half-open pixel box ``(x0, y0, x1, y1)`` for ``crop`` in a width x height image.

    A fraction ``f`` keeps ``round(f * width)`` by ``round(f * height)`` pixels
    (at least 1) centred in the image (odd leftovers go to the right/bottom).
    A pixel box must satisfy ``0 <= x0 < x1 <= width`` and
    ``0 <= y0 < y1 <= height``; otherwise :class:`PhotoError` names the file,
    the crop and the image size.
    """
    c = parse_crop(crop, file=file)
    if c is None:
        return (0, 0, width, height)
    if isinstance(c, float):
        cw = max(1, min(width, round(c * width)))
        ch = max(1, min(height, round(c * height)))
        x0 = (width - cw) // 2
        y0 = (height - ch) // 2
        return (x0, y0, x0 + cw, y0 + ch)
    x0, y0, x1, y1 = c
    if not (0 <= x0 < x1 <= width and 0 <= y0 < y1 <= height):
        where = f"{file}: " if file is not None else ""
        raise PhotoError(f"{where}crop {x0},{y0},{x1},{y1} is not a non-empty box inside the "
                         f"{width}x{height} image (need 0 <= x0 < x1 <= {width}, "
                         f"0 <= y0 < y1 <= {height})")
    return (x0, y0, x1, y1)


# --- classifiers -------------------------------------------------------------

def _canopeo(rgb: np.ndarray, rg: float, bg: float, exg: float) -> np.ndarray:
    R, G, B = (rgb[..., i].astype(np.float64) for i in range(3))
    # G = 0: ratios are undefined; take them as +inf so the pixel is not green.
    # This never changes the result, since 2G - R - B = -(R + B) <= 0 fails anyway.
    inf = np.full(G.shape, np.inf)
    r_g = np.divide(R, G, out=inf.copy(), where=G > 0)
    b_g = np.divide(B, G, out=inf, where=G > 0)
    # three separate & (np.logical_and(a, b, c) would treat c as the output array)
    return (r_g < rg) & (b_g < bg) & (2.0 * G - R - B > exg)


def _exg(rgb: np.ndarray) -> np.ndarray:
    R, G, B = (rgb[..., i].astype(np.float64) for i in range(3))
    s = R + G + B
    # ExG = 2g - r - b = (2G - R - B) / (R + G + B); black pixels (s = 0) get 0
    return np.divide(2.0 * G - R - B, s, out=np.zeros_like(s), where=s > 0)


def _otsu(values: np.ndarray, what: str, file: Path | None) -> float:
    from skimage.filters import threshold_otsu
    if values.size == 0 or np.all(values == values.flat[0]):
        where = f"{file}: " if file is not None else ""
        raise PhotoError(f"{where}{what} is uniform inside the crop; Otsu's threshold is "
                         "undefined (nothing to separate)")
    return float(threshold_otsu(values))


def classify_rgb(rgb: np.ndarray, method: Method, box: Box | None = None, *,
                 canopeo_rg: float = 0.95, canopeo_bg: float = 0.95,
                 canopeo_exg: float = 20.0,
                 file: Path | None = None) -> tuple[np.ndarray, float | None]:
    """Classify every pixel of an RGB array as vegetation (True) or not.

    Parameters
    ----------
    rgb : numpy.ndarray of uint8, shape (height, width, 3)
    method : {"canopeo", "exg-otsu", "blue-otsu"}
    box : (x0, y0, x1, y1), optional
        Half-open pixel box from which Otsu thresholds are computed; the whole
        image is still classified (with that threshold) so the mask PNG can show
        context. None means the whole image.
    canopeo_rg, canopeo_bg, canopeo_exg : float
        Canopeo thresholds on R/G, B/G and 2G − R − B (0–255 units).
    file : pathlib.Path, optional
        Named in error messages.

    Returns
    -------
    mask : numpy.ndarray of bool, shape (height, width)
    threshold : float or None
        The Otsu threshold, or None for Canopeo.

    Notes
    -----
    ``"exg-otsu"`` uses :func:`skimage.filters.threshold_otsu` on the float
    ExG values (256 bins over their [min, max]). Otsu assumes a bimodal
    histogram, so on near-full (or near-zero) cover the histogram is
    unimodal and the threshold splits the vegetation itself: cover is then
    badly underestimated. Prefer Canopeo there.

    ``"blue-otsu"`` passes the uint8 blue channel to
    :func:`skimage.filters.threshold_otsu`. For integer input scikit-image
    builds one bin per integer value over [min, max] of the data, which is the
    histogram autothresholdr (used by coveR2) builds before calling ImageJ's
    Otsu; both maximise the between-class variance, take the first maximum
    and return the last level of the lower class. So the threshold equals
    ImageJ's ("Otsu" in Auto Threshold) and gap = blue > threshold, as in
    coveR2 (104 for coveR2's IMG1.JPG).
    """
    h, w = rgb.shape[:2]
    x0, y0, x1, y1 = box if box is not None else (0, 0, w, h)
    if method == "canopeo":
        return _canopeo(rgb, canopeo_rg, canopeo_bg, canopeo_exg), None
    if method == "exg-otsu":
        exg = _exg(rgb)
        t = _otsu(exg[y0:y1, x0:x1], "ExG", file)
        return exg > t, t
    if method == "blue-otsu":
        blue = rgb[..., 2]
        t = _otsu(blue[y0:y1, x0:x1], "the blue channel", file)
        return ~(blue > t), t  # vegetation = not gap
    where = f"{file}: " if file is not None else ""
    raise PhotoError(f"{where}unknown method {method!r}; valid: {', '.join(METHODS)}")


# --- the API call ------------------------------------------------------------

def default_mask_path(photo: str | os.PathLike[str], method: str,
                      mask_dir: str | os.PathLike[str] = DEFAULT_MASK_DIR) -> Path:
    """``<mask_dir>/<photo stem>_<method>_mask.png``."""
    return Path(mask_dir) / f"{Path(photo).stem}_{method}_mask.png"


def _strips(y0: int, y1: int, width: int) -> list[tuple[int, int]]:
    rows = max(1, TILE_PIXELS // max(1, width))
    return [(y, min(y1, y + rows)) for y in range(y0, y1, rows)]


def _otsu_from_hist(counts: np.ndarray, centres: np.ndarray) -> float:
    """Otsu's threshold of a histogram accumulated over strips.

    The histogram is the one :func:`skimage.filters.threshold_otsu` builds from the
    whole crop (256 bins over [min, max] for ExG, one bin per level for blue), so the
    threshold is the same as from the whole array.
    """
    from skimage.filters import threshold_otsu
    return float(threshold_otsu(hist=(counts, centres)))


def _otsu_threshold(photo: UprightPhoto, method: str, box: Box, file: Path, tick) -> float:
    """Two passes over the crop's strips for ExG (range, then histogram), one for blue."""
    x0, y0, x1, y1 = box
    what = "ExG" if method == "exg-otsu" else "the blue channel"
    uniform = PhotoError(f"{file}: {what} is uniform inside the crop; Otsu's threshold is "
                         "undefined (nothing to separate)")

    def values():
        for a, b in _strips(y0, y1, photo.size[0]):
            rgb, opaque = photo.strip(a, b)
            rgb = rgb[:, x0:x1]
            v = _exg(rgb) if method == "exg-otsu" else rgb[..., 2]
            tick(rgb.shape[0] * rgb.shape[1])
            yield v if opaque is None else v[opaque[:, x0:x1]]

    def enough(n: int) -> None:
        if n < MIN_PIXELS:
            raise PhotoError(f"{file}: {n} pixels to analyse once the {area - n} transparent "
                             f"ones are left out; at least {MIN_PIXELS} are needed to classify "
                             "a photo")

    area = (x1 - x0) * (y1 - y0)
    if method == "blue-otsu":
        counts = np.zeros(256, np.int64)
        for v in values():
            counts += np.bincount(v.ravel(), minlength=256)
        enough(int(counts.sum()))
        levels = np.flatnonzero(counts)
        if len(levels) < 2:
            raise uniform
        lo, hi = int(levels[0]), int(levels[-1])
        return _otsu_from_hist(counts[lo:hi + 1], np.arange(lo, hi + 1))
    lo, hi, n = np.float64(np.inf), np.float64(-np.inf), 0
    for v in values():
        if v.size:
            lo, hi, n = min(lo, v.min()), max(hi, v.max()), n + v.size
    enough(n)
    if not lo < hi:
        raise uniform
    counts = np.zeros(256, np.int64)
    for v in values():
        counts += np.histogram(v, bins=256, range=(lo, hi))[0]
    edges = np.histogram(np.empty(0), bins=256, range=(lo, hi))[1]
    return _otsu_from_hist(counts, (edges[:-1] + edges[1:]) / 2.0)


def _classify_photo(photo: UprightPhoto, method: str, box: Box, rg: float, bg: float,
                    exg: float, file: Path, tick) -> tuple[np.ndarray, float | None, int, int, int]:
    """Classify ``photo`` strip by strip; (labels, threshold, n, n_veg, n_transparent).

    ``labels`` (uint8, height × width) index :data:`MASK_COLOURS`; counts are inside ``box``.
    """
    w, h = photo.size
    x0, y0, x1, y1 = box
    t = None if method == "canopeo" else _otsu_threshold(photo, method, box, file, tick)
    labels = np.empty((h, w), np.uint8)
    n = n_veg = n_clear = 0
    for a, b in _strips(0, h, w):
        rgb, opaque = photo.strip(a, b)
        if method == "canopeo":
            veg = _canopeo(rgb, rg, bg, exg)
        elif method == "exg-otsu":
            veg = _exg(rgb) > t
        else:
            veg = ~(rgb[..., 2] > t)  # vegetation = not gap
        lab = labels[a:b]
        lab[...] = veg
        lab[:, :x0] += 2  # outside the crop: dimmed
        lab[:, x1:] += 2
        if b <= y0 or a >= y1:
            lab[:, x0:x1] += 2
        else:
            r0, r1 = max(a, y0) - a, min(b, y1) - a
            lab[:r0, x0:x1] += 2
            lab[r1:, x0:x1] += 2
            inside = np.ones((r1 - r0, x1 - x0), bool) if opaque is None else opaque[r0:r1, x0:x1]
            n += int(np.count_nonzero(inside))
            n_veg += int(np.count_nonzero(veg[r0:r1, x0:x1] & inside))
            n_clear += inside.size - int(np.count_nonzero(inside))
        if opaque is not None:
            lab[~opaque] = 5
        tick(rgb.shape[0] * w)
    # the crop's outline, drawn as io.png.render_mask_rgb draws it
    th = max(1, round(min(h, w) / 400))
    th = min(th, (x1 - x0 + 1) // 2, (y1 - y0 + 1) // 2) or 1
    for sl in ((slice(y0, y0 + th), slice(x0, x1)), (slice(y1 - th, y1), slice(x0, x1)),
               (slice(y0, y1), slice(x0, x0 + th)), (slice(y0, y1), slice(x1 - th, x1))):
        labels[sl] = 4
    return labels, t, n, n_veg, n_clear


def _analysed_box(parsed: float | Box | None, photo: UprightPhoto, file: Path) -> Box:
    """The crop in the analysed image: a pixel box is given in the photo's own (upright,
    full-size) pixels and scaled outwards by the downscale; a fraction applies as is."""
    w, h = photo.size
    f = photo.downscale
    if f == 1 or not isinstance(parsed, tuple):
        return crop_box(parsed, w, h, file=file)
    x0, y0, x1, y1 = crop_box(parsed, *photo.full_size, file=file)
    return (x0 // f, y0 // f, min(w, -(-x1 // f)), min(h, -(-y1 // f)))


def photo_gap(path: str | os.PathLike[str], method: Method = "canopeo", crop: Crop = None, *,
              canopeo_rg: float = 0.95, canopeo_bg: float = 0.95, canopeo_exg: float = 20.0,
              mask_path: str | os.PathLike[str] | None = None,
              mask_dir: str | os.PathLike[str] | None = None, write_mask: bool = True,
              downscale: int = 1, progress: bool = False) -> PhotoGapResult:
    """Gap fraction (P0) and vegetation cover of one photo.

    The photo is worked on in strips of about :data:`TILE_PIXELS` pixels, so memory is
    the decoded photo (4 bytes a pixel in Pillow), its mask (1 byte a pixel) and one
    strip: about 0.5 GB for an 8000 × 8000 photo. The result is the same as classifying
    the whole array at once (:func:`classify_rgb`): Canopeo is per pixel, and the Otsu
    methods accumulate the whole crop's histogram before thresholding.

    Parameters
    ----------
    path : path-like
        An 8-bit RGB photo (JPEG, PNG, TIFF, ...). With alpha (RGBA, or a palette
        with transparency), fully transparent pixels are left out of the analysis
        and of the Otsu histogram (``n_transparent`` counts them; black in the mask
        PNG). Greyscale, CMYK and 16-bit images raise :class:`PhotoError`.
    method : {"canopeo", "exg-otsu", "blue-otsu"}
        Classifier; see the module docstring and :func:`classify_rgb`.
        ``"canopeo"`` and ``"exg-otsu"`` are for nadir (downward) photos,
        ``"blue-otsu"`` for upward photos against the sky.
    crop : float, (x0, y0, x1, y1), str or None
        Central fraction in (0, 1] kept in each dimension (0.5 keeps the
        central 50 % of the width and of the height), or a half-open pixel box
        in the upright, full-size photo, or its CLI string (``"0.5"``,
        ``"10,10,500,400"``). None analyses the whole image.
    canopeo_rg, canopeo_bg, canopeo_exg : float
        Canopeo thresholds: R/G < canopeo_rg, B/G < canopeo_bg,
        2G − R − B > canopeo_exg (0–255 units). Pixels with G = 0 are never
        green.
    mask_path : path-like, optional
        Where to write the mask PNG.
    mask_dir : path-like, optional
        Directory for ``<photo stem>_<method>_mask.png`` when ``mask_path`` is
        not given; default ``./photo_masks/`` (never beside the photo, whose
        folder may be read-only).
    write_mask : bool
        False: no mask is written (``mask_file`` None); ``simlidar-mi photo-gap`` writes masks
        only into its ``--out`` folder.
    downscale : {1, 2, 4, 8}
        Analyse the photo at 1/downscale of its size in each dimension (JPEGs are
        decoded at that size, so memory falls by downscale²). Averaging mixes leaf
        and background pixels and moves P0, the more the finer the foliage is in
        pixels: on the real test photos by up to 0.025 at 2, 0.076 at 4 and 0.136 at
        8 (grass at 512 × 512), by under 0.01 on a 4288 × 2848 photo (BENCHMARKS.md).
        The default 1 is exact; use a downscale only on large photos, and compare.
    progress : bool
        Show a progress bar (on stderr) when the photo takes more than a second.

    Returns
    -------
    PhotoGapResult

    Raises
    ------
    PhotoError
        Missing, unreadable, truncated or non-RGB photo; a crop outside the
        image; fewer than :data:`MIN_PIXELS` pixels to analyse; an unknown
        method or downscale; a uniform crop for the Otsu methods; a mask
        PNG that cannot be written. Messages name the file.
    """
    p = Path(path)
    if method not in METHODS:
        raise PhotoError(f"{p}: unknown method {method!r}; valid: {', '.join(METHODS)}")
    parsed = parse_crop(crop, file=p)  # bad crop strings fail before decoding
    with open_photo(p, downscale) as photo:
        w, h = photo.size
        box = _analysed_box(parsed, photo, p)
        x0, y0, x1, y1 = box
        at = f" at downscale {downscale}" if downscale > 1 else ""
        if (x1 - x0) * (y1 - y0) < MIN_PIXELS:
            raise PhotoError(f"{p}: {x1 - x0}x{y1 - y0} pixels to analyse{at} (crop {x0},{y0},"
                             f"{x1},{y1} of {w}x{h}); at least {MIN_PIXELS} are needed to "
                             "classify a photo")
        passes = {"canopeo": 0, "exg-otsu": 2, "blue-otsu": 1}[method]
        with make_progress(progress).stage(p.name, w * h + passes * (x1 - x0) * (y1 - y0),
                                           "px", PROGRESS_DELAY_S) as bar:
            labels, threshold, n, n_veg, n_clear = _classify_photo(
                photo, method, box, canopeo_rg, canopeo_bg, canopeo_exg, p, bar.update)
    if n < MIN_PIXELS:
        raise PhotoError(f"{p}: {n} pixels to analyse{at} once the {n_clear} transparent ones "
                         f"are left out; at least {MIN_PIXELS} are needed to classify a photo")
    cover = n_veg / n
    out = None
    if write_mask:
        out = Path(mask_path) if mask_path is not None else default_mask_path(
            p, method, mask_dir if mask_dir is not None else DEFAULT_MASK_DIR)
        try:
            out = write_label_png(out, labels, MASK_COLOURS)
        except SimlidarError as exc:
            raise PhotoError(f"{p}: cannot save the classification mask: {exc}") from exc
    params: tuple[tuple[str, float], ...] = ()
    if method == "canopeo":
        params = (("rg", float(canopeo_rg)), ("bg", float(canopeo_bg)),
                  ("exg", float(canopeo_exg)))
    return PhotoGapResult(file=p, method=method, threshold=threshold, cover=cover,
                          p0=1.0 - cover, n_pixels=n, n_vegetation=n_veg, crop=box,
                          image_size=(w, h), mask_file=out, params=params,
                          n_transparent=n_clear, downscale=downscale)
