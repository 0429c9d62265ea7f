"""The pictures of ``evaluate-als``: DTM error maps, the CHM with true and detected tree tops,
and the detection rate by tree height (matplotlib, Agg)."""
from __future__ import annotations

from pathlib import Path

import numpy as np


def _extent(grid) -> list[float]:
    return [grid.x0_m, grid.x0_m + grid.nx * grid.cell_m, grid.y0_m, grid.y0_m + grid.ny * grid.cell_m]


def plot_all(folder: Path, grid, truth, dtms: dict, chm: np.ndarray, true_xyh: np.ndarray, detected: dict,
             by_height: list[dict]) -> list[str]:
    """Write dtm_error.png, chm_trees.png and (with trees) detection_by_height.png; returns their names."""
    import matplotlib  # noqa: PLC0415
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415
    names = []
    ext = _extent(grid)

    errs = {k: v - truth.dtm for k, v in dtms.items()}
    lim = max([float(np.nanmax(np.abs(e))) for e in errs.values() if np.isfinite(e).any()] + [0.05])
    fig, axes = plt.subplots(1, len(errs), figsize=(4.2 * len(errs), 4.0), dpi=100, squeeze=False)
    for ax, (name, e) in zip(axes[0], errs.items()):
        im = ax.imshow(e, extent=ext, cmap="RdBu_r", vmin=-lim, vmax=lim, interpolation="nearest")
        ok = np.isfinite(e)
        rmse = float(np.sqrt(np.mean(e[ok] ** 2))) if ok.any() else float("nan")
        ax.set_title(f"{name}: RMSE {rmse:.3f} m", fontsize=9)
        ax.set_xlabel("x (m)")
        ax.contour(truth.tree_id >= 0, levels=[0.5], extent=[ext[0], ext[1], ext[3], ext[2]],
                   colors="0.3", linewidths=0.4)
    axes[0][0].set_ylabel("y (m)")
    fig.colorbar(im, ax=axes[0].tolist(), shrink=0.85, label="DTM − true terrain (m); grey: crown edges")
    fig.savefig(folder / "dtm_error.png")
    plt.close(fig)
    names.append("dtm_error.png")

    fig, ax = plt.subplots(figsize=(6.4, 5.4), dpi=100)
    im = ax.imshow(chm, extent=ext, cmap="viridis", interpolation="nearest")
    fig.colorbar(im, ax=ax, label="pit-free CHM (m)")
    if len(true_xyh):
        ax.plot(true_xyh[:, 0], true_xyh[:, 1], "o", mfc="none", mec="white", ms=7, label="true stems")
    marks = {"lmf": ("+", "red"), "watershed": ("x", "orange")}
    for name, det in detected.items():
        mk, col = marks.get(name, (".", "magenta"))
        if len(det):
            ax.plot(det[:, 0], det[:, 1], mk, color=col, ms=6, label=f"{name} tops")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title("CHM with true and detected trees", fontsize=10)
    if len(true_xyh) or detected:
        ax.legend(loc="upper right", fontsize=7, framealpha=0.7)
    fig.savefig(folder / "chm_trees.png")
    plt.close(fig)
    names.append("chm_trees.png")

    if by_height:
        fig, ax = plt.subplots(figsize=(6.0, 4.0), dpi=100)
        for method in dict.fromkeys(r["method"] for r in by_height):
            rows = [r for r in by_height if r["method"] == method]
            mid = [(r["height_from_m"] + r["height_to_m"]) / 2 for r in rows]
            ax.plot(mid, [r["detection_rate"] for r in rows], "o-" if "truth" not in method else "s--",
                    ms=4, label=method)
        ax.set_xlabel("true tree height (m)")
        ax.set_ylabel("detection rate")
        ax.set_ylim(-0.02, 1.02)
        ax.legend(fontsize=7)
        ax.set_title("trees detected by height", fontsize=10)
        fig.tight_layout()
        fig.savefig(folder / "detection_by_height.png")
        plt.close(fig)
        names.append("detection_by_height.png")
    return names
