"""Comparison manifests: reading and checking the CSV that pairs measured P0 with virtual views.

The manifest
------------
A CSV file, one pair per row; lines starting with ``#`` are comments (use them for
provenance), blank lines are skipped.  Rows are numbered like the file's lines
(the header is row 1, comment lines count), as a spreadsheet or editor shows them.

================  ========  ============================================================
column            needed    meaning
================  ========  ============================================================
``scene``         yes       scene file (TOML, ``[strawberry]`` or ``[random_leaves]``),
                            relative to the manifest's folder
``camera``        yes       ``orthographic`` or ``perspective``
``zenith_deg``    yes       view zenith in degrees, 0–80
``step``          yes       extraction step (0 = full canopy, 1, 2 …) or ``mean``: the
                            mean virtual P0 over all the scene's steps (for a measured
                            value that is itself a mean over densities)
``photo``         one of    a photo, relative to the manifest's folder, classified with
                  the two   ``method`` inside ``crop``
``p0_measured``   (exactly  or a measured P0 in [0, 1]
                  one)
``method``        no        photo classifier: ``canopeo`` (default), ``exg-otsu``,
                            ``blue-otsu`` (photo rows only)
``crop``          no        central fraction (``0.5``) or pixel box
                            (``"x0,y0,x1,y1"``) of the photo (photo rows only)
``p0_measured_sd`` no       SD among the photos (or sample areas) whose mean the row's
                            measured P0 is; needs ``n_measured``
``n_measured``    no        how many photos / sample areas that mean holds (≥ 2 with an
                            SD); alone it lets ``compare`` stand in the virtual plots' SD
                            for the missing one (flagged as an assumption)
``note``          no        free text, copied to ``pairs.csv``
================  ========  ============================================================

The header must hold the four required columns and at least one of ``photo`` /
``p0_measured``; unknown columns are refused (a misspelt ``zenith`` would otherwise be
silently ignored).  Example::

    # photos of three 1 m² areas after each extraction, nadir, Canopeo
    scene,camera,zenith_deg,step,photo,method,crop,p0_measured,note
    strawberry_plot.toml,perspective,0,0,photos/a1_s0.jpg,canopeo,0.6,,area 1
    strawberry_plot.toml,perspective,0,1,photos/a1_s1.jpg,canopeo,0.6,,area 1
    strawberry_plot.toml,perspective,15,0,,,,0.172,from a field notebook

:func:`simlidar_mi.canopy.compare.compare` reads a manifest with :func:`read_manifest`.
"""
from __future__ import annotations

import csv
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Sequence

from ..errors import ConfigError, PhotoError

__all__ = ["ManifestError", "ManifestRow", "MANIFEST_COLUMNS", "REQUIRED_COLUMNS", "read_manifest"]

REQUIRED_COLUMNS = ("scene", "camera", "zenith_deg", "step")
MEASUREMENT_COLUMNS = ("photo", "p0_measured")
MANIFEST_COLUMNS = REQUIRED_COLUMNS + MEASUREMENT_COLUMNS + ("method", "crop", "p0_measured_sd",
                                                            "n_measured", "note")
CAMERAS = ("orthographic", "perspective")
MEAN_STEP = "mean"


class ManifestError(ConfigError):
    """A comparison manifest holds something we cannot use.

    The message names the manifest, the row (numbered like the file's lines) and the
    column.  ``file``, ``row``, ``key`` (= the column) and ``value`` are attributes.
    """

    def __init__(self, message: str, *, file: str | Path, row: int | None = None,
                 column: str | None = None, value: Any = None) -> None:
        self.file, self.row, self.key, self.column, self.value = str(file), row, column, column, value
        where = [self.file]
        if row is not None:
            where.append(f"row {row}")
        if column is not None:
            where.append(f"column '{column}'")
        if value is not None:
            where.append(f"value {value!r}")
        ValueError.__init__(self, ", ".join(where) + ": " + message)


@dataclass(frozen=True)
class ManifestRow:
    """One validated manifest row (paths resolved against the manifest's folder)."""

    row: int
    scene: Path
    camera: str
    zenith_deg: float
    step: int | None  # None: the mean over all steps
    photo: Path | None
    method: str
    crop: Any
    p0_measured: float | None
    note: str = ""
    scene_text: str = ""  # as written in the manifest
    photo_text: str = ""
    crop_text: str = ""
    p0_measured_sd: float | None = None  # SD among the photos / areas averaged
    n_measured: int | None = None        # how many photos / areas

    @property
    def step_label(self) -> str:
        return MEAN_STEP if self.step is None else str(self.step)


# ----------------------------------------------------------------------- manifest
def read_manifest(path: str | os.PathLike[str]) -> list[ManifestRow]:
    """Read and check a comparison manifest (see the module docstring).

    Checks everything that can be checked without rendering or decoding photos:
    columns, value types and ranges, that scene and photo files exist, and that each
    row has exactly one of ``photo`` / ``p0_measured``.

    Raises
    ------
    ManifestError
        Naming the manifest, the row and the column.
    """
    from .photo import METHODS, parse_crop  # noqa: PLC0415
    mpath = Path(path)
    src = str(mpath)
    try:
        text = mpath.read_text(encoding="utf-8-sig")  # spreadsheets may add a BOM
    except FileNotFoundError:
        raise ManifestError("no such manifest file", file=src) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ManifestError(f"cannot read the manifest as UTF-8 text: {exc}", file=src) from exc
    # comment lines become empty lines, so the reader's line numbers stay the file's
    lines = ["" if ln.lstrip().startswith("#") else ln for ln in text.splitlines()]
    reader = csv.reader(lines)
    header: list[str] | None = None
    header_row = 0
    rows: list[ManifestRow] = []
    base = mpath.parent
    for cells in reader:
        n = reader.line_num
        if not cells or all(not c.strip() for c in cells):
            continue
        cells = [c.strip() for c in cells]
        if header is None:
            header, header_row = cells, n
            _check_header(header, src, n)
            continue
        if len(cells) > len(header):
            raise ManifestError(f"{len(cells)} fields but the header (row {header_row}) has "
                                f"{len(header)}", file=src, row=n)
        rec = dict(zip(header, cells + [""] * (len(header) - len(cells))))
        rows.append(_parse_row(rec, n, src, base, METHODS, parse_crop))
    if header is None:
        raise ManifestError("empty manifest: no header row "
                            f"(need {', '.join(REQUIRED_COLUMNS)} and photo or p0_measured)",
                            file=src)
    if not rows:
        raise ManifestError("the manifest has a header but no data rows", file=src,
                            row=header_row)
    return rows


def _check_header(header: list[str], src: str, n: int) -> None:
    seen = set()
    for col in header:
        if col == "":
            raise ManifestError("empty column name in the header", file=src, row=n)
        if col in seen:
            raise ManifestError("column given twice in the header", file=src, row=n, column=col)
        seen.add(col)
        if col not in MANIFEST_COLUMNS:
            raise ManifestError(f"unknown column; valid: {', '.join(MANIFEST_COLUMNS)}",
                                file=src, row=n, column=col)
    for col in REQUIRED_COLUMNS:
        if col not in seen:
            raise ManifestError("required column missing from the header "
                                f"(need {', '.join(REQUIRED_COLUMNS)})", file=src, row=n, column=col)
    if not seen & set(MEASUREMENT_COLUMNS):
        raise ManifestError("the header needs a 'photo' or a 'p0_measured' column (or both)",
                            file=src, row=n, column="photo/p0_measured")


def _parse_row(rec: dict[str, str], n: int, src: str, base: Path, methods: Sequence[str],
               parse_crop: Callable[..., Any]) -> ManifestRow:
    def err(col: str, msg: str, value: Any = None) -> ManifestError:
        return ManifestError(msg, file=src, row=n, column=col, value=value)

    for col in REQUIRED_COLUMNS:
        if not rec.get(col, ""):
            raise err(col, "empty; every row needs scene, camera, zenith_deg and step")
    scene_text = rec["scene"]
    scene = (base / scene_text)
    if not scene.is_file():
        raise err("scene", f"no such scene file ({scene})", scene_text)
    camera = rec["camera"]
    if camera not in CAMERAS:
        raise err("camera", f"unknown camera; valid: {', '.join(CAMERAS)}", camera)
    try:
        zenith = float(rec["zenith_deg"])
    except ValueError:
        raise err("zenith_deg", "not a number (degrees)", rec["zenith_deg"]) from None
    if not (math.isfinite(zenith) and 0.0 <= zenith <= 80.0):
        raise err("zenith_deg", "view zenith must lie in [0, 80] degrees", rec["zenith_deg"])
    step_text = rec["step"]
    step: int | None
    if step_text.lower() == MEAN_STEP:
        step = None
    else:
        try:
            step = int(step_text)
        except ValueError:
            raise err("step", f"expected an extraction step (integer ≥ 0) or '{MEAN_STEP}'",
                      step_text) from None
        if step < 0:
            raise err("step", "extraction steps are ≥ 0 (0 = full canopy)", step_text)
    photo_text, p0_text = rec.get("photo", ""), rec.get("p0_measured", "")
    if photo_text and p0_text:
        raise err("photo/p0_measured", "give exactly one of 'photo' and 'p0_measured', not both",
                  (photo_text, p0_text))
    if not photo_text and not p0_text:
        raise err("photo/p0_measured", "give exactly one of 'photo' and 'p0_measured' (both empty)")
    method, crop_text = rec.get("method", ""), rec.get("crop", "")
    photo: Path | None = None
    p0: float | None = None
    crop = None
    if photo_text:
        photo = base / photo_text
        if not photo.is_file():
            raise err("photo", f"no such photo ({photo})", photo_text)
        method = method or "canopeo"
        if method not in methods:
            raise err("method", f"unknown photo method; valid: {', '.join(methods)}", method)
        if crop_text:
            try:
                crop = parse_crop(crop_text)
            except PhotoError as exc:
                raise err("crop", str(exc), crop_text) from None
    else:
        for col, val in (("method", method), ("crop", crop_text)):
            if val:
                raise err(col, "only photo rows take a method or a crop", val)
        try:
            p0 = float(p0_text)
        except ValueError:
            raise err("p0_measured", "not a number", p0_text) from None
        if not (math.isfinite(p0) and 0.0 <= p0 <= 1.0):
            raise err("p0_measured", "a gap fraction must lie in [0, 1]", p0_text)
    sd_text, n_text = rec.get("p0_measured_sd", ""), rec.get("n_measured", "")
    sd: float | None = None
    n_meas: int | None = None
    if n_text:
        try:
            n_meas = int(n_text)
        except ValueError:
            raise err("n_measured", "not an integer (photos or sample areas averaged)",
                      n_text) from None
        if n_meas < 1:
            raise err("n_measured", "must be ≥ 1 (photos or sample areas averaged)", n_text)
    if sd_text:
        try:
            sd = float(sd_text)
        except ValueError:
            raise err("p0_measured_sd", "not a number", sd_text) from None
        if not (math.isfinite(sd) and 0.0 <= sd <= 1.0):
            raise err("p0_measured_sd", "an SD of gap fractions must lie in [0, 1]", sd_text)
        if n_meas is None or n_meas < 2:
            raise err("n_measured", "an SD needs the number of photos / areas it is over (≥ 2)",
                      n_text or None)
    return ManifestRow(n, scene, camera, zenith, step, photo, method, crop, p0,
                       rec.get("note", ""), scene_text, photo_text, crop_text, sd, n_meas)
