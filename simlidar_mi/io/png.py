"""PNG writers for classification masks (photo and rendered gap-fraction images).

A mask PNG lets a person check what was classified: foreground (vegetation,
canopy, a ray hit) and background (soil, sky, a gap) in two clear colours, the
analysed window outlined, and pixels outside the window shown dimmed for
context. Masks are palette PNGs, one byte a pixel (a 2.5 Mpx mask is written in
tens of milliseconds where an RGB image took ~20× longer); viewers show the
colours, :func:`read_mask_png` gives the boolean mask back. Files are written
under a temporary name and renamed when complete, so a reader never sees a
half-written PNG.
"""
from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import Sequence

import numpy as np
from numpy.typing import ArrayLike
from PIL import Image

from ..errors import SimlidarError

__all__ = ["write_mask_png", "read_mask_png", "mask_labels", "write_label_png", "render_mask_rgb", "dimmed", "FOREGROUND_RGB", "BACKGROUND_RGB", "WINDOW_RGB"]

#: Default colours: dark green foreground, white background, magenta window
#: outline (magenta contrasts with both green and white).
FOREGROUND_RGB: tuple[int, int, int] = (0, 128, 0)
BACKGROUND_RGB: tuple[int, int, int] = (255, 255, 255)
WINDOW_RGB: tuple[int, int, int] = (255, 0, 255)
_DIM_GREY = np.array([128, 128, 128], dtype=np.float64)


def _check_window(window: Sequence[int], width: int, height: int) -> tuple[int, int, int, int]:
    if len(window) != 4:
        raise ValueError(f"window must be (x0, y0, x1, y1), got {window!r}")
    x0, y0, x1, y1 = (int(v) for v in window)
    if not (0 <= x0 < x1 <= width and 0 <= y0 < y1 <= height):
        raise ValueError(f"window {window!r} is not a non-empty box inside the "
                         f"{width}x{height} mask (0 <= x0 < x1 <= {width}, "
                         f"0 <= y0 < y1 <= {height})")
    return x0, y0, x1, y1


def mask_labels(mask: ArrayLike, window: Sequence[int] | None = None) -> np.ndarray:
    """Label image of a mask, one byte a pixel (what :func:`write_mask_png` stores).

    Labels: 0 background, 1 foreground, 2 background outside the window (dimmed),
    3 foreground outside the window, 4 the window's outline over background, 6 the outline
    over foreground (drawn alike; kept apart so :func:`read_mask_png` returns the whole
    mask). Labels 0–4 mean what they mean in a photo's mask
    (:data:`simlidar_mi.canopy.photo.MASK_COLOURS`, whose 5 is a clear pixel).

    Parameters
    ----------
    mask : array_like of bool, shape (height, width)
    window : (x0, y0, x1, y1), optional
        Half-open pixel box (columns ``x0:x1``, rows ``y0:y1``) that was analysed; None
        means the whole mask.

    Returns
    -------
    numpy.ndarray of uint8, shape (height, width)
    """
    m = np.asarray(mask)
    if m.ndim != 2 or m.size == 0:
        raise ValueError(f"mask must be a non-empty 2-D array, got shape {m.shape}")
    h, w = m.shape
    labels = m.astype(bool, copy=False).astype(np.uint8)
    if window is not None:
        x0, y0, x1, y1 = _check_window(window, w, h)
        # dim, not hide: the context outside the window helps judge the crop
        labels[:y0] += 2
        labels[y1:] += 2
        labels[y0:y1, :x0] += 2
        labels[y0:y1, x1:] += 2
        # outline drawn just inside the window so it never falls off the image;
        # about 1 px per 400 px of the short side, so it stays visible when scaled down
        t = max(1, round(min(h, w) / 400))
        t = min(t, (x1 - x0 + 1) // 2, (y1 - y0 + 1) // 2) or 1
        for sl in ((slice(y0, y0 + t), slice(x0, x1)), (slice(y1 - t, y1), slice(x0, x1)),
                   (slice(y0, y1), slice(x0, x0 + t)), (slice(y0, y1), slice(x1 - t, x1))):
            edge = labels[sl]  # a view; the corners are visited twice, hence 0/1 only
            edge[edge == 0] = 4
            edge[edge == 1] = 6  # the outline keeps what it covers: the mask reads back whole
    return labels


def _mask_palette(foreground, background, outline) -> list[tuple[int, int, int]]:
    fg = tuple(int(v) for v in foreground)
    bg = tuple(int(v) for v in background)
    ol = tuple(int(v) for v in outline)
    # entry 5 (a photo's clear pixel) is unused here; black keeps the palettes alike
    return [bg, fg, dimmed(bg), dimmed(fg), ol, (0, 0, 0), ol]  # type: ignore[list-item]


def render_mask_rgb(mask: ArrayLike, window: Sequence[int] | None = None, *,
                    foreground: Sequence[int] = FOREGROUND_RGB,
                    background: Sequence[int] = BACKGROUND_RGB,
                    outline: Sequence[int] = WINDOW_RGB) -> np.ndarray:
    """Render a boolean mask as an RGB image (no file written): the colours of the PNG
    :func:`write_mask_png` writes.

    Parameters
    ----------
    mask : array_like of bool, shape (height, width)
        True for foreground (vegetation, canopy, hit), False for background.
    window : (x0, y0, x1, y1), optional
        Half-open pixel box (columns ``x0:x1``, rows ``y0:y1``) that was
        analysed. Pixels outside it are blended halfway to grey and the box is
        outlined. None means the whole mask was analysed.
    foreground, background, outline : (r, g, b)
        0–255 colours.

    Returns
    -------
    numpy.ndarray of uint8, shape (height, width, 3)
    """
    palette = np.array(_mask_palette(foreground, background, outline), np.uint8)
    return palette[mask_labels(mask, window)]


def write_mask_png(path: str | os.PathLike[str], mask: ArrayLike,
                   window: Sequence[int] | None = None, *,
                   foreground: Sequence[int] = FOREGROUND_RGB,
                   background: Sequence[int] = BACKGROUND_RGB,
                   outline: Sequence[int] = WINDOW_RGB) -> Path:
    """Write a boolean mask as a palette PNG, atomically.

    One byte a pixel (:func:`mask_labels`) and a small palette, so writing is
    ~20× faster than an RGB image of the same colours; viewers show the colours, and
    ``Image.open(path).convert("RGB")`` gives exactly :func:`render_mask_rgb`.
    Read the mask back with :func:`read_mask_png`.

    Parameters
    ----------
    path : path-like
        Destination ``.png``. Its directory is created if missing.
    mask : array_like of bool, shape (height, width)
        True for foreground (drawn dark green by default), False for
        background (white).
    window : (x0, y0, x1, y1), optional
        Half-open pixel box that was analysed; outlined in magenta, with the
        pixels outside it dimmed. See :func:`render_mask_rgb`.
    foreground, background, outline : (r, g, b)
        0–255 colours.

    Returns
    -------
    pathlib.Path
        The path written.

    Raises
    ------
    ValueError
        If ``mask`` is not 2-D or ``window`` is not a box inside it.
    SimlidarError
        If the file cannot be written (message names the path).

    Examples
    --------
    >>> import numpy as np, tempfile, pathlib
    >>> m = np.zeros((4, 6), bool); m[1:3, 2:4] = True
    >>> out = write_mask_png(pathlib.Path(tempfile.mkdtemp()) / "m.png", m, (1, 1, 5, 3))
    >>> out.suffix
    '.png'
    """
    return write_label_png(path, mask_labels(mask, window),
                           _mask_palette(foreground, background, outline))


def read_mask_png(path: str | os.PathLike[str]) -> np.ndarray:
    """The boolean mask of a PNG written by :func:`write_mask_png` (labels 1, 3 and 6 are
    foreground), the same array that was written.

    Raises :class:`SimlidarError` naming the path if it is not such a palette PNG."""
    path = Path(path)
    try:
        with Image.open(path) as im:
            if im.mode != "P":
                raise SimlidarError(f"{path}: not a mask PNG (mode {im.mode}, expected a palette image)")
            labels = np.asarray(im)
    except OSError as exc:
        raise SimlidarError(f"cannot read mask PNG {path}: {exc}") from exc
    return (labels == 1) | (labels == 3) | (labels == 6)


def write_label_png(path: str | os.PathLike[str], labels: np.ndarray,
                    colours: Sequence[Sequence[int]]) -> Path:
    """Write a uint8 label image as a palette PNG (label j drawn in ``colours[j]``), atomically.

    One byte per pixel, so a mask of a very large photo is written without an RGB copy;
    viewers show it like an RGB PNG (``Image.open(path).convert("RGB")`` gives the colours).
    Raises :class:`SimlidarError` naming the path if it cannot be written.
    """
    lab = np.asarray(labels)
    if lab.ndim != 2 or lab.dtype != np.uint8 or lab.size == 0:
        raise ValueError(f"labels must be a non-empty 2-D uint8 array, got {lab.dtype} {lab.shape}")
    if int(lab.max()) >= len(colours):
        raise ValueError(f"label {int(lab.max())} has no colour (only {len(colours)} given)")
    im = Image.fromarray(lab)  # mode "L"; putpalette makes it "P"
    im.putpalette([int(v) for c in colours for v in c])
    return _save_png(path, im)


def dimmed(colour: Sequence[int]) -> tuple[int, int, int]:
    """``colour`` blended halfway to grey, as :func:`render_mask_rgb` shows pixels outside the window."""
    c = 0.5 * np.asarray(colour, dtype=np.float64) + 0.5 * _DIM_GREY
    return tuple(int(v) for v in np.clip(np.rint(c), 0, 255))  # type: ignore[return-value]


def _save_png(path: str | os.PathLike[str], image: Image.Image) -> Path:
    """Save ``image`` as PNG under a temporary name, then rename (readers never see half a file)."""
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    except OSError as exc:
        raise SimlidarError(f"cannot write PNG {path}: {exc.strerror or exc}") from exc
    try:
        with os.fdopen(fd, "wb") as fh:
            image.save(fh, format="PNG")
            fh.flush()
            os.fsync(fh.fileno())
            # mkstemp creates 0600; give the PNG ordinary read permissions (by fd: no name lookup)
            os.fchmod(fh.fileno(), 0o644)
        os.replace(tmp, path)
    except BaseException as exc:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        if isinstance(exc, OSError):
            raise SimlidarError(f"cannot write PNG {path}: {exc.strerror or exc}") from exc
        raise
    return path
