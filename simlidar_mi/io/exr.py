"""Scan products ↔ OpenEXR files (the OpenEXR 3.x Python package).

Channels (all N × M, row = position y_i, column = angle θ_k):
``range`` float32 metres, ``class`` uint32 (0 escape, 1 ground, 2 wood, 3 leaf),
``branch_id`` uint32 (element id, 0xFFFFFFFF for none), ``theta_deg`` float32,
``y_m`` float32 (y − origin_y, exact in float32 near the origin), and
``hit_fraction`` float32 when a footprint was simulated.  Header attributes hold
every scan setting, the footprint's ``hit_rule``, the seed, the scene file's SHA-256
and the float64 origin.

A scan with a ``[sensor]`` (``result.echoes`` set) keeps those channels for echo 1 and
adds ``n_returns`` (uint32), ``intensity`` (float32 echo energy E, when the sensor's
intensity is on) and, for each return r = 2 … max_returns, the layer ``echo{r}.range``
(float32, escape distance where the beam has fewer echoes), ``echo{r}.class``,
``echo{r}.branch_id`` (uint32, 0 / 0xFFFFFFFF where absent), ``echo{r}.intensity``
(with intensity on) and ``echo{r}.tree_id`` (scenes of several plants).  The header
attribute ``simlidar_sensor`` holds the resolved sensor as JSON.  Without echoes
nothing changes, byte for byte.
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import OpenEXR

from ..errors import SimlidarError
from .atomic import atomic_file

if TYPE_CHECKING:  # annotations only: io sits below the workflows
    from ..lidar.scan import ScanResult


def header_value(value):
    """A Python value as an OpenEXR header attribute that keeps its precision.

    A plain float would be stored as float32, so floats and short vectors become
    float64 arrays (OpenEXR has float64 vectors of 1 to 3 elements only); longer
    vectors are stored as JSON text.
    """
    if isinstance(value, bool):
        return int(value)
    if isinstance(value, (int, np.integer)):
        return int(value) if abs(int(value)) < 2**31 else str(int(value))
    if isinstance(value, (float, np.floating)):
        return np.array([float(value)], np.float64)
    if isinstance(value, (np.ndarray, list, tuple)):
        flat = [float(x) for x in np.asarray(value, np.float64).ravel()]
        return np.asarray(flat, np.float64) if 1 <= len(flat) <= 3 else json.dumps(flat)
    return str(value)


def write_scan_exr(result: ScanResult, path: str | Path, *, seed: int | None = None,
                   scene_sha256: str = "", extra: dict | None = None) -> Path:
    """Write ``result`` to ``path`` (ZIP compression); returns the path."""
    s, p = result.settings, result.pattern
    n, m = result.shape
    channels = {
        "range": np.ascontiguousarray(result.range_m, np.float32),
        "class": np.ascontiguousarray(result.cls, np.uint32),
        "branch_id": np.ascontiguousarray(result.element_id, np.uint32),
    }
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage,
              "origin_m": np.asarray(result.origin_m, np.float64), "scene_sha256": scene_sha256,
              "hit_rule": p.hit_rule}
    if s is not None:  # the tractor: θ and y channels, every setting in the header
        channels["theta_deg"] = np.ascontiguousarray(np.broadcast_to(s.theta_deg[None, :], (n, m)), np.float32)
        channels["y_m"] = np.ascontiguousarray(
            np.broadcast_to((s.y_m - result.origin_m[1])[:, None], (n, m)), np.float32)
        header["simlidar_settings"] = json.dumps(s.to_dict(), sort_keys=True)
        header["y_channel_note"] = "y_m channel is y minus origin_m[1]; range in metres"
        for key, value in s.to_dict().items():
            header[f"scan_{key}"] = header_value(value)
    else:  # other platforms: column angle and row coordinate, the pattern in the header
        channels["angle_deg"] = np.ascontiguousarray(np.broadcast_to(p.col_angle_deg[None, :], (n, m)), np.float32)
        channels["row_coord"] = np.ascontiguousarray(np.broadcast_to(p.row_coord[:, None], (n, m)), np.float32)
        header["simlidar_pattern"] = json.dumps(p.to_dict(), sort_keys=True)
        header["row_coord_label"] = p.row_label
        header["angle_label"] = p.col_label
    if result.tree_id is not None:
        channels["tree_id"] = np.ascontiguousarray(result.tree_id, np.uint32)
    if p.footprint > 0:
        channels["hit_fraction"] = np.ascontiguousarray(result.hit_fraction, np.float32)
    if getattr(result, "echoes", None) is not None:
        _echo_channels(result, channels, header)
    if seed is not None:
        header["seed"] = header_value(seed)
    for key, value in (extra or {}).items():
        header[key] = header_value(value)
    with atomic_file(path) as tmp:
        # OpenEXR.File modifies the dicts it is given: pass copies.
        with OpenEXR.File(dict(header), dict(channels)) as f:
            f.write(str(tmp))
    return Path(path)


def _echo_channels(result: ScanResult, channels: dict, header: dict) -> None:
    """Add the echo channels and the sensor header of a ``[sensor]`` scan (module docstring)."""
    n, m = result.shape
    echoes, sensor = result.echoes, result.sensor
    counts = result.n_returns if result.n_returns is not None else \
        echoes.returns_per_beam(n * m).reshape(n, m)
    channels["n_returns"] = np.ascontiguousarray(counts, np.uint32)
    with_intensity = result.intensity is not None
    if with_intensity:
        channels["intensity"] = np.ascontiguousarray(result.intensity, np.float32)
    max_returns = int((sensor or {}).get("max_returns") or
                      (int(echoes.return_number.max()) if len(echoes) else 1))
    for r in range(2, max_returns + 1):
        layer = echoes.layer((n, m), r, escape_m=result.pattern.escape_m)
        channels[f"echo{r}.range"] = np.ascontiguousarray(layer["range_m"], np.float32)
        channels[f"echo{r}.class"] = np.ascontiguousarray(layer["cls"], np.uint32)
        channels[f"echo{r}.branch_id"] = np.ascontiguousarray(layer["element_id"], np.uint32)
        if with_intensity:
            channels[f"echo{r}.intensity"] = np.ascontiguousarray(layer["intensity"], np.float32)
        if layer["tree_id"] is not None:
            channels[f"echo{r}.tree_id"] = np.ascontiguousarray(layer["tree_id"], np.uint32)
    if sensor is not None:
        header["simlidar_sensor"] = json.dumps(sensor, sort_keys=True, default=_plain)


def _plain(value):
    """numpy scalars and arrays as JSON values."""
    return value.tolist() if hasattr(value, "tolist") else str(value)


def read_exr(path: str | Path) -> tuple[dict[str, np.ndarray], dict]:
    """Channels and header of any EXR; JSON-encoded ``simlidar_pattern`` and
    ``simlidar_sensor`` are decoded into ``header['pattern']`` and ``header['sensor']``."""
    try:
        with OpenEXR.File(str(path)) as f:
            header = dict(f.header())  # emptied when the file closes
            channels = {k: np.array(v.pixels) for k, v in f.channels().items()}
    except Exception as exc:  # OpenEXR raises plain exceptions for unreadable files
        raise SimlidarError(f"{path}: cannot read EXR: {exc}") from exc
    if "simlidar_pattern" in header:
        header["pattern"] = json.loads(header["simlidar_pattern"])
    if "simlidar_sensor" in header:
        header["sensor"] = json.loads(header["simlidar_sensor"])
    return channels, header
