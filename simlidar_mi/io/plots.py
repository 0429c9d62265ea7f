"""Pictures of products: the false-colour range image (SIMLIDAR Fig. 2b)."""
from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from ..mitsuba_scene import CLASS_CODES  # noqa: E402
from ..scan import ScanResult  # noqa: E402
from .atomic import atomic_file  # noqa: E402


def plot_scan_png(result: ScanResult, path: str | Path, title: str = "") -> Path:
    """Range image: y (m) across, θ (°) up, colour = range of vegetation hits.

    Ground returns are drawn light brown and escapes white so the canopy stands out.
    """
    s = result.settings
    img = np.ma.masked_where(~result.vegetation(), result.range_m).T  # (M, N): θ up
    extent = [s.y_m[0] - s.dy_m / 2, s.y_m[-1] + s.dy_m / 2,
              s.theta_deg[0] - s.dtheta_deg / 2, s.theta_deg[-1] + s.dtheta_deg / 2]
    width = 10 if s.n_positions > s.n_angles else 7
    fig, ax = plt.subplots(figsize=(width, 4.8), dpi=120)
    backdrop = np.where(result.cls.T == CLASS_CODES["ground"], 0.85, 1.0)
    ax.imshow(np.dstack([backdrop, backdrop, backdrop]) *
              np.array([1.0, 0.93, 0.8]), origin="lower", extent=extent, aspect="auto",
              interpolation="nearest")
    im = ax.imshow(img, origin="lower", extent=extent, aspect="auto", cmap="viridis",
                   interpolation="nearest")
    fig.colorbar(im, ax=ax, label="range to vegetation (m)")
    ax.set_xlabel("scanner position y (m)")
    ax.set_ylabel("beam elevation θ (°)")
    counts = result.class_counts()
    ax.set_title(title or f"{s.n_positions}×{s.n_angles} beams: {counts['wood'] + counts['leaf']} "
                          f"vegetation, {counts['ground']} ground, {counts['escape']} escape")
    fig.tight_layout()
    with atomic_file(path) as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)
    return Path(path)
