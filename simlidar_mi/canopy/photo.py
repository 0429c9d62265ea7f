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
analysed crop outlined in magenta) so a person can see what was counted.
Cover is the vegetation fraction of the analysed pixels and P0 = 1 − cover
is the gap fraction.

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
from PIL import Image, ImageFile, ImageOps, UnidentifiedImageError

from ..errors import PhotoError, SimlidarError
from ..io.png import write_mask_png

__all__ = ["METHODS", "PhotoGapResult", "photo_gap", "classify_rgb", "read_rgb",
           "parse_crop", "crop_box", "default_mask_path", "write_mask_png"]

Method = Literal["canopeo", "exg-otsu", "blue-otsu"]
METHODS: tuple[str, ...] = ("canopeo", "exg-otsu", "blue-otsu")
#: A crop: central fraction in (0, 1], a pixel box (x0, y0, x1, y1), the CLI
#: string form of either ("0.5", "10,20,300,400"), or None for the whole image.
Crop = Union[float, Sequence[int], str, None]
Box = tuple[int, int, int, int]

#: Default directory for mask PNGs, relative to the current directory (the
#: photos themselves may sit in a read-only folder).
DEFAULT_MASK_DIR = Path("photo_masks")


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
        Pixels analysed (inside ``crop``).
    n_vegetation : int
        Of those, pixels classified as vegetation.
    crop : (x0, y0, x1, y1)
        Half-open pixel box analysed, in the (EXIF-upright) image.
    image_size : (width, height)
        Size of the whole (upright) image in pixels.
    mask_file : pathlib.Path or None
        The mask PNG written.
    params : tuple of (name, value)
        Method parameters (the Canopeo thresholds).
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

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-ready dict (paths as strings, tuples as lists)."""
        d = asdict(self)
        d["file"] = str(self.file)
        d["mask_file"] = str(self.mask_file) if self.mask_file is not None else None
        d["crop"] = list(self.crop)
        d["image_size"] = list(self.image_size)
        d["params"] = dict(self.params)
        return d


# --- reading -----------------------------------------------------------------

def _rawmodes(im: Image.Image) -> list[str]:
    out = []
    for tile in getattr(im, "tile", None) or []:
        args = tile[3] if isinstance(tile, tuple) and len(tile) > 3 else getattr(tile, "args", None)
        if isinstance(args, str):
            out.append(args)
        elif isinstance(args, tuple) and args and isinstance(args[0], str):
            out.append(args[0])
    return out


def read_rgb(path: str | os.PathLike[str]) -> np.ndarray:
    """Read a photo as an 8-bit RGB array, refusing anything doubtful.

    The image is turned upright from its EXIF orientation (so pixel boxes and
    mask PNGs match what image viewers show). RGBA/RGBX/palette images are
    converted to RGB (alpha dropped); greyscale, CMYK, 16-bit and float images
    are refused.

    Parameters
    ----------
    path : path-like
        The photo.

    Returns
    -------
    numpy.ndarray of uint8, shape (height, width, 3)

    Raises
    ------
    PhotoError
        Missing, unreadable, truncated or non-RGB files; the message names the
        file and what is wrong.
    """
    p = Path(path)
    if not p.exists():
        raise PhotoError(f"{p}: no such file")
    if p.is_dir():
        raise PhotoError(f"{p}: is a directory, not a photo")
    if ImageFile.LOAD_TRUNCATED_IMAGES:
        # someone enabled Pillow's silent grey fill: truncation would go unnoticed
        raise PhotoError(f"{p}: PIL.ImageFile.LOAD_TRUNCATED_IMAGES is True, so truncated "
                         "photos cannot be detected; set it back to False")
    try:
        with Image.open(p) as im:
            mode, raw = im.mode, _rawmodes(im)
            if mode in ("1", "L", "LA", "La", "I", "I;16", "I;16B", "I;16L", "I;16N", "F"):
                raise PhotoError(f"{p}: greyscale image (mode {mode}); the classifiers need "
                                 "colour (8-bit RGB)")
            if mode == "CMYK":
                raise PhotoError(f"{p}: CMYK image; convert it to 8-bit RGB with a colour "
                                 "managed tool first")
            if any(";16" in r or ";32" in r or r.startswith("F") for r in raw):
                # Pillow would keep only the high byte; say so rather than do it silently
                raise PhotoError(f"{p}: more than 8 bits per channel ({', '.join(raw)}); "
                                 "thresholds are defined on 0-255 values, convert to 8-bit RGB")
            if mode not in ("RGB", "RGBA", "RGBX", "RGBa", "P", "PA", "YCbCr"):
                raise PhotoError(f"{p}: unsupported image mode {mode}; need 8-bit RGB")
            # load() decodes everything, so a truncated file fails here, not later
            im.load()
            up = ImageOps.exif_transpose(im)
            if up.mode == "P" and "transparency" in up.info:
                up = up.convert("RGBA")
            rgb = np.asarray(up.convert("RGB"), dtype=np.uint8)
    except PhotoError:
        raise
    except UnidentifiedImageError:
        raise PhotoError(f"{p}: not an image Pillow can read (unknown or corrupt format)") from None
    except Image.DecompressionBombError as exc:
        raise PhotoError(f"{p}: image too large to decode safely ({exc})") from None
    except (OSError, SyntaxError, ValueError, EOFError) as exc:
        # Pillow reports truncation as OSError("image file is truncated ...")
        raise PhotoError(f"{p}: cannot decode image ({exc}); the file may be truncated or "
                         "corrupt") from None
    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.size == 0:
        raise PhotoError(f"{p}: decoded to shape {rgb.shape}, expected (height, width, 3)")
    return rgb


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


def photo_gap(path: str | os.PathLike[str], method: Method = "canopeo", crop: Crop = None, *,
              canopeo_rg: float = 0.95, canopeo_bg: float = 0.95, canopeo_exg: float = 20.0,
              mask_path: str | os.PathLike[str] | None = None,
              mask_dir: str | os.PathLike[str] | None = None) -> PhotoGapResult:
    """Gap fraction (P0) and vegetation cover of one photo.

    Parameters
    ----------
    path : path-like
        An 8-bit RGB photo (JPEG, PNG, TIFF, ...). RGBA is accepted (alpha
        dropped); greyscale, CMYK and 16-bit images raise :class:`PhotoError`.
    method : {"canopeo", "exg-otsu", "blue-otsu"}
        Classifier; see the module docstring and :func:`classify_rgb`.
        ``"canopeo"`` and ``"exg-otsu"`` are for nadir (downward) photos,
        ``"blue-otsu"`` for upward photos against the sky.
    crop : float, (x0, y0, x1, y1), str or None
        Central fraction in (0, 1] kept in each dimension (0.5 keeps the
        central 50 % of the width and of the height), or a half-open pixel box
        in the upright image, or its CLI string (``"0.5"``, ``"10,10,500,400"``).
        None analyses the whole image.
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

    Returns
    -------
    PhotoGapResult

    Raises
    ------
    PhotoError
        Missing, unreadable, truncated or non-RGB photo; a crop outside the
        image; an unknown method; a uniform crop for the Otsu methods; a mask
        PNG that cannot be written. Messages name the file.
    """
    p = Path(path)
    if method not in METHODS:
        raise PhotoError(f"{p}: unknown method {method!r}; valid: {', '.join(METHODS)}")
    parsed = parse_crop(crop, file=p)  # bad crop strings fail before decoding
    rgb = read_rgb(p)
    h, w = rgb.shape[:2]
    box = crop_box(parsed, w, h, file=p)
    mask, threshold = classify_rgb(rgb, method, box, canopeo_rg=canopeo_rg,
                                   canopeo_bg=canopeo_bg, canopeo_exg=canopeo_exg, file=p)
    x0, y0, x1, y1 = box
    n = (x1 - x0) * (y1 - y0)
    n_veg = int(np.count_nonzero(mask[y0:y1, x0:x1]))
    cover = n_veg / n
    out = Path(mask_path) if mask_path is not None else default_mask_path(
        p, method, mask_dir if mask_dir is not None else DEFAULT_MASK_DIR)
    try:
        out = write_mask_png(out, mask, box)
    except SimlidarError as exc:
        raise PhotoError(f"{p}: cannot save the classification mask: {exc}") from exc
    params: tuple[tuple[str, float], ...] = ()
    if method == "canopeo":
        params = (("rg", float(canopeo_rg)), ("bg", float(canopeo_bg)),
                  ("exg", float(canopeo_exg)))
    return PhotoGapResult(file=p, method=method, threshold=threshold, cover=cover,
                          p0=1.0 - cover, n_pixels=n, n_vegetation=n_veg, crop=box,
                          image_size=(w, h), mask_file=out, params=params)
