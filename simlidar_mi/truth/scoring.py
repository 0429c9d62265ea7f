"""Scores of estimated voxel grids against the truth, and user estimators (plug-ins).

Scores (:func:`score`), per estimator, against the truth variable of the same name
(``PAD_m2_m3``, or ``LAD_m2_m3`` for an estimator that gives only leaf area), on **one
voxel set fixed before any estimator runs**: the voxels the scan observed, those at least
``min_beams`` first-return beams entered (the traversal's N >= ``--min-beams``, default 5).
The rule depends on the scan alone, so every estimator, built-in or plug-in, is scored on
the same voxels; ``n`` counts them.

An estimate of NaN in a scored voxel is an **abstention**, scored explicitly:

headline (``r2``, ``rmse``, ``bias``, ``estimate_mean``)
    an abstained voxel counts as estimate 0 ("no plant area found"). Abstaining is thus
    scored exactly as answering 0, an answer every estimator could give: it can gain
    nothing that estimating 0 would not, and leaving out a voxel that holds plant area
    costs its whole truth. (Blanking the voxels few beams entered, which improves the
    "where estimated" figures, lowers the headline: tests/test_scoring.py.)
coverage
    ``coverage_voxels``, the share of the scored voxels with a finite estimate, and
    ``coverage_area``, the share of the truth's area (sum of the scored variable over the
    scored voxels) in them.
where estimated (``n_estimated``, ``r2_estimated``, ``rmse_estimated``, ``bias_estimated``)
    the same statistics over the scored voxels with a finite estimate only: secondary
    figures, to be read with the coverage next to them.

per voxel
    over the scored voxels.
per height bin (z profile)
    the mean truth and mean estimate (abstentions as 0; the ``*_estimated`` figures: over
    the voxels with an estimate) over the scored voxels of each horizontal layer of one
    voxel; scored over the layers that hold any.

``r2`` = 1 - sum (e - t)^2 / sum (t - mean t)^2 (the coefficient of determination of the
estimate taken as a prediction of the truth, not of a fitted line: it is negative when the
estimate is worse than the truth's mean), ``rmse`` = sqrt mean (e - t)^2, ``bias`` =
mean (e - t).

Plug-ins: a Python callable ``f(scan_dir: Path, grid: VoxelGrid)`` returning a dict of
arrays of ``grid.shape`` (indexed [i, j, k] along x, y, z) or an xarray Dataset whose
dimensions are named ``x``, ``y``, ``z`` (any order; our files use the CF order
(z, y, x)) (:func:`call_plugin`), or a shell command with ``{las}``, ``{exr}``,
``{grid}``, ``{out}`` placeholders that reads our files and writes a grid NetCDF to
``{out}`` (:func:`run_command`; read by name, so any dimension order). Both are checked
the same way (:func:`check_estimate`): a ``PAD_m2_m3`` or ``LAD_m2_m3`` variable of
``grid.shape`` on the same voxel centres.
"""
from __future__ import annotations

import importlib
import importlib.util
import shlex
import subprocess
import traceback
from pathlib import Path

import numpy as np

from ..errors import ConfigError
from .grid import VoxelGrid, read_grid

__all__ = ["score", "STAT_KEYS", "layer_profile", "load_plugin", "call_plugin", "check_command", "run_command", "check_estimate",
           "SCORED"]

SCORED = ("PAD_m2_m3", "LAD_m2_m3")


STAT_KEYS = ("r2", "rmse", "bias")


def _stats(t: np.ndarray, e: np.ndarray) -> dict:
    n = int(len(t))
    if n == 0:
        return {"n": 0, "r2": float("nan"), "rmse": float("nan"), "bias": float("nan"),
                "truth_mean": float("nan"), "estimate_mean": float("nan")}
    d = e - t
    ss = float(np.sum((t - t.mean()) ** 2))
    return {"n": n, "r2": 1.0 - float(np.sum(d ** 2)) / ss if ss > 0 else float("nan"),
            "rmse": float(np.sqrt(np.mean(d ** 2))), "bias": float(np.mean(d)),
            "truth_mean": float(t.mean()), "estimate_mean": float(e.mean())}


def layer_profile(values: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Mean of ``values`` over ``mask`` in each z layer (NaN where the layer has none)."""
    n = mask.sum(axis=(0, 1))
    s = np.where(mask, values, 0.0).sum(axis=(0, 1))
    return np.divide(s, n, out=np.full(n.shape, np.nan), where=n > 0)


def score(truth: np.ndarray, estimate: np.ndarray, observed: np.ndarray) -> dict:
    """Scores of ``estimate`` against ``truth`` over the ``observed`` voxels (module docstring):
    {"voxel": stats, "profile": stats, "z_truth": (nz,), "z_estimate": (nz,), "n_voxels"}; each
    stats dict holds the headline (abstention = 0), the coverage and the ``*_estimated`` figures."""
    t = np.asarray(truth, np.float64)
    e = np.asarray(estimate, np.float64)
    mask = np.asarray(observed, bool) & np.isfinite(t)  # fixed before the estimate is looked at
    est = mask & np.isfinite(e)
    e0 = np.where(np.isfinite(e), e, 0.0)  # an abstention answers "no plant area"
    cov = {"n_estimated": int(est.sum()),
           "coverage_voxels": float(est.sum() / mask.sum()) if mask.any() else float("nan")}
    area = float(t[mask].sum())
    cov["coverage_area"] = float(t[est].sum()) / area if area > 0 else float("nan")
    zt, ze = layer_profile(t, mask), layer_profile(e0, mask)
    zt_est, ze_est = layer_profile(t, est), layer_profile(e, est)
    ok, ok_est = np.isfinite(zt), np.isfinite(zt_est)
    out = {"z_truth": zt, "z_estimate": ze, "n_voxels": int(mask.sum())}
    for scale, head, where in (("voxel", _stats(t[mask], e0[mask]), _stats(t[est], e[est])),
                               ("profile", _stats(zt[ok], ze[ok]), _stats(zt_est[ok_est], ze_est[ok_est]))):
        out[scale] = {**head, **cov, **{f"{k}_estimated": where[k] for k in STAT_KEYS}}
    return out


def load_plugin(spec: str):
    """``module:function`` → the callable (the module on ``sys.path``, or a ``.py`` file path)."""
    mod_name, sep, func = spec.rpartition(":")
    if not sep or not mod_name or not func:
        raise ConfigError("an estimator is 'module:function' (e.g. examples.my_estimator:contact_frequency)",
                          key="--estimator", value=spec)
    try:
        if mod_name.endswith(".py"):
            path = Path(mod_name)
            s = importlib.util.spec_from_file_location(path.stem, path)
            if s is None or not path.is_file():
                raise ImportError(f"no file {path}")
            module = importlib.util.module_from_spec(s)
            s.loader.exec_module(module)
        else:
            module = importlib.import_module(mod_name)
    except ImportError as exc:
        raise ConfigError(f"cannot import the estimator's module: {exc}", key="--estimator", value=spec) from None
    except Exception as exc:  # noqa: BLE001  (a SyntaxError, or the module's own code failing: one line)
        raise ConfigError(f"importing the estimator's module failed: {_one_line(exc)}{_user_frames(exc)}",
                          key="--estimator", value=spec) from None
    f = getattr(module, func, None)
    if not callable(f):
        raise ConfigError(f"module {mod_name!r} has no function {func!r}", key="--estimator", value=spec)
    return f


def check_estimate(out, grid: VoxelGrid, source: str) -> dict[str, np.ndarray]:
    """The scored variables of a plug-in's result as float64 arrays of ``grid.shape``;
    a clear error naming ``source`` (plug-in or file), the variable and its shape otherwise."""
    if hasattr(out, "data_vars"):  # an xarray Dataset
        for ax, i in zip("xyz", range(3)):
            if ax in out.coords:
                c = np.asarray(out[ax].values, np.float64)
                if c.shape != (grid.shape[i],) or not np.allclose(c, grid.centres(i), rtol=0,
                                                                    atol=1e-6 * grid.voxel_m):
                    raise ConfigError(f"'{ax}' voxel centres differ from the grid's ({grid.shape[i]} centres "
                                      f"from {grid.centres(i)[0]:.6g} m, step {grid.voxel_m:g} m)",
                                      file=source, key=ax, value=_short(c))
        if set("xyz") <= set(out.dims):
            out = out.transpose("x", "y", "z", ...)
        arrays = {k: out[k].values for k in out.data_vars}
    elif isinstance(out, dict):
        arrays = out
    else:
        raise ConfigError(f"an estimator returns an xarray Dataset or a dict of arrays, not "
                          f"{type(out).__name__}", file=source, key="return", value=type(out).__name__)
    got = {k: arrays[k] for k in SCORED if k in arrays}
    if not got:
        raise ConfigError(f"no {' or '.join(SCORED)} variable (has: {', '.join(map(str, arrays)) or 'none'})",
                          file=source, key=SCORED[0])
    for k, a in got.items():
        a = np.asarray(a)
        if a.shape != tuple(grid.shape):
            raise ConfigError(f"shape {a.shape} is not the grid's {tuple(grid.shape)} (x, y, z)",
                              file=source, key=k, value=list(a.shape))
        if not np.issubdtype(a.dtype, np.number):
            raise ConfigError(f"values must be numbers, not {a.dtype}", file=source, key=k, value=str(a.dtype))
        a = a.astype(np.float64)
        n_inf = int(np.isinf(a).sum())
        if n_inf:  # an area density is finite; NaN marks a voxel the estimator leaves out
            raise ConfigError(f"{n_inf} of {a.size} values are infinite; an estimate is a finite density "
                              "(NaN where the estimator gives none)", file=source, key=k, value="inf")
        got[k] = a
    return got


def _short(c) -> str:
    c = np.asarray(c).ravel()
    return f"{len(c)} values {c[0]:.6g}…{c[-1]:.6g}" if len(c) else "none"


def call_plugin(f, spec: str, scan_dir: Path, grid: VoxelGrid) -> dict[str, np.ndarray]:
    """Run a callable plug-in and check its result (:func:`check_estimate`); an exception it
    raises is one error line naming it."""
    try:
        out = f(Path(scan_dir), grid)
    except Exception as exc:  # noqa: BLE001  (the plug-in's own failure, whatever it is)
        raise ConfigError(f"the estimator failed: {_one_line(exc)}{_user_frames(exc)}", key="--estimator",
                          value=spec) from None
    return check_estimate(out, grid, spec)


def _user_frames(exc: BaseException) -> str:
    """The traceback of ``exc`` cut to the caller's own frames (not simlidar_mi's, not
    importlib's), innermost last, as indented lines after the error line; '' when none."""
    ours = Path(__file__).resolve().parents[1]
    frames = [fr for fr in traceback.extract_tb(exc.__traceback__)
              if not fr.filename.startswith("<") and ours not in Path(fr.filename).resolve().parents]
    if not frames:
        return ""
    lines = "".join(traceback.format_list(frames)).rstrip("\n").splitlines()
    return "\n  in your code (most recent call last):\n" + "\n".join("  " + ln for ln in lines)


def _one_line(exc: BaseException) -> str:
    """``Type: message`` on one line, with the file and line a SyntaxError points at."""
    text = " ".join(str(exc).split())
    if isinstance(exc, SyntaxError) and exc.filename:
        text = f"{exc.msg} ({exc.filename}, line {exc.lineno})"
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def check_command(template: str, **paths) -> list[str]:
    """The argument list of a command plug-in with its placeholders filled (with dummies when
    ``paths`` are not given); a clear error for a bad template."""
    if "{out}" not in template:
        raise ConfigError("the command must write its grid to {out}", key="--estimator-cmd", value=template)
    fill = {k: paths.get(k, k) for k in ("las", "exr", "grid", "out")}
    try:
        argv = [a.format(**fill) for a in shlex.split(template)]
    except (KeyError, IndexError, ValueError) as exc:
        raise ConfigError(f"bad placeholder {exc} (use {{las}}, {{exr}}, {{grid}}, {{out}})",
                          key="--estimator-cmd", value=template) from None
    if not argv:
        raise ConfigError("empty command", key="--estimator-cmd", value=template)
    return argv


def run_command(template: str, *, las: Path, exr: Path, grid_file: Path, out: Path,
                grid: VoxelGrid, timeout_s: float | None = None) -> dict[str, np.ndarray]:
    """Run a command plug-in: placeholders filled with quoted paths, run without a shell,
    then its ``{out}`` NetCDF read (:func:`~simlidar_mi.truth.grid.read_grid`) and checked
    against ``grid`` (corner, voxel size, shape)."""
    argv = check_command(template, las=las, exr=exr, grid=grid_file, out=out)
    try:
        proc = subprocess.run(argv, capture_output=True, text=True, timeout=timeout_s, check=False)
    except (OSError, subprocess.TimeoutExpired) as exc:
        raise ConfigError(f"cannot run the estimator command: {exc}", key="--estimator-cmd", value=template) from None
    if proc.returncode != 0:
        tail = (proc.stderr or proc.stdout).strip().splitlines()[-3:]
        raise ConfigError(f"the estimator command exited with status {proc.returncode}: {' | '.join(tail)}",
                          key="--estimator-cmd", value=template)
    if not Path(out).is_file():
        raise ConfigError(f"the estimator command wrote no file {out}", key="--estimator-cmd", value=template)
    # {out} and {grid} are staging files, gone when the error is read: name the command instead
    label = f"--estimator-cmd {template}"
    try:
        their_grid, ds = read_grid(out)
    except ConfigError as exc:
        raise ConfigError(f"its output grid: {exc.reason.replace(str(out), '{out}')}", file=label, key=exc.key, value=exc.value) from None
    except Exception as exc:  # noqa: BLE001  (not a NetCDF file xarray can read)
        raise ConfigError(f"its output is not a readable grid NetCDF: {_one_line(exc)}", file=label) from None
    if their_grid.shape != grid.shape or not np.isclose(their_grid.voxel_m, grid.voxel_m, rtol=1e-9) \
            or not np.allclose(their_grid.corner_m, grid.corner_m, rtol=0, atol=1e-6 * grid.voxel_m):
        raise ConfigError(f"its output grid (corner {their_grid.corner_m}, voxel {their_grid.voxel_m:g} m, "
                          f"shape {their_grid.shape}) is not the grid it was given, grid.nc (corner "
                          f"{grid.corner_m}, voxel {grid.voxel_m:g} m, shape {grid.shape})", file=label,
                          key="x, y, z", value=list(their_grid.shape))
    return check_estimate(ds, grid, label)
