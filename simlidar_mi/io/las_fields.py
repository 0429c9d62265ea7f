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
#: The scales LAStools accepts (1, 2.5 or 5 × 10^k, lasinfo's "factor ten of 0.1 or 0.5 or 0.25"),
#: 0.1 mm to 1 m, finest first: :class:`ScaleChooser`'s choice for an axis on a regular grid.
SCALES_FLUFF_FREE_M = (0.0001, 0.00025, 0.0005, 0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0)
#: Half the finest scale: every scale of :data:`SCALES_FLUFF_FREE_M` is a whole number of it.
HALF_STEP_M = 0.00005
#: The most a :class:`ScaleChooser` may shift a gridded axis to keep it free of resolution fluff
#: (on top of the 0.05 mm of rounding to 0.1 mm): the rounding of a file at 1 mm, the usual
#: scale of terrestrial scans; rows 2 mm apart need at most 0.1 mm, rows 1 cm apart up to 1.25 mm.
MAX_SHIFT_M = 0.0005


def intensity_text(scale: float, energy_max: float) -> str:
    """VLR record 2: the intensity rule and this scan's scale (:func:`scan_intensity_scale`)."""
    return (f"intensity = round(s * E), s = {float(scale):.9g} counts per unit E, chosen for this "
            f"scan: 65535 / E_max rounded down to 4 significant digits, E_max = {float(energy_max):.9g} "
            "the largest echo energy of the scan (so no echo clips and the strongest reads about "
            "65535; 1 when the scan has no echo energy); E = echo energy, also in extra bytes "
            "echo_energy: sum over the echo's sub-rays of w * rho * |cos i| * (R_ref / r)^2, R_ref = "
            "range_at_10pct_m * sqrt(detection_threshold / 0.1); the sensor record's "
            "intensity_scale is the sensor's nominal scale, not this file's")


def scan_intensity_scale(energy_max: float) -> float:
    """LAS intensity counts per unit echo energy for a scan whose largest echo energy is
    ``energy_max``: 65535 / E_max rounded down to 4 significant digits, so that round(s·E) ≤ 65535
    for every echo (none clips) and the strongest reads at least 65535·(1 − 10⁻³); 1.0 for a
    scan without positive finite energy.  Readable in the VLR and the same for any chunking."""
    e = float(energy_max)
    if not (e > 0.0 and np.isfinite(e)):
        return 1.0
    exact = 65535.0 / e
    digits = 3 - int(np.floor(np.log10(exact)))
    scale = float(np.floor(exact * 10.0 ** digits) / 10.0 ** digits)
    while scale * e > 65535.5:  # guard the decimal rounding; never taken in practice
        scale = float(np.nextafter(scale, 0.0))
    return scale


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
    """Per-axis LAS scale and offset that LAStools reads without "resolution fluff", fed the
    points piece by piece (the same choice for any pieces: a gcd and a first value per axis).

    LAStools' rule (LASlib/src/lasutility.cpp, ``LASsummary::add``; lasinfo and lasvalidate
    print it, lasinfo.cpp / lascheck.cpp): "resolution fluff (x10)" in an axis when every stored
    integer leaves the first point's remainder modulo 10, "serious (x100)" modulo 100, and so on;
    and they accept only scales 1, 2.5 or 5 × 10^k with an offset on the scale's grid
    (else "translation fluff").  Whole-metre offsets lie on every grid used here, so the rule
    is about the scale alone: with the points' 0.1 mm integers f (f_0 the first) and G the gcd
    of every f − f_0, the stored integers share their remainder modulo 10 exactly when G / (s in
    0.1 mm) is a multiple of 10.

    * First the coarsest power of ten, 0.1 mm … 1 m, that every f is a whole multiple of: the same
      coordinates as at 0.1 mm, the previous rule (one that LAStools does not trip when
      G / s is not a multiple of 10).
    * Else (an axis on a regular grid off the scale's grid: a tractor's rows 2 mm apart starting
      at the scene's edge give f = f_0 + 20 i) the scale of :data:`SCALES_FLUFF_FREE_M` that
      moves the axis least (G / s a whole number, not a multiple of 10), finest on a tie, when
      it moves it by at most :data:`MAX_SHIFT_M`: the axis shifts as a whole by that much, the
      distances along it stay exact.
    * Else (a constant axis, one point, or a grid too far off every scale) the first choice:
      every integer the same leaves every remainder the same, whatever the scale."""

    def __init__(self):
        self.first = [None, None, None]   # f_0 per axis (int)
        self.gcd = [0, 0, 0]              # gcd of every f - f_0 per axis

    def add(self, xyz: np.ndarray) -> None:
        """Feed points ``xyz`` (3, n)."""
        if not xyz.shape[1]:
            return
        for c in range(3):
            fine = np.round(xyz[c] / SCALES_M[-1]).astype(np.int64)  # the 0.1 mm integers
            if self.first[c] is None:
                self.first[c] = int(fine[0])
            self.gcd[c] = int(np.gcd.reduce(np.abs(fine - self.first[c]), initial=self.gcd[c]))

    def _choice(self, c: int) -> tuple[float, bool]:
        """(scale of axis c, whether LAStools' x10 rule passes it)."""
        if self.first[c] is None:
            return SCALES_M[0], True
        g, f0 = self.gcd[c], self.first[c]
        exact = int(np.gcd(f0, g))  # every f is a multiple of it
        level = len(SCALES_M) - 1   # 0.1 mm
        while level > 0 and exact % round(SCALES_M[level - 1] / SCALES_M[-1]) == 0:
            level -= 1
        step = round(SCALES_M[level] / SCALES_M[-1])
        if g and (g // step) % 10:
            return SCALES_M[level], True
        best = None  # (shift, scale) in 0.05 mm units, so that 0.25 mm is whole
        for s in SCALES_FLUFF_FREE_M:
            u = round(s / HALF_STEP_M)
            if g == 0 or (2 * g) % u or ((2 * g) // u) % 10 == 0:
                continue
            rem = (2 * f0) % u
            shift = min(rem, u - rem)
            if shift <= round(MAX_SHIFT_M / HALF_STEP_M) and (best is None or shift < best[0]):
                best = (shift, s)
        return (best[1], True) if best else (SCALES_M[level], False)

    def scales(self) -> np.ndarray:
        return np.array([self._choice(c)[0] for c in range(3)], np.float64)

    def fluff_free(self) -> list[bool]:
        """Per axis, whether LAStools' "resolution fluff (x10)" rule passes the chosen scale."""
        return [self._choice(c)[1] for c in range(3)]

    def offsets(self, lo_m: np.ndarray) -> np.ndarray:
        """floor(min) per axis: whole metres, on the grid of every scale used."""
        return np.floor(lo_m)
