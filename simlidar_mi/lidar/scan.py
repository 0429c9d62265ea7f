"""The tractor LiDAR scan: settings (paper eqs. 6–8), running it, and its product.

Geometry of the scan (SIMLIDAR §2): the scanner moves along +y on the line
x = x0, z = z0 and sweeps its beam in the XZ plane at elevation θ, direction
(cos θ, 0, sin θ).  Beam (i, k) is centred on y_i = y_start + i·(gap+1)·Δy and
θ_k = θ_min + k·Δθ and covers Δy × Δθ around that centre; i < N, k < M.

Timing (only with ``[sensor] pulse_rate_hz`` > 0): the mirror turns a full circle per
sweep and fires pulse_rate_hz pulses per second around it, so the sweep rate is
f = pulse_rate·Δθ/360° and beam (i, k) fires at t = i·(gap+1)/f + k/pulse_rate.  With a
platform speed v as well the tractor moves while it sweeps: rows are v/f apart
(Δy = v/f) and beam (i, k) starts at y_i + v·k/pulse_rate, so a profile is slanted.
"""
from __future__ import annotations

import json
import math
import time
from dataclasses import asdict, dataclass, field

import numpy as np

from .._runtime.mitsuba import mitsuba
from ..config import SECTIONS
from ..errors import ConfigError
from ..geometry import CLASS_CODES
from ..io.exr import read_exr
from ..scene.build import BuiltScene
from .packets import padded_rows
from .platforms import BeamPattern, elevation_dirs
from .sensor import SensorModel
from .waveform import Echoes

CLASS_NAMES = {v: k for k, v in CLASS_CODES.items()}
from ..geometry import NO_ID  # noqa: E402  (one definition: uint32 "none")


@dataclass(frozen=True)
class ScanSettings:
    """Resolved, validated scan parameters (real coordinates, metres and degrees)."""

    x0_m: float
    z0_m: float
    y_start_m: float
    dy_m: float
    gap: int
    n_positions: int
    theta_min_deg: float
    dtheta_deg: float
    n_angles: int
    footprint: int = 0
    escape_m: float = 1000.0
    ground: bool = True
    ground_z_m: float = 0.0
    hit_rule: str = "fraction"         # "any": the paper's §3.1 rule; "fraction": sub-beam share
    theta_limits_side: str = "given"   # how eq. 8 filled θ limits: "near", "far", or "given"
    pulse_rate_hz: float = 0.0         # > 0: beams have times (module docstring)
    speed_m_s: float = 0.0             # > 0 (with a pulse rate): the tractor moves while it sweeps

    @property
    def sweep_rate_hz(self) -> float:
        """f = pulse_rate·Δθ/360°: full mirror turns per second (0 without a pulse rate)."""
        return self.pulse_rate_hz * self.dtheta_deg / 360.0

    @property
    def theta_deg(self) -> np.ndarray:
        """Beam-centre angles θ_k, shape (M,)."""
        return self.theta_min_deg + np.arange(self.n_angles) * self.dtheta_deg

    @property
    def y_m(self) -> np.ndarray:
        """Beam-centre positions y_i, shape (N,)."""
        return self.y_start_m + np.arange(self.n_positions) * (self.gap + 1) * self.dy_m

    @property
    def n_beams(self) -> int:
        return self.n_positions * self.n_angles

    def to_dict(self) -> dict:
        d = asdict(self)
        for key in ("pulse_rate_hz", "speed_m_s"):  # absent when off: headers stay as before
            if not d[key]:
                del d[key]
        return d

    def pattern(self) -> BeamPattern:
        """The tractor's beams as a general :class:`~simlidar_mi.lidar.platforms.BeamPattern`."""
        y = self.y_m
        origins = np.stack([np.full_like(y, self.x0_m), y, np.full_like(y, self.z0_m)], axis=1)
        timing = {}
        if self.pulse_rate_hz > 0:
            f = self.sweep_rate_hz
            timing = {"row_time_s": np.arange(self.n_positions) * (self.gap + 1) / f,
                      "col_time_s": np.arange(self.n_angles) / self.pulse_rate_hz,
                      "velocity_m_s": np.array([0.0, self.speed_m_s, 0.0]) if self.speed_m_s > 0 else None}
        meta = {"angle_kind": "elevation"}
        if timing:
            meta["timing"] = ("tractor sweep: i*(gap+1)/f + k/pulse_rate_hz, f = pulse_rate_hz*dtheta/360 = "
                              f"{self.sweep_rate_hz:.9g} Hz" + (f", y moving at {self.speed_m_s:g} m/s"
                                                                 if self.speed_m_s > 0 else ", one pose per sweep"))
        return BeamPattern("tractor", origins, np.zeros(len(y)), self.theta_deg,
                           elevation_dirs(self.theta_deg), np.array([0.0, self.dy_m, 0.0]),
                           self.dtheta_deg, self.footprint, y, "scanner position y (m)",
                           "beam elevation θ (°)", self.escape_m, self.ground, self.ground_z_m,
                           meta, hit_rule=self.hit_rule, **timing)

    def covers(self, points_m) -> np.ndarray:
        """Boolean (n,): which points lie inside the swept volume, i.e. in front of the
        scanner, within the beams' y footprints [y_1 − Δy/2, y_N + Δy/2] and their elevations
        [θ_1 − Δθ/2, θ_M + Δθ/2]."""
        p = np.asarray(points_m, float).reshape(-1, 3)
        return self._covers_xyz(p[:, 0], p[:, 1], p[:, 2])

    def _covers_xyz(self, x: np.ndarray, y: np.ndarray, z: np.ndarray) -> np.ndarray:
        """:meth:`covers` of points given as coordinate arrays."""
        ys, th = self.y_m, self.theta_deg
        inside = (x > self.x0_m) & (y >= ys[0] - self.dy_m / 2)
        inside &= y <= ys[-1] + self.dy_m / 2
        el = np.degrees(np.arctan2(z - self.z0_m, x - self.x0_m))
        inside &= el >= th[0] - self.dtheta_deg / 2
        inside &= el <= th[-1] + self.dtheta_deg / 2
        return inside

    def swept_share(self, branches, samples: int = 17) -> float:
        """Share of A_PR = Σ d·h whose branch axes lie inside the sweep (:meth:`covers`),
        from ``samples`` evenly spaced points on each axis (ends included)."""
        if not len(branches):
            return float("nan")
        t = np.linspace(0.0, 1.0, samples)
        p0, axis = branches.p0, branches.p1 - branches.p0
        # One sample point per branch at a time: (n,) arrays that stay in the cache instead
        # of (n, samples, 3) points; p0 + t·(p1 − p0) and the tests are the same float ops.
        count = np.zeros(len(branches), np.int64)
        for ts in t:
            count += self._covers_xyz(*(p0[:, c] + ts * axis[:, c] for c in range(3)))
        inside = count / samples  # the mean of the samples' 0/1 (exact sums)
        apr = branches.diameter * np.linalg.norm(axis, axis=1)
        return float(np.sum(apr * inside) / np.sum(apr))


def resolve_settings(scan: dict, ground: dict, bbox_min_m, bbox_max_m,
                     source: str | None = None, near_x_m=None, *, pulse_rate_hz: float = 0.0,
                     speed_m_s: float | None = None, dy_given: bool = False) -> ScanSettings:
    """Fill paper defaults (eqs. 6–8) from the scene bounds and validate.

    ``scan`` and ``ground`` are the validated ``[scan]`` and ``[ground]`` tables.
    Eq. 8's Max(x) is, in the paper's frame (scanner looking towards −x, see its eq. 11),
    the side of the wood nearest the scanner; here the scanner looks along +x, so
    ``theta_limits_side = "near"`` (the default) takes the smallest x of the wood in the
    scanned y range, and the sweep covers every tree.  ``near_x_m`` gives that x: a
    number, or a callable ``(y_min_m, y_max_m) -> x or None`` such as
    :meth:`simlidar_mi.lidar.survey.SceneGeometry.near_x_m`; by default the near side of the
    bounding box.  ``"far"`` reads Max(x) as the bounding box's far side (a narrower sweep
    that misses the near, low and high wood).

    Moving mode (module docstring): ``pulse_rate_hz`` > 0 (``[sensor]``) and ``speed_m_s``
    (``[platform]``) set Δy = v/f, f = pulse_rate·Δθ/360°; a ``scan.dy_m`` the scene gave
    (``dy_given``) must agree with it.  A speed without a pulse rate is refused (the sweep
    rate would be unknown); a pulse rate alone times the beams of today's stop-and-go scan.
    """
    lo, hi = np.asarray(bbox_min_m, float), np.asarray(bbox_max_m, float)
    x0, z0 = float(scan["x0_m"]), float(scan["z0_m"])
    dy, gap, dtheta = float(scan["dy_m"]), int(scan["gap"]), float(scan["dtheta_deg"])
    pulse_rate_hz = float(pulse_rate_hz or 0.0)
    if speed_m_s is not None and pulse_rate_hz <= 0:
        raise ConfigError("a moving tractor needs [sensor] pulse_rate_hz > 0 (its sweep rate is "
                          "pulse_rate·dtheta/360°); without it the scan is SIMLIDAR's, one pose per "
                          "sweep every scan.dy_m", file=source, key="platform.speed_m_s", value=speed_m_s)
    if speed_m_s is not None:
        f = pulse_rate_hz * dtheta / 360.0
        dy_moving = float(speed_m_s) / f
        if dy_given and not math.isclose(dy, dy_moving, rel_tol=1e-9):
            raise ConfigError(f"disagrees with platform.speed_m_s = {speed_m_s:g} m/s and sensor.pulse_rate_hz = "
                              f"{pulse_rate_hz:g} Hz, which put sweeps v/f = {dy_moving:.6g} m apart "
                              f"(f = pulse_rate·dtheta/360° = {f:.6g} Hz); drop scan.dy_m or change "
                              "the speed", file=source, key="scan.dy_m", value=dy)
        dy = dy_moving
    side = scan.get("theta_limits_side", "near")
    hit_rule = scan.get("hit_rule", "fraction")
    ground_z = float(ground["z_m"])
    if ground["enabled"] and z0 <= ground_z:
        raise ConfigError(f"the scanner must be above the ground (z = {ground_z} m)",
                          file=source, key="scan.z0_m", value=z0)
    y0 = scan["y_start_m"] if scan["y_start_m"] is not None else float(lo[1])
    y1 = scan["y_end_m"] if scan["y_end_m"] is not None else float(hi[1])
    if y1 <= y0:
        if scan["y_start_m"] is None and scan["y_end_m"] is None:  # both from the geometry
            raise ConfigError(f"the scene's geometry spans no y (from {y0} to {y1} m): the tractor's "
                              "line has no length; give scan.y_start_m and scan.y_end_m", file=source)
        key, value = ("scan.y_end_m", y1) if scan["y_end_m"] is not None else ("scan.y_start_m", y0)
        raise ConfigError(f"y_end_m ({y1} m) must be beyond y_start_m ({y0} m)", file=source,
                          key=key, value=value)
    # Eqs. 6 and 7: N = Int(span/Δy), M = Int(span/Δθ); the 1e-9 guards 0.3/0.1 = 2.9999.
    n_pos = _count((y1 - y0) / ((gap + 1) * dy))
    if n_pos < 1:
        # blame the gap when the step fits without it, else the step itself
        key, value = ("scan.gap", gap) if gap > 0 and _count((y1 - y0) / dy) >= 1 else ("scan.dy_m", dy)
        raise ConfigError(f"y span {y1 - y0:.4g} m is shorter than one step (gap + 1)·dy_m = "
                          f"{(gap + 1) * dy:.4g} m", file=source, key=key, value=value)
    th_min, th_max = scan["theta_min_deg"], scan["theta_max_deg"]
    if th_min is None or th_max is None:
        # Wood whose y meets the beams' footprints [y_1 − Δy/2, y_N + Δy/2].
        y_lo, y_hi = y0 - dy / 2, y0 + (n_pos - 1) * (gap + 1) * dy + dy / 2
        x_near = near_x_m(y_lo, y_hi) if callable(near_x_m) else near_x_m
        x_near = float(lo[0]) if x_near is None else float(x_near)
        if not x0 < x_near:
            raise ConfigError(f"the scanner stands inside or beyond the wood (x from {x_near:.3f} to "
                              f"{hi[0]:.3f} m in y {y_lo:.3f}…{y_hi:.3f} m): eq. 8 derives θ limits "
                              "only for a scanner in front of the wood (x0 < its nearest x); move "
                              "the scanner or give theta_min_deg and theta_max_deg",
                              file=source, key="scan.x0_m", value=x0)
        reach = (x_near if side == "near" else float(hi[0])) - x0  # Max(x) − x0 of eq. 8
        if th_min is None:
            th_min = -math.degrees(math.atan((z0 - ground_z) / reach))
        if th_max is None:
            th_max = math.degrees(math.atan((hi[2] - z0) / reach))
    else:
        side = "given"
    for key, th in (("scan.theta_min_deg", th_min), ("scan.theta_max_deg", th_max)):
        if not -90.0 <= th <= 90.0:
            raise ConfigError("elevation angles must lie in [-90, 90] degrees", file=source, key=key, value=th)
    if th_min >= th_max:
        given_min, given_max = scan["theta_min_deg"] is not None, scan["theta_max_deg"] is not None
        if not (given_min or given_max):  # both derived (eq. 8) from the geometry
            raise ConfigError(f"eq. 8 derives θ limits {th_min:.4f}° … {th_max:.4f}° from the geometry: its top "
                              f"(z = {float(hi[2]):.4g} m) is not above the ground (z = {ground_z} m), so "
                              "there is nothing to sweep; check the meshes' heights "
                              "or give theta_min_deg and theta_max_deg", file=source)
        key, value = ("scan.theta_min_deg", th_min) if given_min else ("scan.theta_max_deg", th_max)
        raise ConfigError(f"theta_min_deg ({th_min:.4f}°) must be below theta_max_deg ({th_max:.4f}°)",
                          file=source, key=key, value=value)
    n_ang = _count((th_max - th_min) / dtheta)
    if n_ang < 1:
        raise ConfigError(f"θ span {th_max - th_min:.4g}° is shorter than one step", file=source,
                          key="scan.dtheta_deg", value=dtheta)
    n_sub = (int(scan["footprint"]) + 1) ** 2
    if n_pos * n_ang * n_sub > int(scan["max_beams"]):
        # Blame the key that grew the count most over what its default would give.
        growth = {"scan.dy_m": n_pos / max(1, _count((y1 - y0) / ((gap + 1) * _DEFAULT["dy_m"]))),
                  "scan.dtheta_deg": n_ang / max(1, _count((th_max - th_min) / _DEFAULT["dtheta_deg"])),
                  "scan.footprint": n_sub / (_DEFAULT["footprint"] + 1) ** 2}
        key = max(growth, key=growth.get)
        if growth[key] <= 1:
            key = "scan.max_beams"
        value = {"scan.dy_m": dy, "scan.dtheta_deg": dtheta, "scan.footprint": int(scan["footprint"]),
                 "scan.max_beams": int(scan["max_beams"])}[key]
        raise ConfigError(f"{_n(n_pos)}×{_n(n_ang)} beams × {n_sub} sub-beams = {n_pos * n_ang * n_sub:.3g} "
                          f"exceeds scan.max_beams = {scan['max_beams']} ({_n(n_pos)} positions at dy_m = "
                          f"{dy:g} over {y1 - y0:g} m, {_n(n_ang)} angles at dtheta_deg = {dtheta:g} over "
                          f"{th_max - th_min:.4g}°, footprint {scan['footprint']}); coarsen "
                          f"{key if key != 'scan.max_beams' else 'dy_m/dtheta_deg'} or raise max_beams",
                          file=source, key=key, value=value)
    return ScanSettings(x0, z0, float(y0), dy, gap, n_pos, float(th_min), dtheta, n_ang,
                        int(scan["footprint"]), float(scan["escape_m"]), bool(ground["enabled"]),
                        ground_z, hit_rule, side, pulse_rate_hz, float(speed_m_s or 0.0))


_DEFAULT = {k: SECTIONS["scan"][k].default for k in ("dy_m", "dtheta_deg", "footprint")}


def _count(ratio: float) -> int:
    """Int(ratio) of eqs. 6-7 (the 1e-9 guards 0.3/0.1 = 2.9999), capped so a tiny step
    gives a huge count for the max_beams check rather than an overflow."""
    return int(math.floor(min(ratio, 1e18) + 1e-9))


def _n(count: int) -> str:
    return str(count) if count < 10**9 else f"{count:.3g}"


@dataclass
class ScanResult:
    """An N × M scan: row i = platform pose (tractor: position y_i), column k = beam angle.

    ``range_m`` is float32 metres (escape distance where nothing was hit), ``cls``
    uint8 (0 escape, 1 ground, 2 wood, 3 leaf), ``element_id`` uint32 (branch row,
    ``n_branches + j`` for primitive j, leaf id; 0xFFFFFFFF for ground/escape),
    ``hit_fraction`` float32 share of sub-beams meeting vegetation (under either hit rule).
    With a ``[sensor]`` section these first-return arrays hold echo 1 of ``echoes``.
    """

    settings: ScanSettings | None  # the tractor's settings; None for other platforms
    range_m: np.ndarray
    cls: np.ndarray
    element_id: np.ndarray
    hit_fraction: np.ndarray
    origin_m: np.ndarray
    seconds: float = 0.0
    metadata: dict = field(default_factory=dict)
    pattern: BeamPattern | None = None
    tree_id: np.ndarray | None = None  # uint32 (N, M), scenes of several plants only
    # A [sensor] scan (issue 7): every echo, echoes per beam, first-return intensity, and
    # the resolved sensor for headers.  None: the first-return scan of old.
    echoes: Echoes | None = None
    n_returns: np.ndarray | None = None      # uint8 (N, M)
    intensity: np.ndarray | None = None      # float32 (N, M), echo 1's energy
    sensor: dict | None = None

    def __post_init__(self) -> None:
        if self.pattern is None:
            self.pattern = self.settings.pattern()

    @property
    def shape(self) -> tuple[int, int]:
        return self.range_m.shape

    def class_counts(self) -> dict[str, int]:
        # uint8 compares and counts: no int64 copy of every beam as np.bincount makes
        return {CLASS_NAMES[c]: int(np.count_nonzero(self.cls == c)) for c in range(4)}

    def vegetation(self) -> np.ndarray:
        """Boolean (N, M): first return is wood or leaf."""
        # Codes 2 and 3 (wood, leaf) are the ones whose bit 0 set gives 3: one pass fewer
        return np.bitwise_or(self.cls, 1) == CLASS_CODES["leaf"]

    def points_m(self) -> np.ndarray:
        """(N, M, 3) float64 first-return points in real coordinates (escapes included)."""
        p = self.pattern
        r = self.range_m.astype(np.float64)[..., None]
        return p.beam_origins_m() + r * p.world_dirs()

    def impacted_area_m2(self) -> float:
        """A_IM, the paper's eq. 2: Σ over vegetation hits of Δy·l·(sin θ⁺ − sin θ⁻).

        θ± = θ_k ± Δθ/2 are the beam's edges.  With a footprint, each vegetation beam
        counts whole under ``hit_rule = "any"`` (the paper's §3.1) and its hit fraction
        under ``"fraction"``.  Eq. 1 measures l·Δsin θ ≈ l·cos θ·Δθ, which undercounts the
        area on a vertical target by cos²θ; :meth:`impacted_area_yz_m2` is exact.
        """
        s = self.settings
        th = np.deg2rad(s.theta_deg)
        half = np.deg2rad(s.dtheta_deg) / 2
        dsin = np.sin(th + half) - np.sin(th - half)
        term = self._hit_weight()  # w·l·Δsin θ in place: one float64 (N, M) array, same bits
        term *= self.range_m
        term *= dsin
        return float(s.dy_m * np.sum(term))

    def impacted_area_yz_m2(self) -> float:
        """The beam footprint projected on the YZ plane at the hit's depth, summed over hits:
        Δy·x·(tan θ⁺ − tan θ⁻) with x = l·cos θ.  Equals d·h for a vertical cylinder."""
        s = self.settings
        th = np.deg2rad(s.theta_deg)
        half = np.deg2rad(s.dtheta_deg) / 2
        fraction = self._weighs_fraction()
        # Terms w·(l·cos θ)·Δtan θ where w > 0, else 0 (NaN: 0, as np.nansum), in one float64
        # array and no weight array: the weight is 1 (a product that changes nothing) or the
        # beam's float32 hit fraction, multiplied in the same order, so the bits are the same.
        hit = self.vegetation()
        with np.errstate(over="ignore", invalid="ignore"):
            dtan = np.tan(th + half) - np.tan(th - half)
            area = np.multiply(self.range_m, np.cos(th), dtype=np.float64)
            if fraction:
                area *= self.hit_fraction
                hit &= self.hit_fraction > 0
            area *= dtan
        np.copyto(area, 0.0, where=~hit)
        np.copyto(area, 0.0, where=np.isnan(area))
        return float(s.dy_m * np.sum(area))

    def _weighs_fraction(self) -> bool:
        """Whether a beam weighs its hit fraction (else 1) in the impacted areas."""
        if self.settings is None:
            raise ValueError("impacted areas are defined for the tractor scan (paper eq. 2) only")
        return self.settings.footprint > 0 and self.settings.hit_rule == "fraction"

    def _hit_weight(self) -> np.ndarray:
        """Float64 (N, M) weight of each beam in the impacted areas (0 off vegetation)."""
        if self._weighs_fraction():
            # a float64 zero: the float32 fractions widen (exactly) in the same single pass
            return np.where(self.vegetation(), self.hit_fraction, np.float64(0.0))
        return self.vegetation().astype(np.float64)


DEFAULT_CHUNK_BEAMS = 1 << 22  # [scan] chunk_beams' default: ~4 M beams per trace


class BeamTracer:
    """SIMLIDAR's first-return scan of one pattern, traced on demand by beam range.

    :meth:`trace` of any range gives the bytes the whole-scan trace gives for those beams
    (plugins/range_integrator.py ``trace``), so scans streamed in chunks do not depend on
    the chunk size."""

    def __init__(self, built: BuiltScene, settings: ScanSettings | BeamPattern, variant: str | None = None,
                 rows: tuple[int, int] | None = None):
        mi = mitsuba(variant)
        self.settings, self.pattern, self._lidar = _lidar(mi, built, settings, rows)
        self._integrator = _range_integrator(mi, built, self.pattern)
        self._scene = built.scene
        self.n_beams = self.pattern.n_beams
        # A tile's sensor starts up to a packet before the tile (lidar.packets): its beam index.
        self._lead = (rows[0] * self.pattern.n_cols if rows else 0) - self._lidar.first_beam

    def trace(self, beam_start: int = 0, beam_count: int | None = None) -> dict[str, np.ndarray | None]:
        """Flat numpy arrays ``range`` (float32 m), ``cls`` (uint8), ``elem`` and ``tree``
        (uint32; tree None for scenes of one plant) and ``frac`` (float32) of the beams."""
        count = self.n_beams - beam_start if beam_count is None else int(beam_count)
        out = self._integrator.trace(self._scene, self._lidar, self._lead + int(beam_start), count)
        # .numpy() is a writable view whose base (a memoryview) keeps the Dr.Jit array alive, so
        # no copy is needed (tests/test_scan_views.py): 50 MB of copies a 2.5 M-beam scan saves.
        return {"range": out["range"].numpy(), "cls": np.asarray(out["class"].numpy(), np.uint8),
                "elem": out["element_id"].numpy(), "frac": out["hit_fraction"].numpy(),
                "tree": out["tree_id"].numpy() if "tree_id" in out else None}

    def row_blocks(self, chunk_beams: int = DEFAULT_CHUNK_BEAMS):
        """Yield (first row, end row, arrays) over whole rows, tracing at most ``chunk_beams``
        beams at a time (a row longer than that is traced in pieces and joined)."""
        N, M = self.pattern.n_rows, self.pattern.n_cols
        chunk_beams = max(1, int(chunk_beams))
        rows = max(1, chunk_beams // M)
        for a in range(0, N, rows):
            b = min(N, a + rows)
            if chunk_beams >= M:
                yield a, b, self.trace(a * M, (b - a) * M)
                continue
            pieces = [self.trace(a * M + c, min(chunk_beams, M - c)) for c in range(0, M, chunk_beams)]
            yield a, b, {k: None if pieces[0][k] is None else np.concatenate([p[k] for p in pieces])
                         for k in pieces[0]}


def scan(built: BuiltScene, settings: ScanSettings | BeamPattern,
         variant: str | None = None, sensor: SensorModel | None = None, *, seed: int = 0,
         leg: int = 0, rows: tuple[int, int] | None = None, chunk_beams: int | None = None) -> ScanResult:
    """Fire every beam of ``settings`` (tractor) or of a platform's pattern into ``built``.

    With a :class:`~simlidar_mi.lidar.sensor.SensorModel` (``[sensor]`` effects on) the
    physical scanner runs (:func:`scan_physical`, seeded by ``seed`` and ``leg``); without
    one, SIMLIDAR's first-return scan.  ``rows = (r0, r1)`` fires only rows r0 … r1 − 1, a
    tile of :mod:`simlidar_mi.lidar.tiles`: the same rays and the same per-beam values as
    those rows of the whole scan (arrays of r1 − r0 rows; echoes keep global beam indices).
    ``chunk_beams`` (``[scan] chunk_beams``) bounds the beams per trace; None traces the
    first-return scan at once.  The result holds every beam either way
    (:mod:`simlidar_mi.lidar.stream` writes files without holding them)."""
    if sensor is not None:
        return scan_physical(built, settings, sensor, seed=seed, leg=leg, variant=variant, rows=rows,
                             chunk_beams=chunk_beams or DEFAULT_CHUNK_BEAMS)
    tracer = BeamTracer(built, settings, variant, rows)
    pattern = tracer.pattern
    shape = (pattern.n_rows, pattern.n_cols)
    t0 = time.perf_counter()
    if chunk_beams is None or chunk_beams >= tracer.n_beams:
        a = tracer.trace()
    else:
        a = None
        for r0, r1, part in tracer.row_blocks(chunk_beams):
            if a is None:
                a = {k: None if v is None else np.empty(tracer.n_beams, v.dtype) for k, v in part.items()}
            for k, v in part.items():
                if v is not None:
                    a[k][r0 * shape[1]:r1 * shape[1]] = v
    seconds = time.perf_counter() - t0
    tree = a["tree"].reshape(shape) if a["tree"] is not None else None
    return ScanResult(tracer.settings, a["range"].reshape(shape), a["cls"].reshape(shape),
                      a["elem"].reshape(shape), a["frac"].reshape(shape), built.origin_m.copy(), seconds,
                      _metadata(built), pattern, tree)


def _metadata(built: BuiltScene) -> dict:
    return {"representation": built.representation, "facets": built.facets,
            "n_branches": built.n_branches, "n_dropped": built.n_dropped}


def _lidar(mi, built: BuiltScene, settings, rows: tuple[int, int] | None = None):
    """(tractor settings or None, pattern, Mitsuba sensor) for ``settings`` (only rows
    r0 … r1 − 1 of it with ``rows``: the pattern returned is then those rows)."""
    o = built.origin_m
    if isinstance(settings, ScanSettings):
        s = settings
        pattern = s.pattern()
        lidar = mi.load_dict({
            "type": "tractor_lidar",
            "n_positions": s.n_positions, "n_angles": s.n_angles,
            "y_start": s.y_start_m - o[1], "dy": s.dy_m, "gap": s.gap,
            "theta_min_deg": s.theta_min_deg, "dtheta_deg": s.dtheta_deg,
            "x0": s.x0_m - o[0], "z0": s.z0_m - o[2], "footprint": s.footprint,
            "film": _film(s.n_angles, s.n_positions),
        })
        if rows is not None:  # the whole tractor's float32 tables, sliced: the same rays
            ra, rb = padded_rows(*rows, s.n_positions, s.n_angles)  # whole packets (lidar.packets)
            p1 = s.footprint + 1
            origins = np.stack([np.asarray(a, np.float64)[ra * p1:rb * p1] for a in lidar._o], axis=1)
            dirs = np.stack([np.asarray(a, np.float64) for a in lidar._d], axis=1)
            pattern = pattern.rows(*rows)
            lidar = mi.load_dict({"type": "lidar_pattern", "n_positions": rb - ra, "n_angles": s.n_angles,
                                  "footprint": s.footprint, "film": _film(s.n_angles, rb - ra)})
            lidar.set_tables(origins, dirs)
            lidar.first_beam = ra * s.n_angles
    else:
        s, pattern = None, (settings if rows is None else settings.rows(*rows))
        ra, rb = (0, settings.n_rows) if rows is None else padded_rows(*rows, settings.n_rows, settings.n_cols)
        own = settings if rows is None else settings.rows(ra, rb)  # the sensor's rows: whole packets
        lidar = mi.load_dict({"type": "lidar_pattern", "n_positions": own.n_rows,
                              "n_angles": own.n_cols, "footprint": own.footprint,
                              "film": _film(own.n_cols, own.n_rows)})
        lidar.set_tables(*own.sub_tables(o))
        if own.beam_dirs is not None:
            lidar.set_beam_dirs(own.beam_dirs.reshape(-1, 3))
        lidar.first_beam = ra * settings.n_cols
    motion = pattern.motion_tables()
    if motion is not None:  # each beam from the platform's position at its own time
        lidar.set_motion(*motion)
    return s, pattern, lidar


def _range_integrator(mi, built: BuiltScene, pattern: BeamPattern):
    integrator = mi.load_dict({"type": "lidar_range", "escape": pattern.escape_m,
                               "ground": pattern.ground, "ground_z": pattern.ground_z_m - built.origin_m[2],
                               "hit_rule": pattern.hit_rule})
    integrator.set_tables(**built.integrator_tables())
    if built.terrain_mesh is not None:
        integrator.set_terrain(built.terrain_mesh, built.terrain_shape_id, built.terrain_cell_m)
    return integrator


from ..config.work import DEFAULT_CHUNK_RAYS  # noqa: E402  (the work estimate sizes chunks by it too)


def physical_tracer(built: BuiltScene, settings_or_pattern: ScanSettings | BeamPattern, model: SensorModel,
                    *, seed: int = 0, leg: int = 0, variant: str | None = None,
                    chunk_beams: int = DEFAULT_CHUNK_BEAMS, chunk_rays: int = DEFAULT_CHUNK_RAYS,
                    rows: tuple[int, int] | None = None):
    """The :class:`~simlidar_mi.lidar.physical.PhysicalTracer` of a pattern (rows r0 … r1 − 1
    with ``rows``): its Mitsuba sensor, and the range integrator with reflectances and normals."""
    from .physical import PhysicalTracer  # noqa: PLC0415
    mi = mitsuba(variant)
    s, pattern, lidar = _lidar(mi, built, settings_or_pattern, rows)
    integrator = _range_integrator(mi, built, pattern)
    integrator.set_reflectance(model.class_reflectance(), built.shape_reflectance)
    if model.needs_energy:
        normals = built.prim_normals()
        if normals is not None:
            integrator.set_normals(normals, built.instance_yaw_rad)
    return PhysicalTracer(s, pattern, lidar, integrator, built.scene, model, _metadata(built), seed=seed,
                          leg=leg, chunk_beams=chunk_beams, chunk_rays=chunk_rays,
                          beam0=rows[0] * pattern.n_cols if rows is not None else 0)


def scan_physical(built: BuiltScene, settings_or_pattern: ScanSettings | BeamPattern,
                  model: SensorModel, *, seed: int = 0, leg: int = 0, variant: str | None = None,
                  chunk_beams: int = DEFAULT_CHUNK_BEAMS, chunk_rays: int = DEFAULT_CHUNK_RAYS,
                  rows: tuple[int, int] | None = None) -> ScanResult:
    """A real scanner's scan: divergent sub-rays, echoes from the waveform, intensity, noise.

    Beams are traced in chunks of whole beams (at most ``chunk_beams`` beams, ``[scan]
    chunk_beams``, and at most ``chunk_rays`` sub-rays, at least one beam:
    :mod:`simlidar_mi.lidar.physical`, whose chunks :mod:`~simlidar_mi.lidar.stream_sensor`
    writes without holding them), so the trace's memory stays bounded (the result holds
    every beam and echo); every step is per beam or
    keyed by the global beam index, so results do not depend on the chunk size (nor on
    ``rows``, a tile of the scan: see :func:`scan`).  Per sub-ray energies follow the law
    of :mod:`simlidar_mi.lidar.sensor`; echoes come from
    :func:`simlidar_mi.lidar.waveform.detect_echoes`, range noise from
    :mod:`simlidar_mi.lidar.noise` keyed by (``seed``, ``leg``, beam, return number).

    Without energies (``model.needs_energy`` false: range limits alone, or divergence with
    ``detection = "nearest"``) a beam's first return is its nearest sub-ray inside
    [range_min_m, range_max_m] (under ``hit_rule = "any"`` its nearest vegetation sub-ray).

    The result's first-return arrays hold echo 1 (escape where a beam has none);
    ``hit_fraction`` is the profile-weighted share of the beam's sub-rays whose first hit is
    vegetation; ``n_returns``, ``echoes``, ``intensity`` (with ``intensity = true``) and
    ``sensor`` are filled.
    """
    tracer = physical_tracer(built, settings_or_pattern, model, seed=seed, leg=leg, variant=variant,
                             chunk_beams=chunk_beams, chunk_rays=chunk_rays, rows=rows)
    pattern = tracer.pattern
    shape = (pattern.n_rows, pattern.n_cols)
    t0 = time.perf_counter()
    full, parts = {}, []
    for b0, n, part in tracer.chunks():
        for k, v in part.items():
            if k == "echoes":
                parts.append(v)
            elif v is not None:
                full.setdefault(k, np.empty(tracer.n_beams, v.dtype))[b0:b0 + n] = v
    seconds = time.perf_counter() - t0
    meta = dict(tracer.metadata, trace_seconds=tracer.trace_s, echo_seconds=tracer.echo_s)
    grid = {k: v.reshape(shape) for k, v in full.items()}
    return ScanResult(tracer.settings, grid["range"], grid["cls"], grid["elem"], grid["frac"],
                      built.origin_m.copy(), seconds, meta, pattern, grid.get("tree"),
                      echoes=Echoes.concat(parts) if tracer.energy else None, n_returns=grid["n_ret"],
                      intensity=grid.get("inten"), sensor=model.to_dict())


def _film(width: int, height: int) -> dict:
    return {"type": "hdrfilm", "width": width, "height": height, "pixel_format": "luminance",
            "rfilter": {"type": "box"}}


def read_scan_exr(path, broadcast: bool = False) -> tuple[dict[str, np.ndarray], dict]:
    """Channels and header of a scan EXR; ``header['settings']`` is a ScanSettings.

    The broadcast constants are 1-D float64 header arrays (issue #8): the tractor's
    ``header['theta_deg']`` (M,) and ``header['y_m']`` (N, real y), other platforms'
    ``header['angle_deg']`` (M,) and ``header['row_coord']`` (N,).  ``broadcast=True`` also
    gives them as the N × M float32 channels files stored before: ``theta_deg`` and ``y_m``
    (y − origin_m[1]), or ``angle_deg`` and ``row_coord``.  Older files keep their channels.
    """
    from ..io.exr import CONSTANT_ATTRS  # noqa: PLC0415
    channels, header = read_exr(path)
    if "simlidar_settings" in header:
        header["settings"] = ScanSettings(**json.loads(header["simlidar_settings"]))
    for name, attr in CONSTANT_ATTRS.items():
        if attr in header:
            header[name] = np.asarray(json.loads(header[attr]), np.float64)
        elif name in channels:  # a file from before issue #8
            c = channels[name]
            header[name] = (c[0, :] if name in ("theta_deg", "angle_deg") else
                            c[:, 0] + (header["origin_m"][1] if name == "y_m" else 0.0)).astype(np.float64)
    if broadcast and "range" in channels:
        n, m = channels["range"].shape
        for name in CONSTANT_ATTRS:
            if name in header and name not in channels:
                v = header[name]
                if name == "y_m":
                    v = v - header["origin_m"][1]
                col = name in ("theta_deg", "angle_deg")
                channels[name] = np.ascontiguousarray(
                    np.broadcast_to((v[None, :] if col else v[:, None]).astype(np.float32), (n, m)))
    return channels, header
