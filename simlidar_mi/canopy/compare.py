"""Virtual vs measured gap fraction: the strawberry paper's Table 5 and Figure 4.

``simlidar-mi compare MANIFEST.csv --out DIR`` (or :func:`compare`) pairs measured gap
fractions (P0) with the P0 of virtual canopies seen by the same kind of camera at the
same view zenith and extraction step, and reports, per zenith and for all rows
together, the statistics of the paper's Table 5 (:func:`comparison_stats`).

The manifest (its columns, and an example) is described in
:mod:`simlidar_mi.canopy.manifest`.

Every distinct scene file is rendered once (:func:`simlidar_mi.canopy.gapfraction.run_gapfraction`
with its ``[gapfraction]`` settings, restricted to the cameras and zeniths the manifest
asks for); every photo once per (method, crop).

Outputs (written together, or not at all)
-----------------------------------------
``comparison.csv``
    ``zenith_deg, n, r, rmse, rmse_r, bias, bias_r, bias_se, scatter, paper_rmse,
    paper_bias, paper_scatter``: one row per zenith, then ``all``.  Relative values are
    fractions (the paper prints percentages).  ``scatter = √(rmse² − bias²)`` is the
    spread of the errors around their mean; ``bias_se`` the part of the bias's
    uncertainty due to the virtual side's seed noise (√Σ p0_virtual_se² / n);
    ``paper_*`` are the paper's Table 5 values at that zenith (its scatter: 0.021,
    0.0145, 0.009 at 0/15/30°).  ``r`` and ``scatter`` are ``nan`` with fewer than two
    pairs (``r`` also with no spread): r per zenith is the correlation across a zenith's
    rows (extraction steps, treatments), so it needs one row per step; the shipped manifest
    has one row per zenith (the paper prints its per-step P0 only as Figure 4's points).
    Uncertainty: ``bias_ci_low``/``bias_ci_high`` a t-based 95 % interval
    (:func:`bias_interval`, Welch–Satterthwaite ``ci_df``) from the spread between the
    scene's replicate plots (plot to plot) and, where the manifest gives ``p0_measured_sd``
    and ``n_measured``, between the measured photos / areas (photo to photo); a row with
    ``n_measured`` only takes its virtual plots' SD as a stand-in (``ci_basis`` says which).
    ``rmse_ci_*``, ``r_ci_*``: percentile 95 % intervals of :data:`BOOTSTRAP_DRAWS`
    resamplings of the replicate plots (and of the measured values within their SE).
    ``bias_inside_ci``: ``yes`` when 0 lies in the bias interval (the gap cannot be told
    from noise), ``no`` when it does not.
``pairs.csv``
    Every manifest row with its measured P0 and the virtual P0: the mean over the
    scene's ``[gapfraction] replicates`` plots, the SD between them
    (``p0_virtual_sd_plot``) and the SD of the mean (``p0_virtual_sd``); see
    :data:`PAIRS_COLUMNS`.
``comparison.png``
    Measured (x) vs virtual (y) P0, one panel per zenith, with the 1:1 line (Fig. 4).
``photo_mask_row<row>_<photo>_<method>.png``, ``virtual_<scene>_gap_<camera>_z<zenith>_s<step>.png``
    What each photo was classified as, and each virtual image used (window outlined).
``readings.csv``
    ``reading`` then :data:`COMPARISON_COLUMNS`: the same statistics under both readings of
    the strawberry paper's petiole angles (:data:`PETIOLE_READINGS`), over the manifest rows
    whose scene has a ``[strawberry]`` section (each such scene is rendered a second time with
    ``strawberry.leaf.petiole_zenith`` swapped); absent when no row has one, or with
    ``readings=False``.  The scene's own reading (θ as the zenith by default, the paper's
    "hemisphere") was chosen from the paper's text, not from this comparison; the other
    (φ) had been chosen because it fits the measured values better (:data:`READINGS_NOTE`).
``comparison.json``
    Manifest and scene checksums, settings, the statistics (and ``readings``).
"""
from __future__ import annotations

import hashlib
import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from ..errors import ConfigError, PhotoError, SimlidarError
from ..plants.strawberry_leaf import StrawberryLeafParams
from ..io.atomic import writes_output
from .gapfraction import replicate_sd
from .compare_intervals import bias_interval
from .manifest import ManifestError, ManifestRow, read_manifest

__all__ = [
    "Pair", "ComparisonResult", "COMPARISON_COLUMNS", "PAIRS_COLUMNS", "PAPER_TABLE5",
    "comparison_stats", "compare", "plot_comparison", "PETIOLE_READINGS", "READINGS_NOTE",
    "bias_interval", "BOOTSTRAP_DRAWS",
]

COMPARISON_COLUMNS = ("zenith_deg", "n", "r", "rmse", "rmse_r", "bias", "bias_r", "bias_se",
                      "scatter", "bias_ci_low", "bias_ci_high", "ci_df", "rmse_ci_low", "rmse_ci_high",
                      "r_ci_low", "r_ci_high", "bias_inside_ci", "ci_basis",
                      "paper_rmse", "paper_bias", "paper_scatter")
PAIRS_COLUMNS = ("row", "scene", "camera", "zenith_deg", "step", "p0_measured", "p0_measured_sd",
                 "n_measured", "p0_virtual",
                 "p0_virtual_sd", "p0_virtual_sd_plot", "replicates", "difference", "measured_from",
                 "photo", "method", "crop", "lai_virtual", "note")
# The files a comparison owns in its folder (whole-name regular expressions): a re-run
# removes the masks of rows, photos and scenes the manifest no longer has.
COMPARE_OUTPUTS = (r"comparison\.(csv|json|png)", r"pairs\.csv", r"readings\.csv", r"virtual_.+\.png",
                   r"photo_mask_row\d+_.+\.png")

#: The strawberry paper's two petiole angles, φ (45 ± 5.6°) and θ (65 ± 45°): which one is the
#: petiole's zenith (the other being the azimuth step between leaves) it does not say.
PETIOLE_READINGS = {"phi": "φ (45 ± 5.6°) the petiole zenith, θ the divergence (a cone of petioles)",
                    "theta": "θ (65 ± 45°) the petiole zenith, φ the divergence (the paper's hemisphere)"}
READINGS_NOTE = ("The default petiole reading (theta as the zenith) was chosen from the paper's text "
                 "(leaves 'tending to form a hemisphere'), not from this comparison, and fits the "
                 "measured gap fractions worse than the other (phi as the zenith, which had been "
                 "chosen because it fits them better and so is no independent check).")
#: The paper's Table 5 per view zenith: (RMSE, Bias) over its 4 densities.  Its error
#: scatter √(RMSE² − Bias²) is 0.0209, 0.0145 and 0.0089.
PAPER_TABLE5 = {0.0: (0.022, 0.007), 15.0: (0.015, 0.004), 30.0: (0.012, 0.008)}
_ZENITH_TOL_DEG = 1e-9


@dataclass
class Pair:
    """A manifest row with its measured and virtual P0."""

    row: ManifestRow
    p0_measured: float
    p0_virtual: float
    lai_virtual: float
    photo_result: Any = None  # simlidar_mi.canopy.photo.PhotoGapResult for photo rows
    p0_virtual_sd_plot: float = math.nan  # SD between the scene's replicate plots
    replicates: int = 1
    p0_virtual_replicates: tuple[float, ...] = ()  # each replicate plot's P0, in replicate order

    @property
    def p0_virtual_sd(self) -> float:
        """Seed-to-seed SD of ``p0_virtual`` (a mean over ``replicates`` plots)."""
        return self.p0_virtual_sd_plot / math.sqrt(self.replicates)

    @property
    def difference(self) -> float:
        """Simulated − observed."""
        return self.p0_virtual - self.p0_measured

    def to_row(self) -> dict[str, Any]:
        r = self.row
        src = "value" if r.photo is None else f"photo:{r.method}"
        return {"row": r.row, "scene": r.scene_text, "camera": r.camera,
                "zenith_deg": f"{r.zenith_deg:g}", "step": r.step_label,
                "p0_measured": f"{self.p0_measured:.6f}",
                "p0_measured_sd": "" if r.p0_measured_sd is None else f"{r.p0_measured_sd:.6f}",
                "n_measured": "" if r.n_measured is None else r.n_measured,
                "p0_virtual": f"{self.p0_virtual:.6f}",
                "p0_virtual_sd_plot": f"{self.p0_virtual_sd_plot:.6f}",
                "p0_virtual_sd": f"{self.p0_virtual_sd:.6f}", "replicates": self.replicates,
                "difference": f"{self.difference:+.6f}", "measured_from": src,
                "photo": r.photo_text, "method": r.method if r.photo is not None else "",
                "crop": r.crop_text, "lai_virtual": f"{self.lai_virtual:.4f}", "note": r.note}


@dataclass
class ComparisonResult:
    """What :func:`compare` produced.

    Attributes
    ----------
    manifest : pathlib.Path
    pairs : list of Pair
        In manifest order.
    stats : list of dict
        One per zenith (ascending), then ``zenith_deg = "all"``; keys
        :data:`COMPARISON_COLUMNS`.
    files : dict of str to pathlib.Path
        Files written.
    readings : dict of str to list of dict
        Per petiole reading (``"phi"``, ``"theta"``), the statistics rows over the manifest
        rows whose scene is a strawberry plot; empty when none is, or with ``readings=False``.
    own_reading : str or None
        Which of them the scenes themselves use.
    """

    manifest: Path
    pairs: list[Pair]
    stats: list[dict[str, Any]]
    files: dict[str, Path] = field(default_factory=dict)
    readings: dict[str, list[dict[str, Any]]] = field(default_factory=dict)
    own_reading: str | None = None

    def stats_for(self, zenith_deg: float | str) -> dict[str, Any]:
        """The statistics row of one zenith (or ``"all"``)."""
        for s in self.stats:
            if s["zenith_deg"] == zenith_deg or (
                    not isinstance(zenith_deg, str) and not isinstance(s["zenith_deg"], str)
                    and abs(s["zenith_deg"] - zenith_deg) <= _ZENITH_TOL_DEG):
                return s
        raise KeyError(zenith_deg)


# --------------------------------------------------------------------- statistics
def comparison_stats(simulated: Sequence[float], observed: Sequence[float]) -> dict[str, float]:
    """Agreement of simulated (s) with observed (o) values, as the paper's Table 5.

    Parameters
    ----------
    simulated, observed : sequences of float, same length n ≥ 1

    Returns
    -------
    dict
        ``n``; ``r`` Pearson's correlation (nan when n < 2 or either has no spread);
        ``rmse`` = √mean((s − o)²); ``rmse_r`` = rmse / mean(o); ``bias`` = mean(s − o);
        ``bias_r`` = bias / mean(o) (relative values are fractions; nan when mean(o) = 0);
        ``scatter`` = √(rmse² − bias²), the SD (ddof 0) of the errors around their mean
        (nan when n < 2: one pair has no scatter to measure).

    Raises
    ------
    ConfigError
        Different lengths, no values, or non-finite values.

    Examples
    --------
    >>> s = comparison_stats([0.2, 0.3, 0.4], [0.1, 0.3, 0.5])
    >>> s["n"], round(s["r"], 6), round(s["rmse"], 6), round(s["bias"], 6)
    (3, 1.0, 0.08165, 0.0)
    """
    s = np.asarray(simulated, np.float64).ravel()
    o = np.asarray(observed, np.float64).ravel()
    if s.shape != o.shape:
        raise ConfigError(f"simulated and observed differ in length ({s.size} vs {o.size})",
                          key="simulated")
    if s.size == 0:
        raise ConfigError("no values to compare", key="simulated")
    if not (np.isfinite(s).all() and np.isfinite(o).all()):
        raise ConfigError("simulated and observed values must be finite", key="simulated")
    d = s - o
    rmse = float(math.sqrt(np.mean(d * d)))
    bias = float(np.mean(d))
    mean_o = float(np.mean(o))
    r = math.nan
    if s.size >= 2:
        ds, do = s - s.mean(), o - o.mean()
        den = math.sqrt(float(np.sum(ds * ds)) * float(np.sum(do * do)))
        if den > 0:
            # clip: rounding can put a perfect correlation a hair above 1
            r = float(min(1.0, max(-1.0, float(np.sum(ds * do)) / den)))
    rel = (lambda x: x / mean_o) if mean_o != 0 else (lambda x: math.nan)
    scatter = math.sqrt(max(rmse * rmse - bias * bias, 0.0)) if s.size >= 2 else math.nan
    return {"n": int(s.size), "r": r, "rmse": rmse, "rmse_r": rel(rmse), "bias": bias,
            "bias_r": rel(bias), "scatter": scatter}


# ------------------------------------------------------------------------ helpers
def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _photo_p0s(rows: list[ManifestRow], src: str, mask_dir: Path) -> dict[int, Any]:
    """PhotoGapResult per photo row (each photo decoded once per method and crop)."""
    from .photo import crop_box, photo_gap, read_rgb  # noqa: PLC0415
    done: dict[tuple, Any] = {}
    out: dict[int, Any] = {}
    for r in rows:
        if r.photo is None:
            continue
        key = (str(r.photo.resolve()), r.method, r.crop_text)
        if key not in done:
            try:
                rgb = read_rgb(r.photo)
            except PhotoError as exc:
                raise ManifestError(f"unreadable photo: {exc}", file=src, row=r.row,
                                    column="photo", value=r.photo_text) from exc
            h, w = rgb.shape[:2]
            try:
                crop_box(r.crop, w, h, file=r.photo)
            except PhotoError as exc:
                raise ManifestError(str(exc), file=src, row=r.row, column="crop",
                                    value=r.crop_text) from exc
            # flat names, matched by COMPARE_OUTPUTS: a re-run removes masks of dropped rows
            mask = mask_dir / f"photo_mask_row{r.row}_{r.photo.stem}_{r.method}.png"
            try:
                done[key] = photo_gap(r.photo, r.method, r.crop, mask_path=mask)
            except PhotoError as exc:  # e.g. Otsu on a uniform crop
                raise ManifestError(str(exc), file=src, row=r.row, column="photo",
                                    value=r.photo_text) from exc
        out[r.row] = done[key]
    return out


def _render_scenes(rows: list[ManifestRow], src: str, progress=False, extra=None):
    """Render every distinct scene once (all its replicate plots); {scene: (run, cfg)}.

    ``extra(cfg)``: overrides to render a scene with instead (None: skip the scene), given its
    configuration as the manifest asks for it."""
    from ..config import load_scene  # noqa: PLC0415
    from .gapfraction import run_gapfraction  # noqa: PLC0415
    by_scene: dict[Path, list[ManifestRow]] = {}
    for r in rows:
        by_scene.setdefault(r.scene.resolve(), []).append(r)
    runs = {}
    for scene, rs in by_scene.items():
        cams = sorted({r.camera for r in rs})
        zens = sorted({r.zenith_deg for r in rs})
        overrides = ["gapfraction.cameras=[" + ", ".join(f'"{c}"' for c in cams) + "]",
                     "gapfraction.zeniths_deg=[" + ", ".join(repr(float(z)) for z in zens) + "]"]
        try:
            cfg = load_scene(scene, overrides)
            if extra is not None:
                more = extra(cfg)
                if more is None:
                    continue
                cfg = load_scene(scene, overrides + more)
            run = run_gapfraction(cfg, None, progress=progress)
        except SimlidarError as exc:
            raise ManifestError(f"cannot render this scene: {exc}", file=src, row=rs[0].row,
                                column="scene", value=rs[0].scene_text) from exc
        runs[scene] = (run, cfg)
    return runs


def _virtual(row: ManifestRow, run, src: str) -> tuple[list[float], float, list]:
    """(P0 of each replicate plot, LAI, replicate 0's images) of the view a row asks for.

    With ``step = mean`` each replicate's value is its mean over the steps, so the SD
    between replicates is that of the mean, not a mix of the steps' SDs.
    """
    steps = sorted({c.step for c in run.canopies})
    if row.step is not None and row.step not in steps:
        raise ManifestError(f"the scene has extraction steps {steps[0]}–{steps[-1]} only",
                            file=src, row=row.row, column="step", value=row.step_label)

    def pick(images):
        return [im for im in images if im.camera.kind == row.camera
                and abs(im.camera.zenith_deg - row.zenith_deg) <= _ZENITH_TOL_DEG
                and (row.step is None or im.step == row.step)]
    reps = [pick(images) for images in run.replicate_images]
    if not reps[0]:  # cannot happen: the scene was rendered for exactly these views
        raise ManifestError("no virtual image of this view was rendered", file=src, row=row.row,
                            column="camera", value=row.camera)
    values = [float(np.mean([im.p0 for im in imgs])) for imgs in reps]
    lai = float(np.mean([im.lai for imgs in reps for im in imgs]))
    return values, lai, reps[0]


def _fmt(v: Any) -> str:
    if isinstance(v, str):
        return v
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    return "nan" if not math.isfinite(v) else f"{v:.6g}"


#: Bootstrap draws for the RMSE and r intervals (resampled replicate plots; fixed seed, so a
#: comparison repeats bit for bit).
BOOTSTRAP_DRAWS = 2000
_BOOTSTRAP_SEED = 20140225  # the paper's field day


def _measured_spread(ps: list[Pair]) -> tuple[list[float | None], list[int | None], str]:
    """Per pair (SD among the measured photos/areas, their number) and what the interval rests on.

    A row with ``n_measured`` but no ``p0_measured_sd`` takes its virtual plots' SD as a stand-in
    (one virtual plot ≈ one ~1 m² sample area): an assumption, named in ``ci_basis``."""
    sds, ns, stand_in, given = [], [], False, False
    for p in ps:
        sd, n = p.row.p0_measured_sd, p.row.n_measured
        if sd is None and n is not None and n >= 2 and math.isfinite(p.p0_virtual_sd_plot):
            sd, stand_in = p.p0_virtual_sd_plot, True
        elif sd is not None:
            given = True
        sds.append(sd)
        ns.append(n)
    basis = "plots"
    if given:
        basis += "+photos"
    if stand_in:
        basis += "+photos(virtual SD stand-in)"
    if all(sd is None for sd in sds):
        basis += " (measured spread not given)"
    return sds, ns, basis


def _bootstrap(ps: list[Pair], sds, ns) -> tuple[float, float, float, float]:
    """Percentile 95 % intervals of RMSE and r: replicate plots resampled (jointly within a
    scene), measured values drawn around themselves with SD sd/√n where known."""
    reps = [np.asarray(p.p0_virtual_replicates, np.float64) for p in ps]
    if any(len(x) < 2 for x in reps):
        return math.nan, math.nan, math.nan, math.nan
    rng = np.random.default_rng(_BOOTSTRAP_SEED)
    scenes = [p.row.scene.resolve() for p in ps]
    sim = np.empty((BOOTSTRAP_DRAWS, len(ps)))
    for g in dict.fromkeys(scenes):
        idx = [i for i, sc in enumerate(scenes) if sc == g]
        n_rep = len(reps[idx[0]])
        draw = rng.integers(0, n_rep, size=(BOOTSTRAP_DRAWS, n_rep))
        for i in idx:
            sim[:, i] = reps[i][draw].mean(1)
    obs = np.tile(np.array([p.p0_measured for p in ps]), (BOOTSTRAP_DRAWS, 1))
    for i, (sd, n) in enumerate(zip(sds, ns)):
        if sd is not None and n is not None and n >= 1:
            obs[:, i] += rng.normal(0.0, sd / math.sqrt(n), BOOTSTRAP_DRAWS)
    d = sim - obs
    rmse = np.sqrt(np.mean(d * d, axis=1))
    r_lo = r_hi = math.nan
    if len(ps) >= 2:
        sc, oc = sim - sim.mean(1, keepdims=True), obs - obs.mean(1, keepdims=True)
        den = np.sqrt((sc * sc).sum(1) * (oc * oc).sum(1))
        ok = den > 0
        if ok.any():
            r = (sc * oc).sum(1)[ok] / den[ok]
            r_lo, r_hi = (float(x) for x in np.percentile(r, [2.5, 97.5]))
    lo, hi = np.percentile(rmse, [2.5, 97.5])
    return float(lo), float(hi), r_lo, r_hi


def _stats_row(zenith: float | str, ps: list[Pair]) -> dict[str, Any]:
    st = comparison_stats([p.p0_virtual for p in ps], [p.p0_measured for p in ps])
    # seed noise of the virtual side only (measured values carry their own)
    bias_se = math.sqrt(sum(p.p0_virtual_sd ** 2 for p in ps)) / len(ps)
    sds, ns, basis = _measured_spread(ps)
    if all(len(p.p0_virtual_replicates) for p in ps):
        ci = bias_interval([p.p0_virtual_replicates for p in ps], [p.row.scene.resolve() for p in ps],
                           [p.p0_measured for p in ps], sds, ns)
        rmse_lo, rmse_hi, r_lo, r_hi = _bootstrap(ps, sds, ns)
    else:
        ci = {"low": math.nan, "high": math.nan, "df": math.nan}
        rmse_lo = rmse_hi = r_lo = r_hi = math.nan
    inside = ("nan" if not math.isfinite(ci["low"])
              else "yes" if ci["low"] <= 0.0 <= ci["high"] else "no")
    paper = next((v for z, v in PAPER_TABLE5.items() if not isinstance(zenith, str)
                  and abs(z - zenith) <= _ZENITH_TOL_DEG), None)
    ref = {"paper_rmse": math.nan, "paper_bias": math.nan, "paper_scatter": math.nan}
    if paper is not None:
        ref = {"paper_rmse": paper[0], "paper_bias": paper[1],
               "paper_scatter": math.sqrt(paper[0] ** 2 - paper[1] ** 2)}
    return {"zenith_deg": zenith, **st, "bias_se": bias_se, "bias_ci_low": ci["low"],
            "bias_ci_high": ci["high"], "ci_df": ci["df"], "rmse_ci_low": rmse_lo,
            "rmse_ci_high": rmse_hi, "r_ci_low": r_lo, "r_ci_high": r_hi,
            "bias_inside_ci": inside, "ci_basis": basis, **ref}


def _group_stats(pairs: list[Pair]) -> list[dict[str, Any]]:
    out = []
    for z in sorted({p.row.zenith_deg for p in pairs}):
        out.append(_stats_row(z, [p for p in pairs if abs(p.row.zenith_deg - z) <= _ZENITH_TOL_DEG]))
    out.append(_stats_row("all", pairs))
    return out


def plot_comparison(pairs: Sequence[Pair], stats: Sequence[dict[str, Any]], path: str | Path,
                    title: str = "") -> Path:
    """Measured vs virtual P0, one panel per zenith, with the 1:1 line (the paper's Fig. 4).

    Points are labelled with their extraction step; photo-derived and typed-in
    measurements use different markers; error bars are the virtual P0's seed-to-seed SD
    (``p0_virtual_sd``).
    """
    import matplotlib  # noqa: PLC0415
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    from ..io.atomic import atomic_file  # noqa: PLC0415
    zen = [s for s in stats if s["zenith_deg"] != "all"]
    vals = [v for p in pairs for v in (p.p0_measured, p.p0_virtual)]
    lo, hi = min(vals), max(vals)
    pad = max(0.02, 0.08 * (hi - lo))
    lim = (max(0.0, lo - pad), min(1.0, hi + pad))
    fig, axes = plt.subplots(1, len(zen), figsize=(3.6 * len(zen) + 0.4, 4.0), dpi=120,
                             squeeze=False)
    for ax, s in zip(axes[0], zen):
        z = s["zenith_deg"]
        ps = [p for p in pairs if abs(p.row.zenith_deg - z) <= _ZENITH_TOL_DEG]
        ax.plot(lim, lim, color="0.5", lw=1, ls="--", label="1:1")
        for src, marker, colour in (("photo", "o", "tab:green"), ("value", "s", "tab:blue")):
            sel = [p for p in ps if (p.row.photo is not None) == (src == "photo")]
            if sel:
                ax.scatter([p.p0_measured for p in sel], [p.p0_virtual for p in sel], s=36,
                           marker=marker, color=colour, zorder=3,
                           label="from photo" if src == "photo" else "measured value")
                se = [p.p0_virtual_sd if math.isfinite(p.p0_virtual_sd) else 0.0 for p in sel]
                ax.errorbar([p.p0_measured for p in sel], [p.p0_virtual for p in sel], yerr=se,
                            fmt="none", ecolor=colour, elinewidth=1, capsize=2, zorder=2)
        for p in ps:
            label = p.row.step_label if p.row.step is None else f"step {p.row.step}"
            ax.annotate(label, (p.p0_measured, p.p0_virtual), textcoords="offset points",
                        xytext=(4, 4), fontsize=7, color="0.3")
        ax.set_xlim(lim)
        ax.set_ylim(lim)
        ax.set_aspect("equal")
        ax.set_xlabel("measured P0")
        ax.set_ylabel("virtual P0")
        r = "– (needs ≥ 2 rows)" if not math.isfinite(s["r"]) else f"{s['r']:.3f}"
        ci = ("" if not math.isfinite(s.get("bias_ci_low", math.nan))
              else f"\n95 % CI {s['bias_ci_low']:+.3f}…{s['bias_ci_high']:+.3f}")
        ax.set_title(f"θ = {z:g}°   n = {s['n']}\nr = {r}, RMSE = {s['rmse']:.3f}, "
                     f"bias = {s['bias']:+.3f} ± {s['bias_se']:.3f}{ci}", fontsize=9)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="upper left")
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    with atomic_file(path) as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)
    return Path(path)


# ----------------------------------------------------------------------- the API
@writes_output("out_dir")
def compare(manifest_path: str | os.PathLike[str], out_dir: str | os.PathLike[str], *,
            progress=False, readings: bool = True) -> ComparisonResult:
    """Pair measured and virtual P0 as a manifest says; write the Table 5 statistics.

    Parameters
    ----------
    manifest_path : path-like
        The manifest CSV (format in the module docstring).
    out_dir : path-like
        Output folder: ``comparison.csv``, ``pairs.csv``, ``comparison.png``,
        ``comparison.json``, ``photo_mask_*.png``, ``virtual_*.png``.  Files appear together
        when everything succeeded; a failure leaves the folder as it was.
    progress : see :func:`simlidar_mi._runtime.progress.make_progress` (the scenes' renders).
    readings : bool
        Also render every strawberry scene under the other petiole reading and report both
        series (``readings.csv``); False skips that second render.

    Returns
    -------
    ComparisonResult

    Raises
    ------
    ManifestError
        Bad columns or values, unknown scenes, unreadable photos, a step the scene does
        not have; the message names the manifest, row and column.
    """
    from ..io.atomic import atomic_file, staged_dir, write_csv  # noqa: PLC0415
    from ..io.png import write_mask_png  # noqa: PLC0415
    mpath = Path(manifest_path)
    src = str(mpath)
    rows = read_manifest(mpath)
    out = Path(out_dir)
    with staged_dir(out, COMPARE_OUTPUTS) as stage:
        photos = _photo_p0s(rows, src, stage)  # cheap, fails before any rendering
        runs = _render_scenes(rows, src, progress)
        pairs, used = [], {}
        for r in rows:
            run, _cfg = runs[r.scene.resolve()]
            values, lai, imgs = _virtual(r, run, src)
            for im in imgs:
                used[(r.scene.resolve(), im.stem())] = (r.scene.stem, im)
            p0_m = photos[r.row].p0 if r.photo is not None else float(r.p0_measured)
            pairs.append(Pair(r, float(p0_m), float(np.mean(values)), lai, photos.get(r.row),
                              replicate_sd(values), len(values), tuple(values)))
        stats = _group_stats(pairs)
        by_reading, own = _petiole_readings(rows, runs, pairs, src, progress) if readings else ({}, None)
        files: dict[str, Path] = {}
        write_csv(stage / "comparison.csv", COMPARISON_COLUMNS,
                  ({k: _fmt(s[k]) for k in COMPARISON_COLUMNS} for s in stats))
        files["comparison.csv"] = out / "comparison.csv"
        write_csv(stage / "pairs.csv", PAIRS_COLUMNS, (p.to_row() for p in pairs))
        files["pairs.csv"] = out / "pairs.csv"
        if by_reading:
            write_csv(stage / "readings.csv", ("reading",) + COMPARISON_COLUMNS,
                      ({"reading": name, **{k: _fmt(st[k]) for k in COMPARISON_COLUMNS}}
                       for name, sts in by_reading.items() for st in sts))
            files["readings.csv"] = out / "readings.csv"
        plot_comparison(pairs, stats, stage / "comparison.png", title=f"{mpath.name}: "
                        "virtual vs measured gap fraction")
        files["comparison.png"] = out / "comparison.png"
        for (_scene, stem), (scene_stem, im) in sorted(used.items(), key=lambda kv: str(kv[0])):
            write_mask_png(stage / f"virtual_{scene_stem}_{stem}.png", im.mask(), im.window.box_px)
        meta = {"manifest": src, "manifest_sha256": _sha256(mpath),
                "scenes": {str(k): {"sha256": cfg.sha256, "seed": cfg.seed,
                                    "gapfraction": cfg["gapfraction"]}
                           for k, (_run, cfg) in runs.items()},
                "stats": _json_stats(stats)}
        if by_reading:
            meta["readings"] = {"petiole_zenith": {
                "own": own, "what": PETIOLE_READINGS, "note": READINGS_NOTE,
                "stats": {name: _json_stats(sts) for name, sts in by_reading.items()}}}
        with atomic_file(stage / "comparison.json") as tmp:
            tmp.write_text(json.dumps(meta, indent=2, default=str) + "\n", encoding="utf-8")
        files["comparison.json"] = out / "comparison.json"
    for p in pairs:  # the mask paths moved with the staging folder
        if p.photo_result is not None and p.photo_result.mask_file is not None:
            p.photo_result = _moved(p.photo_result, stage, out)
    return ComparisonResult(mpath, pairs, stats, files, by_reading, own)


def _json_stats(stats: list[dict[str, Any]]) -> list[dict[str, Any]]:
    return [{k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in s.items()}
            for s in stats]


def _petiole_readings(rows: list[ManifestRow], runs: dict, pairs: list[Pair], src: str,
                      progress) -> tuple[dict[str, list[dict[str, Any]]], str | None]:
    """Both petiole readings' statistics over the rows whose scene is a strawberry plot: the
    scenes' own (from ``pairs``) and the other (each such scene rendered again with
    ``petiole_zenith`` swapped).  ({reading: stats rows}, the scenes' own reading)."""
    def own_of(cfg) -> str | None:
        default = StrawberryLeafParams().petiole_zenith
        return (cfg["strawberry.leaf"]["petiole_zenith"] or default) if cfg.has("strawberry") else None
    owns = {own_of(cfg) for _run, cfg in runs.values()} - {None}
    if not owns:
        return {}, None
    if len(owns) > 1:  # scenes of both readings: each row is paired with its scene's own and the other
        own = "mixed"
    else:
        (own,) = owns

    def other(cfg) -> list[str] | None:
        o = own_of(cfg)
        return None if o is None else [f'strawberry.leaf.petiole_zenith="{"theta" if o == "phi" else "phi"}"']
    alt_runs = _render_scenes(rows, src, progress, extra=other)
    mine, theirs = [], []
    for r, pair in zip(rows, pairs):
        alt = alt_runs.get(r.scene.resolve())
        if alt is None:
            continue
        values, lai, _imgs = _virtual(r, alt[0], src)
        mine.append(pair)
        theirs.append(Pair(r, pair.p0_measured, float(np.mean(values)), lai, None,
                           replicate_sd(values), len(values), tuple(values)))
    if own == "mixed":  # name the series by what they are to each scene
        return {"own": _group_stats(mine), "other": _group_stats(theirs)}, own
    return {own: _group_stats(mine), "theta" if own == "phi" else "phi": _group_stats(theirs)}, own


def _moved(result, stage: Path, out: Path):
    from dataclasses import replace  # noqa: PLC0415
    try:
        rel = Path(result.mask_file).relative_to(stage)
    except ValueError:
        return result
    return replace(result, mask_file=out / rel)
