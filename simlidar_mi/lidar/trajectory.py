"""The platform's trajectory as a text file, in the columns HELIOS++ writes (issue 31 §4).

``[scan] trajectory = true`` writes ``trajectory.txt`` beside the points: one line per row of
the scan (an airborne scan line, a path's sweep, a spinning head's azimuth step, a rosette's
time step, a tractor's sweep), legs one after the other, seven space-separated columns as
HELIOS++'s ``*_trajectory.txt`` has them::

    x y z gps_time roll pitch yaw

* ``x y z`` (m, the scene's coordinates, as the points): the platform's position at ``gps_time``
  (the scanner's origin: the row's origin, ``BeamPattern.row_origin_m``);
* ``gps_time`` (s): the row's time in the time base of the points' ``gps_time``
  (:func:`~simlidar_mi.io.las.row_times_s`: a pulse time for an airborne line or a timed
  platform, a scan-order time, 1 s per row, for the others), the time of the row's column 0;
* ``roll pitch yaw`` (degrees): the platform's attitude.  The platforms of this project stay
  level (roll = pitch = 0); ``yaw`` is the heading of the platform's forward direction,
  counter-clockwise from the scene's +x
  (:func:`~simlidar_mi.io.las_fields.forward_heading_deg`: an airborne line's or a path leg's
  heading, 90° for a tractor driving along +y).  A spinning head's turn is the scanner's, not
  the platform's, and is not in it.  The columns and units are HELIOS++'s; the yaw's origin
  and sense are this project's (the scene's x axis, counter-clockwise), not HELIOS++'s.

Numbers are written with 17 significant digits, so a float64 read back is the model's value
bit for bit (HELIOS++ writes 4 decimals).  A row that fires from one position (an airborne
line: the model fires a line from one platform position) is one pose: a point's pose is the
last line at or before its ``gps_time``.  A beam fired ``dt`` after its row on a moving
platform (``BeamPattern.moving``) left from ``x y z + dt · velocity``, the straight line between
two lines of a leg: linear interpolation of this file at a point's ``gps_time`` gives its origin
(tests/test_trajectory.py); such a leg ends with one more line, the pose at its last beam.  A tripod (``static``) does not move: it writes none.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..io.atomic import atomic_file
from ..io.las_fields import forward_heading_deg

TRAJECTORY_FILE = "trajectory.txt"
#: The columns, in HELIOS++'s order.
COLUMNS = ("x", "y", "z", "gps_time", "roll", "pitch", "yaw")


def trajectory_rows(patterns: list) -> np.ndarray:
    """(rows, 7) float64 trajectory of the legs ``patterns`` (module docstring)."""
    from ..io.las import row_times_s  # noqa: PLC0415 - io.las imports laspy lazily; keep it so
    parts, first_row = [], 0
    for p in patterns:
        n = p.n_rows
        times, _ = row_times_s(p, first_row, 0, n)
        if p.row_time_s is not None:  # timed rows: the row's column-0 emission time, without delay
            t0 = np.asarray(p.row_time_s, np.float64)
        else:
            t0 = times[:, 0] if p.col_time_s is None else times[:, 0] - float(p.col_time_s[0])
        out = np.zeros((n, 7), np.float64)
        out[:, :3] = p.row_origin_m
        out[:, 3] = t0
        out[:, 6] = forward_heading_deg(p)
        parts.append(out)
        if p.moving:  # the leg's last beam: where the platform is when the scan ends
            last = int(np.argmax(p.col_time_s))
            dt = float(p.col_time_s[last])
            end = out[-1].copy()
            end[:3] = p.row_origin_m[-1] + dt * np.asarray(p.velocity_m_s, np.float64)
            end[3] = times[-1, last]
            if dt > 0:
                parts.append(end[None, :])
        first_row += n
    return np.concatenate(parts) if parts else np.zeros((0, 7))


def write_trajectory(path: str | Path, patterns: list) -> Path:
    """``trajectory.txt`` of the legs ``patterns`` at ``path`` (module docstring)."""
    rows = trajectory_rows(patterns)
    with atomic_file(path) as tmp:
        np.savetxt(tmp, rows, fmt="%.17g", delimiter=" ")
    return Path(path)


def read_trajectory(path: str | Path) -> np.ndarray:
    """(rows, 7) float64 columns of a trajectory file (HELIOS++'s or ours)."""
    return np.loadtxt(path, ndmin=2)


def has_trajectory(patterns: list) -> bool:
    """Whether the scan's platform moves (every kind but ``static``)."""
    return any(p.kind != "static" for p in patterns)
