"""Side by side with HELIOS++: the same orchard, the same pulses, both tools.

    .venv/bin/python bench/bench_helios.py [--trees 4] [--iterations 7] [--sweeps N]
                                           [--modes single,fwf] [--out bench/out/helios]
    HELIOS=/path/to/helios++ .venv/bin/python bench/bench_helios.py ...   # also runs both

Export (always): the SIMLIDAR Table 3 orchard (``scenes/simlidar_table3_7x4.toml``, its
4 trees of 7 iterations unless ``--trees``/``--iterations`` say otherwise) as

* ``wood.obj`` — the very triangles of our native mesh scene (k = 12 prisms with their caps,
  taken from the built Mitsuba scene and moved back by its float64 origin, printed with
  17 digits so that they read back bit for bit), ``ground.obj`` — one square of two
  triangles, ``escape_m`` around the sweep, for HELIOS (ours keeps its analytic ground);
* ``scene_obj.toml`` — our scene from the OBJ (``[[primitive]] type = "obj"``, the same
  ``[scan]``, ``[sensor]``, ``[platform]`` and float64 origin as the native run);
* HELIOS++ XML: ``scanner.xml``, ``platform.xml``, ``scene.xml`` and one survey per mode.

How the HELIOS survey reproduces our tractor sweep, pulse by pulse: our moving tractor
(``[sensor] pulse_rate_hz`` f_p and ``[platform] speed_m_s`` v) turns its mirror a full
circle per sweep, f = f_p·Δθ/360°, and fires beam (i, k) at y_i + v·k/f_p, elevation
θ_k = θ_min + k·Δθ.  HELIOS's ``rotating`` optics (PolygonMirrorBeamDeflector) with
``scanAngleMax_deg = 180`` turns a full circle at ``scanFreq_hz`` = f, one pulse every
Δθ, from mirror angle 0 (advancing before each pulse, wrapping to −180° at +180°), and
emits only the pulses with verticalAngleMin < a ≤ verticalAngleMax.  The scanner mount
(z by −90°, then x by φ) points mirror angle a at elevation a + φ in our XZ plane; φ puts
the window at mirror angles −175° … −24.75°, so the first half turn from 0 emits nothing
and every later turn emits exactly our M pulses.  A ``linearpath`` platform moves
v/f_p per pulse along +y; its start is set so that the first emitted pulse sits at y_0,
its end half-way between the last sweep and the next.  :func:`helios_pulses` models this
(the same float64 steps as HELIOS's source) and the test checks it against our sweep;
``--pulse-log`` checks HELIOS's own pulse log (``--writePulse``) against ours.

Modes: ``single`` — one ray a pulse (ours: no divergence; HELIOS: beamSampleQuality 1, which
casts the central ray only; its divergence stays set because its energy model divides by it);
``fwf`` — 0.3 mrad divergence and 19 sub-rays (HELIOS: beamSampleQuality 3, rings of
1 + 6 + 12) with full-waveform echoes.

What cannot be matched (the counts differ for these reasons, not for geometry):

* Energy: HELIOS's received power uses a beam width that grows from ``rangeMin_m``
  (its ImprovedEnergyModel), so near the scanner the echo energy falls about as 1/R⁴
  rather than our 1/R²-with-footprint; echoes near the detection limit differ.
* rangeMin: HELIOS drops the whole pulse when its nearest sub-ray hit is nearer than
  ``rangeMin_m`` (it cannot start the waveform); ours drops only the sub-rays nearer
  than ``range_min_m``.  ``--range-min-m`` (default 0.05 m) sits below the nearest twig
  (0.07 m from the line), so neither drops anything here.
* Sub-rays: HELIOS's 19 sub-rays lie on rings at 0, ⅓ and ⅔ of its beamDivergence_rad,
  equally weighted apart from its energy model; ours sample the beam's Gaussian profile
  (full angle γ at 1/e²).  Pulse length: HELIOS's pulseLength_ns is the whole pulse;
  ours is the FWHM.  Detection: HELIOS's threshold and peak finder are its own.
* Detection limit: HELIOS keeps an echo above ``receivedEnergyMin_W`` (default 1e-4 W of its
  default 4 W), ours above ``detection_threshold`` of the emitted energy; the far ground,
  met at grazing angles just below the horizon, falls under HELIOS's limit first (one tree,
  500 sweeps: 10 ground pulses a sweep fewer than ours, single ray).
* Noise: none in either (HELIOS ``accuracy_m = 0``, ours no range noise).
* Leg ends: HELIOS v2.0.2 loses pulses near the end of a leg (:data:`EXTRA_SWEEPS`), so its
  leg runs longer and the extra sweeps are cut; its scan time includes them (+2 sweeps).

HELIOS's scene: HELIOS keeps a serialized copy of a scene it has built (``scene.scene``) and
reads it instead of the OBJ while it is newer than ``scene.xml``.  ``helios`` times HELIOS
reading the OBJ (the copy deleted first: the issue's measurement, and what both tools do on a
mesh they have not seen); ``helios_cached`` times it reading its copy.  Ours has no such cache.

Timing: each run is its own process (HELIOS: ``helios++``; ours: ``simlidar-mi scan``
writing all its files); end to end is its wall time, peak memory its ru_maxrss (the
largest process, from wait4); scan time is HELIOS's "Pulse computation tasks finished in"
line and our measures.json ``seconds.scan``.
"""
from __future__ import annotations

import argparse
import math
import os
import re
import shutil
import subprocess
import sys
import time
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "bench"))

import simlidar_mi as sm  # noqa: E402

SCENE = REPO / "scenes" / "simlidar_table3_7x4.toml"
PULSE_RATE_HZ = 72_000.0      # f_p: with Δθ = 0.25°, f = 50 sweeps/s ...
WINDOW_START_DEG = -175.0     # mirror angle of the first pulse of a sweep (see module docstring)
LAS_CODES = {"wood": 64, "ground": 2, "leaf": 5}   # our LAS classes (simlidar_mi.io.las)
REFLECTANCE = {"wood": 0.35, "ground": 0.20}       # our [materials] defaults
# HELIOS v2.0.2 loses pulses near a leg's end (emitted, never traced; measured with its pulse
# log): its leg runs this many sweeps longer and only the pulses of our N sweeps are counted,
# cut by their GPS time (see count_helios).
EXTRA_SWEEPS = 2
MODES = {"single": {"samples": 1, "quality": 1}, "fwf": {"samples": 19, "quality": 3}}


@dataclass(frozen=True)
class Sweep:
    """Our tractor sweep in the terms HELIOS needs (metres, degrees, hertz)."""

    x0_m: float
    z0_m: float
    y0_m: float          # y of beam (0, 0)
    dy_m: float
    n_sweeps: int
    theta_min_deg: float
    dtheta_deg: float
    n_angles: int
    pulse_rate_hz: float
    speed_m_s: float
    escape_m: float
    ground_z_m: float

    @property
    def sweep_rate_hz(self) -> float:
        return self.pulse_rate_hz * self.dtheta_deg / 360.0

    def pulses(self) -> tuple[np.ndarray, np.ndarray]:
        """Our pulses in firing order: origins (n, 3) and unit directions (n, 3)."""
        i, k = np.divmod(np.arange(self.n_sweeps * self.n_angles), self.n_angles)
        th = np.radians(self.theta_min_deg + k * self.dtheta_deg)
        y = self.y0_m + i * self.dy_m + self.speed_m_s * k / self.pulse_rate_hz
        o = np.stack([np.full_like(y, self.x0_m), y, np.full_like(y, self.z0_m)], 1)
        return o, np.stack([np.cos(th), np.zeros_like(th), np.sin(th)], 1)


def scene_config(trees: int, iterations: int, sweeps: int | None, speed_m_s: float,
                 extra: list[str] = ()) -> tuple[object, object, Sweep, list[str], list[str]]:
    """The Table 3 scene at this size, its geometry, our sweep, the size overrides (native
    scene only) and the ``--set`` overrides that give both of our runs exactly that sweep."""
    over = [f"orchard.n_trees={trees}", f"orchard.tree.iterations={iterations}", *extra]
    cfg = sm.load_scene(SCENE, over)
    geo = sm.generate(cfg)
    lo, hi = geo.bounds_m()
    sc = cfg["scan"]
    y0 = float(sc["y_start_m"] if sc["y_start_m"] is not None else lo[1])
    y1 = float(sc["y_end_m"] if sc["y_end_m"] is not None else hi[1])
    if sweeps is not None:
        y1 = y0 + (sweeps + 0.5) * sc["dy_m"]
    scan = {**sc, "y_start_m": y0, "y_end_m": y1}
    st = sm.resolve_settings(scan, cfg["ground"], lo, hi, cfg.source, geo.near_x_m,
                             pulse_rate_hz=PULSE_RATE_HZ, speed_m_s=speed_m_s, dy_given=True)
    if sweeps is not None and st.n_positions != sweeps:
        raise AssertionError(f"{st.n_positions} sweeps, wanted {sweeps}")
    sweep = Sweep(st.x0_m, st.z0_m, st.y_start_m, st.dy_m, st.n_positions, st.theta_min_deg,
                  st.dtheta_deg, st.n_angles, PULSE_RATE_HZ, speed_m_s, st.escape_m, st.ground_z_m)
    theta_max = st.theta_min_deg + (st.n_angles + 0.5) * st.dtheta_deg  # M stays Int(span/Δθ)
    scan_over = [f"scan.x0_m={st.x0_m!r}", f"scan.z0_m={st.z0_m!r}", f"scan.y_start_m={y0!r}",
             f"scan.y_end_m={y1!r}", f"scan.dy_m={st.dy_m!r}", f"scan.dtheta_deg={st.dtheta_deg!r}",
             f"scan.theta_min_deg={st.theta_min_deg!r}", f"scan.theta_max_deg={theta_max!r}",
             f"scan.escape_m={st.escape_m!r}", f"sensor.pulse_rate_hz={PULSE_RATE_HZ!r}",
             f"platform.speed_m_s={speed_m_s!r}"]
    return cfg, geo, sweep, over, scan_over


def sensor_overrides(mode: str, divergence_mrad: float, pulse_length_ns: float,
                     range_min_m: float) -> list[str]:
    """Our [sensor] keys for a mode (single ray: no divergence, first hits as SIMLIDAR)."""
    if mode == "single":
        return [f"sensor.range_min_m={range_min_m!r}"]
    return [f"sensor.divergence_mrad={divergence_mrad!r}", f"sensor.beam_samples={MODES[mode]['samples']}",
            "sensor.max_returns=15", 'sensor.detection="waveform"',
            f"sensor.pulse_length_ns={pulse_length_ns!r}", f"sensor.range_min_m={range_min_m!r}"]


# --- HELIOS's pulses, modelled from its source (PolygonMirrorBeamDeflector, LinearPathPlatform)


def mirror_angles(scan_freq_hz: float, pulse_rate_hz: float, n_steps: int) -> np.ndarray:
    """HELIOS's mirror angle (rad) at each of the first ``n_steps`` simulation steps: from 0,
    ``angle += step`` before each pulse, reset to −π once it reaches π (float64, as its
    doSimStep).  After the first reset every turn repeats, so one turn is stepped."""
    amax = 180.0 * (math.pi / 180.0)
    step = (scan_freq_hz * (amax - (-amax))) / pulse_rate_hz
    first, a = [], 0.0
    while True:
        a += step
        if a >= amax:
            break
        first.append(a)
    turn, a = [-amax], -amax
    while True:
        a += step
        if a >= amax:
            break
        turn.append(a)
    first.append(-amax)  # the step that wrapped
    reps = max(0, -(-(n_steps - len(first)) // len(turn)))
    return np.concatenate([first, np.tile(turn[1:] + [-amax], reps)])[:n_steps]


def helios_plan(sweep: Sweep) -> dict:
    """The HELIOS settings that reproduce ``sweep``: angles, window, mount, leg ends."""
    f = sweep.sweep_rate_hz
    phi = sweep.theta_min_deg - WINDOW_START_DEG              # elevation = mirror angle + φ
    half = 0.5 * sweep.dtheta_deg
    vmin = WINDOW_START_DEG - half
    vmax = WINDOW_START_DEG + (sweep.n_angles - 1) * sweep.dtheta_deg + half
    if not (-180.0 < vmin and vmax < 0.0):
        raise ValueError(f"a sweep of {sweep.n_angles} × {sweep.dtheta_deg}° does not fit in a half turn")
    steps_turn = round(360.0 / sweep.dtheta_deg)
    a = mirror_angles(f, sweep.pulse_rate_hz, 3 * steps_turn)
    on = np.flatnonzero((a > math.radians(vmin)) & (a <= math.radians(vmax)))
    n_first = int(on[0])                                       # step of beam (0, 0)
    per_step = sweep.speed_m_s / sweep.pulse_rate_hz           # platform move per step
    fired = sweep.n_sweeps + EXTRA_SWEEPS
    last = n_first + (fired - 1) * steps_turn + sweep.n_angles - 1
    end_step = 0.5 * (last + n_first + fired * steps_turn)    # between two sweeps
    y_start = sweep.y0_m - n_first * per_step
    return {"scan_freq_hz": f, "phi_deg": phi, "vmin_deg": vmin, "vmax_deg": vmax,
            "y_start_m": y_start, "y_end_m": y_start + end_step * per_step,
            "n_steps": int(math.floor(end_step)) + 1, "steps_turn": steps_turn, "first_step": n_first}


def helios_pulses(sweep: Sweep, plan: dict) -> tuple[np.ndarray, np.ndarray]:
    """The pulses HELIOS fires for ``plan`` (origins, directions), from its stepping rules:
    position = start + n·v/f_p (the platform moves before the scanner steps, velocity 0 at
    step 0), direction = mount · Rx(a) · forward."""
    a = mirror_angles(plan["scan_freq_hz"], sweep.pulse_rate_hz, plan["n_steps"])
    n = np.flatnonzero((a > math.radians(plan["vmin_deg"])) & (a <= math.radians(plan["vmax_deg"])))
    el = a[n] + math.radians(plan["phi_deg"])
    y = plan["y_start_m"] + n * (sweep.speed_m_s / sweep.pulse_rate_hz)
    o = np.stack([np.full_like(y, sweep.x0_m), y, np.full_like(y, sweep.z0_m)], 1)
    return o, np.stack([np.cos(el), np.zeros_like(el), np.sin(el)], 1)


# --- export -------------------------------------------------------------------------------


def wood_triangles(cfg, geo) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The triangles of our native scene, read back from the built Mitsuba meshes:
    vertices (float64, real coordinates), faces (int64), and the scene's float64 origin."""
    import mitsuba as mi  # noqa: PLC0415  (sm.build has loaded it)
    built = sm.build(cfg, geo)
    vs, fs, base = [], [], 0
    for shape in built.prim_shapes:
        if shape is None:
            continue
        if "leaf" in shape.id():
            raise ValueError("leaves are not exported (the Table 3 orchard has none)")
        p = mi.traverse(shape)
        v = np.asarray(p["vertex_positions"], np.float32).reshape(-1, 3)
        vs.append(v.astype(np.float64) + built.origin_m)   # exact: f32 + whole metres
        fs.append(np.asarray(p["faces"], np.int64).reshape(-1, 3) + base)
        base += len(v)
    return np.concatenate(vs), np.concatenate(fs), np.asarray(built.origin_m, float)


def write_obj(path: Path, vertices: np.ndarray, faces: np.ndarray, material: str) -> None:
    """A text OBJ with one material; 17 significant digits, so float64 reads back exactly."""
    path.with_suffix(".mtl").write_text(
        f"newmtl {material}\nKd {REFLECTANCE[material]} {REFLECTANCE[material]} {REFLECTANCE[material]}\n"
        f"helios_reflectance {REFLECTANCE[material]}\nhelios_classification {LAS_CODES[material]}\n")
    with open(path, "w") as fh:
        fh.write(f"mtllib {path.with_suffix('.mtl').name}\no {material}\nusemtl {material}\n")
        np.savetxt(fh, vertices, fmt="v %.17g %.17g %.17g")
        np.savetxt(fh, faces + 1, fmt="f %d %d %d")


def ground_square(sweep: Sweep) -> tuple[np.ndarray, np.ndarray]:
    """Two triangles of the ground, ``escape_m`` beyond the sweep on every side (ours is a
    plane; no pulse reaches beyond escape_m)."""
    r = sweep.escape_m
    y1 = sweep.y0_m + sweep.n_sweeps * sweep.dy_m
    x0, x1, ya, yb = sweep.x0_m - r, sweep.x0_m + r, sweep.y0_m - r, y1 + r
    z = sweep.ground_z_m
    return (np.array([[x0, ya, z], [x1, ya, z], [x1, yb, z], [x0, yb, z]]),
            np.array([[0, 1, 2], [0, 2, 3]]))


def _xml(path: Path, root: ET.Element) -> None:
    ET.indent(root)
    path.write_bytes(b'<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root) + b"\n")


def write_helios_xml(out: Path, sweep: Sweep, plan: dict, divergence_mrad: float,
                     pulse_length_ns: float, range_min_m: float) -> dict[str, Path]:
    """Scanner, platform, scene and one survey per mode (absolute paths inside)."""
    g = repr
    files = {}
    doc = ET.Element("document")
    for mode, m in MODES.items():
        sc = ET.SubElement(doc, "scanner", {
            "id": f"tractor_{mode}", "name": f"simlidar tractor sweep ({mode})", "optics": "rotating",
            "accuracy_m": "0", "beamDivergence_rad": g(divergence_mrad * 1e-3),
            "pulseFreqs_Hz": g(int(sweep.pulse_rate_hz)), "pulseLength_ns": g(pulse_length_ns),
            "rangeMin_m": g(range_min_m), "scanAngleMax_deg": "180", "scanAngleEffectiveMax_deg": "180",
            "scanFreqMin_Hz": "0", "scanFreqMax_Hz": g(2 * plan["scan_freq_hz"]),
            "headRotatePerSecMax_deg": "0", "maxNOR": "0", "wavelength_nm": "905"})
        ET.SubElement(sc, "FWFSettings", {"beamSampleQuality": str(m["quality"])})
        ET.SubElement(sc, "beamOrigin", {"x": "0", "y": "0", "z": "0"})
        ET.SubElement(sc, "headRotateAxis", {"x": "0", "y": "0", "z": "1"})
    _xml(out / "scanner.xml", doc)
    doc = ET.Element("document")
    pf = ET.SubElement(doc, "platform", {"id": "tractor", "name": "tractor line", "type": "linearpath"})
    mount = ET.SubElement(pf, "scannerMount", {"x": "0", "y": "0", "z": "0", "rotations": "local"})
    ET.SubElement(mount, "rot", {"axis": "z", "angle_deg": "-90"})     # beam plane: our XZ
    ET.SubElement(mount, "rot", {"axis": "x", "angle_deg": g(plan["phi_deg"])})  # elevation = a + φ
    _xml(out / "platform.xml", doc)
    doc = ET.Element("document")
    scene = ET.SubElement(doc, "scene", {"id": "orchard", "name": "Table 3 orchard"})
    for pid, name in (("1", "wood"), ("2", "ground")):
        part = ET.SubElement(scene, "part", {"id": pid})
        flt = ET.SubElement(part, "filter", {"type": "objloader"})
        ET.SubElement(flt, "param", {"type": "string", "key": "filepath", "value": str(out / f"{name}.obj")})
        ET.SubElement(flt, "param", {"type": "string", "key": "up", "value": "z"})
    _xml(out / "scene.xml", doc)
    for mode in MODES:
        doc = ET.Element("document")
        sv = ET.SubElement(doc, "survey", {
            "name": f"tractor_{mode}", "scene": f"{out / 'scene.xml'}#orchard",
            "platform": f"{out / 'platform.xml'}#tractor", "scanner": f"{out / 'scanner.xml'}#tractor_{mode}"})
        for y, active in ((plan["y_start_m"], "true"), (plan["y_end_m"], "false")):
            leg = ET.SubElement(sv, "leg")
            ET.SubElement(leg, "platformSettings", {"x": g(sweep.x0_m), "y": g(y), "z": g(sweep.z0_m),
                                                     "onGround": "false", "movePerSec_m": g(sweep.speed_m_s)})
            ET.SubElement(leg, "scannerSettings", {
                "active": active, "pulseFreq_hz": g(int(sweep.pulse_rate_hz)), "scanFreq_hz": g(plan["scan_freq_hz"]),
                "scanAngle_deg": "180", "verticalAngleMin_deg": g(plan["vmin_deg"]),
                "verticalAngleMax_deg": g(plan["vmax_deg"]), "headRotatePerSec_deg": "0",
                "headRotateStart_deg": "0", "headRotateStop_deg": "0", "trajectoryTimeInterval_s": "0"})
        files[mode] = out / f"survey_{mode}.xml"
        _xml(files[mode], doc)
    return files


def write_obj_scene(path: Path, origin_m: np.ndarray, cfg) -> None:
    """Our scene from the OBJ: the mesh as a wood primitive, the native scene's ground and
    origin ([scan]/[sensor]/[platform] come as ``--set`` overrides, as for the native run)."""
    o = ", ".join(repr(float(x)) for x in origin_m)
    path.write_text(
        f'[scene]\nname = "table3_from_obj"\nseed = {cfg["scene"]["seed"]}\norigin_m = [{o}]\n\n'
        f'[[primitive]]\ntype = "obj"\npath = "wood.obj"\nlabel = "wood"\n\n'
        f'[ground]\nenabled = {str(cfg["ground"]["enabled"]).lower()}\nz_m = {cfg["ground"]["z_m"]!r}\n')


@dataclass
class Export:
    out: Path
    sweep: Sweep
    plan: dict
    overrides: list
    surveys: dict
    n_triangles: int


def export(out: Path, trees: int, iterations: int, sweeps: int | None = None, *,
           speed_m_s: float | None = None, divergence_mrad: float = 0.3, pulse_length_ns: float = 4.0,
           range_min_m: float = 0.05, extra: list[str] = ()) -> Export:
    """Write every input of both tools for this size into ``out``."""
    out = Path(out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    cfg0 = sm.load_scene(SCENE)
    dy = cfg0["scan"]["dy_m"]
    speed = speed_m_s if speed_m_s is not None else dy * PULSE_RATE_HZ * cfg0["scan"]["dtheta_deg"] / 360.0
    cfg, geo, sweep, size_over, scan_over = scene_config(trees, iterations, sweeps, speed, extra)
    plan = helios_plan(sweep)
    v, f, origin = wood_triangles(cfg, geo)
    write_obj(out / "wood.obj", v, f, "wood")
    write_obj(out / "ground.obj", *ground_square(sweep), "ground")
    write_obj_scene(out / "scene_obj.toml", origin, cfg)
    surveys = write_helios_xml(out, sweep, plan, divergence_mrad, pulse_length_ns, range_min_m)
    over_sensor = {m: sensor_overrides(m, divergence_mrad, pulse_length_ns, range_min_m) for m in MODES}
    return Export(out, sweep, plan, {"size": size_over, "scan": scan_over, **over_sensor}, surveys, len(f))


# --- running and counting -----------------------------------------------------------------


def run_timed(cmd: list[str], log: Path, cwd: Path | None = None) -> tuple[float, float]:
    """Run ``cmd`` (stdout+stderr to ``log``): wall seconds and peak RSS in GB (ru_maxrss
    of the largest process waited for, from wait4)."""
    t = time.perf_counter()
    with open(log, "w") as fh:
        proc = subprocess.Popen(cmd, stdout=fh, stderr=subprocess.STDOUT, cwd=cwd)
        _, status, ru = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t
    proc.returncode = os.waitstatus_to_exitcode(status)
    if proc.returncode:
        raise RuntimeError(f"{cmd[0]} exited {proc.returncode}; see {log}")
    return wall, ru.ru_maxrss / 2**20


def echo_histogram(return_number: np.ndarray, n_returns: np.ndarray) -> dict[str, int]:
    """Pulses with 1, 2 and 3+ echoes (each pulse counted at its first return)."""
    n = n_returns[return_number == 1]
    return {"1": int(np.sum(n == 1)), "2": int(np.sum(n == 2)), "3+": int(np.sum(n >= 3))}


def count_ours(las_path: Path) -> dict:
    import laspy  # noqa: PLC0415
    las = laspy.read(las_path)
    cls = np.asarray(las.classification)
    return {"wood": int(np.sum(cls == LAS_CODES["wood"])), "ground": int(np.sum(cls == LAS_CODES["ground"])),
            "points": len(cls), **echo_histogram(np.asarray(las.return_number), np.asarray(las.number_of_returns))}


def our_steps(t_s: np.ndarray, t0_s: float, sweep: Sweep) -> np.ndarray:
    """Which of HELIOS's timed records belong to our N sweeps: step k = (t − t0)·f_p after
    pulse (0, 0); sweep i's pulses are steps i·turn … i·turn + M − 1."""
    k = np.rint((np.asarray(t_s, float) - t0_s) * sweep.pulse_rate_hz)
    turn = round(360.0 / sweep.dtheta_deg)
    return (k >= 0) & (k <= (sweep.n_sweeps - 1) * turn + sweep.n_angles - 1)


def count_helios(xyz_path: Path, sweep: Sweep) -> dict:
    """HELIOS's xyz columns: x y z intensity echo_width return_number number_of_returns
    fullwave_index hit_object_id classification gps_time (s).  Pulse (0, 0) points 75°
    down at the ground 1 m below, so the earliest point is its return and times t0."""
    import pandas as pd  # noqa: PLC0415
    df = pd.read_csv(xyz_path, sep=" ", header=None, usecols=[5, 6, 9, 10])
    t = df[10].to_numpy(float)
    keep = our_steps(t, t.min(), sweep)
    cols = df[[5, 6, 9]].to_numpy(np.int64)[keep]
    cls = cols[:, 2]
    return {"wood": int(np.sum(cls == LAS_CODES["wood"])), "ground": int(np.sum(cls == LAS_CODES["ground"])),
            "points": len(cls), **echo_histogram(cols[:, 0], cols[:, 1])}


def run_ours(ex: Export, mode: str, which: str) -> dict:
    """``simlidar-mi scan`` on the native scene or the scene from the OBJ, all its files."""
    out = ex.out / f"ours_{which}_{mode}"
    shutil.rmtree(out, ignore_errors=True)
    scene = SCENE if which == "native" else ex.out / "scene_obj.toml"
    over = (ex.overrides["size"] if which == "native" else []) + ex.overrides["scan"] + ex.overrides[mode]
    cmd = [sys.executable, "-m", "simlidar_mi.cli", "scan", str(scene), "--out", str(out)]
    for o in over:
        cmd += ["--set", o]
    wall, rss = run_timed(cmd, ex.out / f"ours_{which}_{mode}.log", cwd=REPO)
    import json  # noqa: PLC0415
    sec = json.loads((out / "measures.json").read_text())["seconds"]
    return {"scan_s": sec["scan"], "wall_s": wall, "rss_gb": rss, **count_ours(out / "points.las")}


def run_helios(ex: Export, mode: str, binary: str, pulse_log: bool = False, assets: list = (),
               cached: bool = False) -> dict:
    """``helios++`` on the mode's survey (``assets``: its --assets folders, e.g. the one with
    its spectra/); with ``pulse_log`` its pulse log is checked against our pulses.

    HELIOS keeps a serialized copy of a scene it has built (``scene.scene`` beside
    ``scene.xml``) and reads it instead of the OBJ while it is newer than the XML.  ``cached``
    False ("from the OBJ", as the issue measured it): the copy is deleted first, so HELIOS reads
    the OBJ and builds its KD-grove; True ("its scene cache"): a run from the OBJ makes the copy
    if it is missing or stale (untimed), then the timed run reads it."""
    out = ex.out / f"helios_{mode}{'_cached' if cached else ''}"
    shutil.rmtree(out, ignore_errors=True)
    log = ex.out / f"helios_{mode}{'_cached' if cached else ''}.log"
    serial, xml = ex.out / "scene.scene", ex.out / "scene.xml"
    fresh = serial.exists() and serial.stat().st_mtime > xml.stat().st_mtime
    if not cached:
        serial.unlink(missing_ok=True)
    else:
        if not fresh:
            run_helios(ex, mode, binary, assets=assets, cached=False)
        # HELIOS compares the two times in whole seconds (time_t): a copy made in the XML's
        # second counts as stale, so the XML is dated back (a small scene builds in under 1 s)
        t_serial = serial.stat().st_mtime
        if int(t_serial) <= int(xml.stat().st_mtime):
            os.utime(xml, (t_serial - 2, t_serial - 2))
    cmd = [binary, str(ex.surveys[mode]), "--output", str(out)] + (["--writePulse"] if pulse_log else [])
    for folder in assets:
        cmd += ["--assets", str(folder)]
    wall, rss = run_timed(cmd, log, cwd=Path(binary).resolve().parent)
    read_serial = "Writing serial scene" not in log.read_text()
    if read_serial != cached:
        raise RuntimeError(f"HELIOS {'did not read' if cached else 'read'} its scene cache; see {log}")
    m = re.findall(r"Pulse computation tasks finished in ([0-9.eE+-]+) sec", log.read_text())
    xyz = sorted(out.rglob("leg000_points.xyz"))
    if not xyz:
        raise RuntimeError(f"HELIOS wrote no leg000_points.xyz under {out}; see {log}")
    res = {"scan_s": float(m[-1]) if m else float("nan"), "wall_s": wall, "rss_gb": rss,
           **count_helios(xyz[-1], ex.sweep)}
    if pulse_log:
        res["pulse_check"] = check_pulse_log(ex, sorted(out.rglob("leg000_pulse.txt"))[-1])
    return res


def check_pulse_log(ex: Export, path: Path) -> dict:
    """HELIOS's pulse log against our pulses: count, largest origin and direction gaps."""
    import pandas as pd  # noqa: PLC0415
    p = pd.read_csv(path, sep=" ", header=None).to_numpy()
    p = p[np.argsort(p[:, 7], kind="stable")]                 # by pulse index
    p = p[our_steps(p[:, 6] * 1e-9, p[0, 6] * 1e-9, ex.sweep)]  # its time column is in ns
    o, d = ex.sweep.pulses()
    n = min(len(p), len(o))
    return {"helios_pulses": len(p), "our_pulses": len(o),
            "max_origin_gap_m": float(np.abs(p[:n, 0:3] - o[:n]).max()) if n else float("nan"),
            "max_direction_gap": float(np.abs(p[:n, 3:6] - d[:n]).max()) if n else float("nan")}


HEADS = {"helios": "HELIOS++ from the OBJ", "helios_cached": "HELIOS++ from its scene cache",
         "ours_obj": "ours, scene from the OBJ", "ours_native": "ours, native scene"}
SHORT = {"ours_obj": "OBJ", "ours_native": "native"}


def table(ex: Export, res: dict) -> str:
    """One markdown table: a column per run, HELIOS/ours ratios for the times and memory."""
    runs = [k for k in HEADS if k in res]
    hel = [k for k in runs if k.startswith("helios")]
    ours = [k for k in runs if not k.startswith("helios")]
    rows = [f"| run | {' | '.join(HEADS[k] for k in runs)} | "
            + " | ".join(f"{HEADS[h]} / ours ({', '.join(SHORT[k] for k in ours)})" for h in hel) + " |",
            "|---|" + "---|" * (len(runs) + len(hel))]

    def ratio(mode, key):
        return " | ".join(", ".join(f"{res[h][mode][key] / res[k][mode][key]:.2f}×" for k in ours) for h in hel)
    for mode in res[runs[0]]:
        r = {k: res[k][mode] for k in runs}
        blank = " |" * len(hel)
        rows.append(f"| {mode}: wood / ground points | "
                    + " | ".join(f"{r[k]['wood']:,} / {r[k]['ground']:,}" for k in runs) + f" |{blank}")
        rows.append(f"| {mode}: pulses with 1 / 2 / 3+ echoes | "
                    + " | ".join(f"{r[k]['1']:,} / {r[k]['2']:,} / {r[k]['3+']:,}" for k in runs) + f" |{blank}")
        for key, label, unit in (("scan_s", "scan", "s"), ("wall_s", "end to end", "s"), ("rss_gb", "peak memory", "GB")):
            rows.append(f"| {mode}: {label} | " + " | ".join(f"{r[k][key]:.2f} {unit}" for k in runs)
                        + f" | {ratio(mode, key)} |")
    s = ex.sweep
    return (f"{s.n_sweeps:,} sweeps × {s.n_angles} pulses = {s.n_sweeps * s.n_angles:,} pulses, "
            f"{ex.n_triangles:,} triangles\n\n" + "\n".join(rows))


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trees", type=int, default=4)
    ap.add_argument("--iterations", type=int, default=7)
    ap.add_argument("--sweeps", type=int, default=None, help="sweeps (default: the scene's y range)")
    ap.add_argument("--modes", default="single,fwf")
    ap.add_argument("--runs", default="helios,helios_cached,ours_obj,ours_native",
                    help="helios: HELIOS++ reading the OBJ; helios_cached: reading its own serialized scene")
    ap.add_argument("--divergence-mrad", type=float, default=0.3)
    ap.add_argument("--pulse-length-ns", type=float, default=4.0)
    ap.add_argument("--range-min-m", type=float, default=0.05)
    ap.add_argument("--pulse-log", action="store_true", help="check HELIOS's pulse log against ours")
    ap.add_argument("--helios-assets", action="append", default=[], help="HELIOS --assets folder (repeatable)")
    ap.add_argument("--out", type=Path, default=REPO / "bench" / "out" / "helios")
    a = ap.parse_args(argv)
    t = time.perf_counter()
    ex = export(a.out, a.trees, a.iterations, a.sweeps, divergence_mrad=a.divergence_mrad,
                pulse_length_ns=a.pulse_length_ns, range_min_m=a.range_min_m)
    print(f"exported {ex.n_triangles:,} triangles and {ex.sweep.n_sweeps * ex.sweep.n_angles:,} pulses "
          f"to {ex.out} in {time.perf_counter() - t:.1f} s", file=sys.stderr)
    binary = os.environ.get("HELIOS")
    runs = [r for r in a.runs.split(",") if r]   # --runs "": export only
    if not binary:
        runs = [r for r in runs if not r.startswith("helios")]
        print("HELIOS is not set: HELIOS++ is not run", file=sys.stderr)
    if not runs:
        return
    res: dict = {r: {} for r in runs}
    for mode in a.modes.split(","):
        for r in runs:
            res[r][mode] = (run_helios(ex, mode, binary, a.pulse_log, a.helios_assets, cached=r == "helios_cached")
                            if r.startswith("helios") else run_ours(ex, mode, r.split("_")[1]))
            print(f"  {r} {mode}: {res[r][mode]}", file=sys.stderr)
    from _machine import machine  # noqa: PLC0415
    print(f"Machine: {machine()}  \nDate: {time.strftime('%Y-%m-%d')}  \nCommand: `"
          + ("HELIOS=... " if binary else "") + "python bench/bench_helios.py "
          + " ".join(sys.argv[1:] if argv is None else argv) + "`\n\n" + table(ex, res))


if __name__ == "__main__":
    main()
