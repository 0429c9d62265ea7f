"""Reading photos for :mod:`simlidar_mi.canopy.photo`: checks, upright strips, downscaling.

A photo is decoded once (so a truncated file fails before anything is counted), then
handed out in strips of upright rows: the EXIF orientation is applied strip by strip,
so a rotated 8000 × 8000 photo is never held twice.  Pillow keeps a decoded RGB photo
at 4 bytes a pixel; that, and the strip being worked on, is the memory a photo costs.

``downscale`` f in (1, 2, 4, 8) analyses a photo 1/f the size in each dimension:
JPEGs are decoded at that size by the decoder itself (libjpeg's DCT scaling, so memory
falls by f²); other formats are decoded in full, then averaged over f × f blocks.

Alpha: pixels whose alpha is 0 (fully transparent) are *not analysed*; every other
pixel counts with its stored colour (straight alpha).  So an RGBA photo whose outside
is transparent (a fisheye circle, a cut-out) is analysed inside its opaque part only.
"""
from __future__ import annotations

import os
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

import numpy as np
from PIL import Image, ImageFile, UnidentifiedImageError

from ..errors import PhotoError

__all__ = ["DOWNSCALES", "UprightPhoto", "open_photo", "read_rgb"]

#: Accepted ``downscale`` factors (the scales a JPEG decoder can apply itself).
DOWNSCALES: tuple[int, ...] = (1, 2, 4, 8)
_GREY = ("1", "L", "LA", "La", "I", "I;16", "I;16B", "I;16L", "I;16N", "F")
_ALPHA = ("RGBA", "RGBa", "PA")
_T = Image.Transpose
_ORIENT = {2: _T.FLIP_LEFT_RIGHT, 3: _T.ROTATE_180, 4: _T.FLIP_TOP_BOTTOM, 5: _T.TRANSPOSE,
           6: _T.ROTATE_270, 7: _T.TRANSVERSE, 8: _T.ROTATE_90}  # as ImageOps.exif_transpose


def _rawmodes(im: Image.Image) -> list[str]:
    out = []
    for tile in getattr(im, "tile", None) or []:
        args = tile[3] if isinstance(tile, tuple) and len(tile) > 3 else getattr(tile, "args", None)
        if isinstance(args, str):
            out.append(args)
        elif isinstance(args, tuple) and args and isinstance(args[0], str):
            out.append(args[0])
    return out


class UprightPhoto:
    """A decoded, checked photo handed out in strips of upright rows.

    Attributes
    ----------
    size : (width, height)
        Upright size of the analysed (possibly downscaled) image.
    full_size : (width, height)
        Upright size of the photo as stored.
    downscale : int
    has_alpha : bool
        True when the photo carries transparency (then :meth:`strip` returns a mask).
    """

    def __init__(self, im: Image.Image, orientation: int, full_size: tuple[int, int],
                 downscale: int) -> None:
        self._im = im
        self._orientation = orientation if orientation in _ORIENT else 1
        w, h = im.size
        self.size = (h, w) if self._orientation >= 5 else (w, h)
        fw, fh = full_size
        self.full_size = (fh, fw) if self._orientation >= 5 else (fw, fh)
        self.downscale = downscale
        self.has_alpha = im.mode in _ALPHA or (im.mode == "P" and "transparency" in im.info)

    def strip(self, y0: int, y1: int) -> tuple[np.ndarray, np.ndarray | None]:
        """Upright rows ``y0:y1``: uint8 RGB (rows, width, 3) and, when the photo has
        alpha, a bool (rows, width) mask of the analysed (not fully transparent) pixels."""
        w, h = self._im.size  # as stored
        o = self._orientation
        if o <= 4:  # upright rows are stored rows (flipped for 3 and 4)
            box = (0, y0, w, y1) if o <= 2 else (0, h - y1, w, h - y0)
        else:       # upright rows are stored columns (reversed for 7 and 8)
            box = (y0, 0, y1, h) if o <= 6 else (w - y1, 0, w - y0, h)
        part = self._im.crop(box)
        if o in _ORIENT:
            part = part.transpose(_ORIENT[o])
        if self.has_alpha:
            a = np.asarray(part.convert("RGBA"))
            return np.ascontiguousarray(a[..., :3]), a[..., 3] > 0
        return np.asarray(part.convert("RGB"), dtype=np.uint8), None

    def close(self) -> None:
        self._im.close()


@contextmanager
def open_photo(path: str | os.PathLike[str], downscale: int = 1) -> Iterator[UprightPhoto]:
    """Open, check and decode a photo; yields an :class:`UprightPhoto`, closed on exit.

    Raises :class:`PhotoError` (naming the file) for missing, unreadable, truncated,
    greyscale, CMYK, more-than-8-bit and other non-RGB photos, and a bad ``downscale``.
    """
    p = Path(path)
    if isinstance(downscale, bool) or downscale not in DOWNSCALES:
        raise PhotoError(f"{p}: downscale {downscale!r} must be one of "
                         f"{', '.join(map(str, DOWNSCALES))}")
    if not p.exists():
        raise PhotoError(f"{p}: no such file")
    if p.is_dir():
        raise PhotoError(f"{p}: is a directory, not a photo")
    if ImageFile.LOAD_TRUNCATED_IMAGES:
        # someone enabled Pillow's silent grey fill: truncation would go unnoticed
        raise PhotoError(f"{p}: PIL.ImageFile.LOAD_TRUNCATED_IMAGES is True, so truncated "
                         "photos cannot be detected; set it back to False")
    photo = None
    try:
        im = Image.open(p)
        try:
            mode, raw = im.mode, _rawmodes(im)
            if mode in _GREY:
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
            full = im.size
            orientation = int(im.getexif().get(0x0112, 1) or 1)
            if downscale > 1 and im.format == "JPEG":
                # the decoder scales by 1/downscale: the full photo is never decoded
                im.draft("RGB", (max(1, full[0] // downscale), max(1, full[1] // downscale)))
            # load() decodes everything, so a truncated file fails here, not later
            im.load()
            want = (-(-full[0] // downscale), -(-full[1] // downscale))
            if im.size not in (want, full):  # the decoder scaled, but not by 1/downscale
                raise PhotoError(f"{p}: cannot decode this {full[0]}x{full[1]} image at "
                                 f"1/{downscale} of its size; try a smaller downscale")
            if im.size != want:  # not a JPEG: decoded in full, now averaged over blocks
                if im.mode in ("P", "PA"):
                    im = im.convert("RGBA" if im.mode == "PA" or "transparency" in im.info else "RGB")
                im = im.reduce(downscale)
            photo = UprightPhoto(im, orientation, full, downscale)
        except BaseException:
            im.close()
            raise
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
    try:
        w, h = photo.size
        if w * h == 0:
            raise PhotoError(f"{p}: decoded to an empty {w}x{h} image")
        yield photo
    finally:
        photo.close()


def read_rgb(path: str | os.PathLike[str], downscale: int = 1) -> np.ndarray:
    """Read a photo as an 8-bit RGB array, refusing anything doubtful.

    The image is turned upright from its EXIF orientation (so pixel boxes and
    mask PNGs match what image viewers show). RGBA/RGBX/palette images are
    converted to RGB (the alpha channel is not returned; :func:`photo_gap`
    uses it as a mask); greyscale, CMYK, 16-bit and float images are refused.
    The whole photo is returned: for very large photos use
    :func:`simlidar_mi.canopy.photo.photo_gap`, which works strip by strip.

    Parameters
    ----------
    path : path-like
        The photo.
    downscale : {1, 2, 4, 8}
        Read the photo at 1/downscale of its size (module docstring).

    Returns
    -------
    numpy.ndarray of uint8, shape (height, width, 3)

    Raises
    ------
    PhotoError
        Missing, unreadable, truncated or non-RGB files; the message names the
        file and what is wrong.
    """
    with open_photo(path, downscale) as photo:
        w, h = photo.size
        return photo.strip(0, h)[0]
