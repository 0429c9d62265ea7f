"""Pictures of products: the false-colour range image (SIMLIDAR Fig. 2b)."""
from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from ..geometry import CLASS_CODES  # noqa: E402
from .atomic import atomic_file

if TYPE_CHECKING:  # annotations only: io sits below the workflows
    from ..lidar.scan import ScanResult  # noqa: E402


def plot_scan_png(result: ScanResult, path: str | Path, title: str = "") -> Path:
    """Range image: rows (tractor: y in m) across, beam angle (tractor: θ in °) up,
    colour = range of vegetation hits.

    Ground returns are drawn beige and escapes pale so the canopy stands out.
    """
    p = result.pattern
    img = np.ma.masked_where(~result.vegetation(), result.range_m).T  # (M, N): angle up
    rows, ang, span = p.row_coord, p.col_angle_deg, p.col_span_deg
    if p.meta.get("angle_kind") == "direction":  # per-beam directions (rosette): pulse index up
        ang, span = np.arange(p.n_cols, dtype=np.float64), 1.0
    half_row = 0.5 * (rows[1] - rows[0]) if len(rows) > 1 else 0.5
    extent = [rows[0] - half_row, rows[-1] + half_row, ang[0] - span / 2, ang[-1] + span / 2]
    width = 10 if p.n_rows > p.n_cols else 7
    fig, ax = plt.subplots(figsize=(width, 4.8), dpi=120)
    backdrop = np.where(result.cls.T == CLASS_CODES["ground"], 0.85, 1.0)
    ax.imshow(np.dstack([backdrop, backdrop, backdrop]) *
              np.array([1.0, 0.93, 0.8]), origin="lower", extent=extent, aspect="auto",
              interpolation="nearest")
    im = ax.imshow(img, origin="lower", extent=extent, aspect="auto", cmap="viridis",
                   interpolation="nearest")
    fig.colorbar(im, ax=ax, label="range to vegetation (m)")
    ax.set_xlabel(p.row_label)
    ax.set_ylabel(p.col_label)
    counts = result.class_counts()
    ax.set_title(title or f"{p.n_rows}×{p.n_cols} beams: {counts['wood'] + counts['leaf']} "
                          f"vegetation, {counts['ground']} ground, {counts['escape']} escape")
    fig.tight_layout()
    with atomic_file(path) as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)
    return Path(path)
