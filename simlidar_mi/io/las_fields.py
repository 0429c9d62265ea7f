"""What the LAS fields of a scan hold, as LAS 1.4 R15 defines them (io/las.py writes them):
the scan angle from nadir and the beam's own angles, the platform's forward direction, the
firing order of a row, the intensity scale and the per-axis coordinate scale.  Shared by the
held writer (io/las.py) and the streamed scans' point spill (lidar/las_spill.py)."""
from __future__ import annotations

import numpy as np

#: LAS scan angle unit (LAS 1.4 §2.6 "Scan Angle"): 0.006° per count.
SCAN_ANGLE_UNIT_DEG = 0.006
#: Candidate per-axis scales, coarsest first (module docstring; :class:`ScaleChooser`).
SCALES_M = (1.0, 0.1, 0.01, 0.001, 0.0001)


def intensity_text(sensor: dict) -> str:
    """VLR record 2: the intensity rule and the sensor's scale (module docstring)."""
    return (f"intensity = min(65535, round(s * E)), s = 65535 * r_I^2 / R_ref^2 = "
            f"{float(sensor['intensity_scale']):.9g} counts per unit E, r_I = "
            f"{float(sensor['intensity_range_m']):g} m (a 100 % Lambertian target at normal incidence "
            "filling the beam at r_I reads 65535); E = echo energy, unclipped in extra bytes "
            "echo_energy: sum over the echo's sub-rays of w * rho * |cos i| * (R_ref / r)^2, R_ref = "
            "range_at_10pct_m * sqrt(detection_threshold / 0.1); 0 when [sensor] intensity is off")


def echo_intensity(energy: np.ndarray, scale: float | None) -> np.ndarray:
    """uint16 LAS intensities of echo energies (module docstring); zeros when ``scale`` is None."""
    if scale is None:
        return np.zeros(len(energy), np.uint16)
    return np.minimum(65535.0, np.rint(float(scale) * np.asarray(energy, np.float64))).astype(np.uint16)


def forward_heading_deg(pattern) -> float:
    """The platform's forward (along-track) direction, degrees counter-clockwise from +x: the
    heading of an airborne line, path leg or moving head; +y (90°) for the tractor, which drives
    along its rows; +x (0°, the azimuth origin) for a tripod and a static head or rosette."""
    heading = (pattern.meta or {}).get("heading_deg")
    if heading is not None:
        return float(heading)
    return 90.0 if pattern.kind == "tractor" else 0.0


def firing_order(pattern) -> np.ndarray | None:
    """Columns in the order a row fires them (stable sort of ``col_time_s``), or None when
    that is column order already (every pattern but a spinning head, whose columns are sorted
    by elevation)."""
    t = pattern.col_time_s
    if t is None or not np.any(np.diff(np.asarray(t, np.float64)) < 0):
        return None
    return np.argsort(np.asarray(t, np.float64), kind="stable")


def firing_sort(beam: np.ndarray, m: int, fire: np.ndarray) -> np.ndarray:
    """Indices that put flat beam indices ``beam`` (sorted, row·M + column) in firing order
    (rows first, then :func:`firing_order`), stable for echoes of one beam."""
    rank = np.empty(m, np.int64)
    rank[fire] = np.arange(m)
    i, k = np.divmod(np.asarray(beam, np.int64), m)
    return np.argsort(i * m + rank[k], kind="stable")


class BeamAngles:
    """``scan_angle`` (int16, 0.006° units), ``elevation_deg`` and ``azimuth_deg`` (float32)
    of beams (row i, column k) of one pattern (module docstring).

    Elevation and platform-frame azimuth are per column; a row turns the azimuth by its yaw.
    Rows sharing a yaw (a tractor, path leg or airborne line: one yaw) share one table of M
    columns; a spinning head (a yaw per row) is computed per point, a rosette from its
    per-beam directions."""

    def __init__(self, pattern):
        p = self.pattern = pattern
        self.m, self.heading = p.n_cols, forward_heading_deg(p)
        self.table = None
        if p.beam_dirs is not None:
            return
        cd = np.asarray(p.col_dir, np.float64)
        self.col_el = np.degrees(np.arctan2(cd[:, 2], np.hypot(cd[:, 0], cd[:, 1])))
        self.col_az = np.degrees(np.arctan2(cd[:, 1], cd[:, 0]))
        yaws, group = np.unique(np.asarray(p.row_yaw_deg, np.float64), return_inverse=True)
        if len(yaws) * 8 <= max(1, p.n_rows) and len(yaws) * self.m <= 1 << 20:
            el = np.broadcast_to(self.col_el[None, :], (len(yaws), self.m)).ravel()
            self.table = self._angles(el, (yaws[:, None] + self.col_az[None, :]).ravel())
            self.group = group.ravel().astype(np.int64) * self.m

    def _angles(self, el: np.ndarray, az: np.ndarray):
        az = az - 360.0 * np.floor((az + 180.0) / 360.0)  # [-180, 180)
        rel = np.mod(az - self.heading, 360.0)
        left = (rel > 0.0) & (rel < 180.0)  # counter-clockwise of forward: the left side
        off_nadir = 90.0 + el
        scan = np.round(np.where(left, -off_nadir, off_nadir) / SCAN_ANGLE_UNIT_DEG).astype(np.int16)
        return scan, el.astype(np.float32), az.astype(np.float32)

    def __call__(self, i: np.ndarray, k: np.ndarray):
        """(scan_angle, elevation_deg, azimuth_deg) of beams (i, k)."""
        p = self.pattern
        if self.table is not None:
            at = self.group[i] + k
            return tuple(t.take(at) for t in self.table)
        if p.beam_dirs is not None:
            d = p.beam_dirs[i, k]
            el = np.degrees(np.arctan2(d[:, 2], np.hypot(d[:, 0], d[:, 1])))
            return self._angles(el, np.degrees(np.arctan2(d[:, 1], d[:, 0])))
        return self._angles(self.col_el.take(k), np.asarray(p.row_yaw_deg, np.float64).take(i) + self.col_az.take(k))


class ScaleChooser:
    """Per-axis LAS scale: 0.1 mm, or the coarsest of :data:`SCALES_M` that every point's
    0.1 mm coordinate is a whole multiple of, checked piece by piece (the same for any pieces).

    The file then stores exactly the coordinates a 0.1 mm file would, and no axis has all its
    stored integers divisible by 10 (lasinfo's "resolution fluff"), since that would have chosen
    the next coarser scale.  Offsets are whole metres, so divisibility does not depend on them;
    at 1 m the integers are x − floor(min): if all points agree modulo 10 m (a constant axis, say),
    :meth:`offsets` moves that offset 1 m down."""

    def __init__(self):
        self.level = np.zeros(3, np.int64)  # index into SCALES_M
        self.mod10 = [None, None, None]     # x mod 10 m at level 0 while it is one value

    def add(self, xyz: np.ndarray) -> None:
        """Feed points ``xyz`` (3, n)."""
        if not xyz.shape[1]:
            return
        for c in range(3):
            if self.level[c] == len(SCALES_M) - 1:  # already the finest: nothing to check
                continue
            fine = np.round(xyz[c] / SCALES_M[-1])  # the 0.1 mm integers (exact in float64)
            while self.level[c] < len(SCALES_M) - 1:
                step = round(SCALES_M[self.level[c]] / SCALES_M[-1])
                if not np.any(np.fmod(fine, step)):
                    break
                self.level[c] += 1
            if self.level[c] == 0 and self.mod10[c] is not False:
                r = np.unique(np.mod(fine / 10_000, 10.0))
                same = len(r) == 1 and self.mod10[c] in (None, float(r[0]))
                self.mod10[c] = float(r[0]) if same else False

    def scales(self) -> np.ndarray:
        return np.array([SCALES_M[lv] for lv in self.level], np.float64)

    def offsets(self, lo_m: np.ndarray) -> np.ndarray:
        """floor(min) per axis, 1 m lower for a 1 m axis whose points all agree modulo 10 m."""
        off = np.floor(lo_m)
        for c in range(3):
            if self.level[c] == 0 and self.mod10[c] is not False:
                off[c] -= 1.0
        return off
