"""Issue #29 §4: what LiDAR tools still misread in our files.

* LAStools' "resolution fluff": :func:`lastools_fluff` is the rule as LAStools states it
  (LAStools/LAStools, LASlib/src/lasutility.cpp, ``LASsummary::add``; the flags
  ``has_fluff``/``has_serious_fluff`` in LASlib/inc/lasutility.hpp, printed by lasinfo.cpp and
  lascheck.cpp): the first point's X % 10, % 100, % 1000, % 10000 (C's remainder, sign of the
  dividend) are kept, and an axis has fluff (x10), serious (x100), very serious (x1000) … when
  every point leaves the same remainder.  lascheck.cpp also warns on a scale that is not
  1, 2.5 or 5 × 10^k and on an offset off the scale's grid ("translation fluff").
* Intensity: a scale per scan from its largest echo, so nothing clips and 16 bits are used.
* Extra Bytes ``no_data`` for the ids' 4294967295 (LAS 1.4 R15 §4, option bit 0).
* OpenImageIO and the integer EXR channels.
"""
from __future__ import annotations

import struct

import laspy
import numpy as np
import pytest

from simlidar_mi.cli import main
from simlidar_mi.config import load_scene
from simlidar_mi.io import las_fields
from simlidar_mi.io.exr import write_scan_exr
from simlidar_mi.io.las import write_scan_las
from simlidar_mi.lidar.scan import ScanResult, ScanSettings
from simlidar_mi.lidar.survey import run_scan
from tests.conftest import SCENES
from tests.las_conformance import EB_DESCRIPTOR_SIZE, read_header, read_vlrs
from tests.test_echo_outputs import _echo_result

LEVELS = (10, 100, 1000, 10000)  # x10, x100 ("serious"), x1000 ("very serious"), x10000


def lastools_fluff(stored: np.ndarray) -> tuple[bool, ...]:
    """LAStools' fluff flags of one axis's stored integers (module docstring), x10 … x10000.
    Each level counts the points matching the first point's remainder at it and at every
    coarser level, and flags the axis when all points do."""
    v = np.asarray(stored, np.int64)
    if not len(v):
        return (False,) * len(LEVELS)
    same = np.ones(len(v), bool)
    flags = []
    for d in LEVELS:
        r = np.fmod(v, d)  # C's %: the sign of the dividend
        same &= r == r[0]
        flags.append(bool(same.all()))
    return tuple(flags)


def lastools_header_warnings(las: laspy.LasData) -> list[str]:
    """lascheck.cpp's scale and offset warnings: scale 1, 2.5 or 5 × 10^k, offset on its grid."""
    out = []
    for c, name in enumerate("xyz"):
        s, o = las.header.scales[c], las.header.offsets[c]
        mant = s / 10.0 ** np.floor(np.log10(s))
        if not any(abs(mant - m) < 1e-9 for m in (1.0, 2.5, 5.0)):
            out.append(f"{name} scale factor {s}")
        if abs(o - s * round(o / s)) > 1e-9:
            out.append(f"{name} offset {o}: translation fluff")
    return out


def test_the_rule_is_lastools_remainders_not_multiples_of_ten():
    """The demo's Y (6028 + 20·i) has no integer divisible by 10 and still trips x10; a
    remainder of −3 is not one of 7 (C's %); a constant axis trips every level."""
    assert lastools_fluff(6028 + 20 * np.arange(50)) == (True, False, False, False)
    assert lastools_fluff(6000 + 200 * np.arange(50)) == (True, True, False, False)
    assert lastools_fluff(np.arange(50)) == (False,) * 4
    assert lastools_fluff([-3, 7, 17]) == (False,) * 4
    assert lastools_fluff([5, 5, 5]) == (True,) * 4
    assert lastools_fluff([12345]) == (True,) * 4  # one point: every level (no file avoids it)


def _axis_report(path):
    las = laspy.read(path)
    arr = las.points.array
    return las, {name: lastools_fluff(arr[name]) for name in "XYZ"}, \
        {name: len(np.unique(arr[name])) for name in "XYZ"}


def _tractor(y_start_m: float, dy_m: float, n_pos: int, theta_deg, ranges) -> ScanResult:
    """A tractor pattern (rows along y on a regular grid) with given per-column ranges."""
    theta = np.asarray(theta_deg, float)
    p = ScanSettings(x0_m=1.0, z0_m=1.0, y_start_m=y_start_m, dy_m=dy_m, gap=0, n_positions=n_pos,
                     theta_min_deg=float(theta[0]), dtheta_deg=float(theta[1] - theta[0]) if len(theta) > 1 else 1.0,
                     n_angles=len(theta)).pattern()
    n, m = p.n_rows, p.n_cols
    rng_m = np.broadcast_to(np.asarray(ranges, np.float32), (n, m)).copy()
    cls = np.full((n, m), 2, np.uint8)
    return ScanResult(None, rng_m, cls, np.arange(n * m, dtype=np.uint32).reshape(n, m),
                      np.ones((n, m), np.float32), np.zeros(3), pattern=p)


def _kinds():
    rng = np.random.default_rng(29)
    theta = np.arange(-60.0, 60.0, 0.25)
    # rows 2 mm apart from an edge off the 0.1 mm-multiple-of-10 grid (the demo's Y), wood at random ranges
    yield "grid", _tractor(-0.3972, 0.002, 200, theta, rng.uniform(0.5, 3.0, len(theta)))
    yield "grid_odd_start", _tractor(-1.23456, 0.002, 200, theta, rng.uniform(0.5, 3.0, len(theta)))
    yield "grid_1cm", _tractor(0.5, 0.01, 100, theta, rng.uniform(0.5, 3.0, len(theta)))
    # orchard_leafy's rows: 1 cm apart from y = −1.453 m (Y = 547 + 10·i at 1 mm): 2.5 mm, moved 0.5 mm
    yield "grid_1cm_leafy", _tractor(-1.453, 0.01, 100, theta, rng.uniform(0.5, 3.0, len(theta)))
    # the ground plane z = 0 seen from 1 m: x = 1 + cot(−θ), z = 0 for every point
    down = np.arange(-80.0, -10.0, 0.5)
    yield "plane", _tractor(-0.3972, 0.002, 100, down, 1.0 / np.sin(np.radians(-down)))
    # one ray a row, 30° down onto the ground: x and z the same for every point, y on the grid
    yield "single_ray", _tractor(-0.3972, 0.002, 300, [-30.0], [2.0])


@pytest.mark.parametrize("kind,res", list(_kinds()), ids=[k for k, _ in _kinds()])
def test_no_axis_with_two_values_trips_lastools_fluff(tmp_path, kind, res):
    """Every axis holding at least two values passes LAStools' rule at x10 (so at every level),
    with scales and offsets lascheck accepts, and the points within 0.15 mm of the simulated
    ones (0.05 mm of rounding, at most 0.1 mm of shift of rows 2 mm apart; 0.5 mm at most for
    other grids, MAX_SHIFT_M).  A constant axis
    (the plane's z, the single ray's x and z) trips it whatever the scale: LAStools counts
    remainders of equal integers."""
    path = write_scan_las(res, tmp_path / "p.las")
    las, fluff, distinct = _axis_report(path)
    for name in "XYZ":
        if distinct[name] > 1:
            assert fluff[name] == (False,) * 4, (kind, name, las.header.scales, fluff)
        else:
            assert kind in ("plane", "single_ray") and name in "XZ", (kind, name)
    assert lastools_header_warnings(las) == []
    i, k = np.asarray(las.scan_position), np.asarray(las.scan_angle_index)
    moved = 5.5e-4 if kind == "grid_1cm_leafy" else 1.5e-4  # rows 2 mm apart: ≤ 0.1 mm (+ 0.05)
    np.testing.assert_allclose(las.xyz, res.points_m()[i, k], rtol=0, atol=moved)
    step = 0.01 if kind.startswith("grid_1cm") else 0.002  # exact distances along the track
    y = np.asarray(las.points.array["Y"], np.int64) * las.header.scales[1]
    np.testing.assert_allclose(np.diff(np.unique(y)), step, rtol=0, atol=1e-9)


def test_a_coarse_grid_far_off_every_scale_keeps_exact_coordinates_and_the_fluff(tmp_path):
    """The documented limit: rows 5 cm apart from y = −0.3972 m would need a 1 cm scale or
    coarser and a move of 2.8 mm (> MAX_SHIFT_M); the file keeps the exact 0.1 mm coordinates
    (x10 fluff in Y, as lasinfo reports) rather than move the points."""
    res = _tractor(-0.3972, 0.05, 40, [-30.0, -20.0], [2.0, 2.5])
    las, fluff, _ = _axis_report(write_scan_las(res, tmp_path / "p.las"))
    assert fluff["Y"][0] and las.header.scales[1] == 0.0001
    i, k = np.asarray(las.scan_position), np.asarray(las.scan_angle_index)
    np.testing.assert_allclose(las.xyz, res.points_m()[i, k], rtol=0, atol=0.5e-4)


def test_scale_chooser_is_the_same_for_any_pieces():
    """The choice (a gcd and a first value per axis) does not depend on how the points come."""
    res = dict(_kinds())["grid_odd_start"]
    keep = res.cls != 0
    pts = res.points_m()[keep].T
    whole = las_fields.ScaleChooser()
    whole.add(pts)
    pieces = las_fields.ScaleChooser()
    for a in range(0, pts.shape[1], 777):
        pieces.add(pts[:, a:a + 777])
    assert np.array_equal(whole.scales(), pieces.scales()) and whole.fluff_free() == [True, True, True]
    assert whole.scales()[1] == 0.00025  # y: 2 mm = 8 steps of 0.25 mm


def test_demo_points_have_no_resolution_fluff(tmp_path):
    """The issue's file: scenes/apple_orchard.toml's points.las (Y was 6028 + 20·i at 0.1 mm)."""
    assert main(["scan", str(SCENES / "apple_orchard.toml"), "--out", str(tmp_path / "a"), "--no-png"]) == 0
    las, fluff, distinct = _axis_report(tmp_path / "a" / "points.las")
    assert all(d > 1 for d in distinct.values())
    assert fluff == {name: (False,) * 4 for name in "XYZ"}, (las.header.scales, fluff)
    assert lastools_header_warnings(las) == []


# --- intensity --------------------------------------------------------------------------------

def _plate_scene(x_m: float, rho: float = 1.0, sensor: str = "") -> str:
    """A tripod at the origin and one Lambertian plate facing it (normal −x) at x = ``x_m``, met
    by 4 beams (elevations 0° and 10°, azimuths 0° and 10°); the default sensor with intensity."""
    return ('[scene]\nname = "plate"\n[ground]\nenabled = false\n[platform]\nkind = "static"\n'
            'position_m = [0.0, 0.0, 0.0]\nelevation_deg = [0.0, 10.0, 10.0]\nazimuth_deg = [0.0, 11.0, 10.0]\n'
            f"[sensor]\nintensity = true\n{sensor}"
            f'[[primitive]]\ntype = "box"\nmin_m = [{x_m}, -5.0, -5.0]\nmax_m = [{x_m + 0.05}, 5.0, 5.0]\n'
            f"reflectance = {rho}\n")


def _intensity_scale_of(las) -> float:
    text = las.header.vlrs.get_by_id("simlidar-mi", [2])[0].record_data.decode("ascii")
    return float(text.split("s = ")[1].split(" counts")[0])


def _check_plate(path):
    las = laspy.read(path)
    counts = np.asarray(las.intensity, np.float64)
    az, el = np.radians(np.asarray(las.azimuth_deg, np.float64)), np.radians(np.asarray(las.elevation_deg, np.float64))
    r, cos_i = np.asarray(las.range_m, np.float64), np.cos(el) * np.cos(az)
    s = _intensity_scale_of(las)
    energy = np.asarray(las.echo_energy, np.float64)
    np.testing.assert_allclose(counts / s, energy, rtol=0, atol=0.5 / s * 1.0001)  # E back from counts
    physical = cos_i / r ** 2  # one ρ for every point
    np.testing.assert_allclose((counts / s) / physical, (counts / s)[0] / physical[0], rtol=0.01)
    return las, counts, s


def test_a_plate_nearer_than_the_reference_range_does_not_clip(tmp_path):
    """ρ = 1 at 0.3 m with the default sensor (r_I = 0.5 m): the old fixed scale put 4 of 4
    points at 65535.  Now the strongest reads 65470 … 65535, the others follow cos i / r², and
    counts / s give E back (s stated in VLR record 2)."""
    run_scan(load_scene(text=_plate_scene(0.3)), tmp_path / "p", write_png=False)
    las, counts, s = _check_plate(tmp_path / "p" / "points.las")
    assert len(counts) == 4 and len(np.unique(counts)) == 3  # (0°, 10°) and (10°, 0°): one cos i
    assert 65470 <= counts.max() <= 65535 and np.count_nonzero(counts == 65535) <= 1
    assert s == las_fields.scan_intensity_scale(float(np.asarray(las.echo_energy).max()))


def test_a_weak_airborne_like_scan_uses_the_16_bits(tmp_path):
    """A dark (ρ = 0.1) plate 20 m away: the sensor's fixed scale gave it 4 counts (airborne
    scans 5-40); the scan's own scale puts its strongest echo near 65535 and keeps the ratios."""
    run_scan(load_scene(text=_plate_scene(20.0, rho=0.1)), tmp_path / "p", write_png=False)
    las, counts, s = _check_plate(tmp_path / "p" / "points.las")
    sensor = __import__("json").loads(las.header.vlrs.get_by_id("simlidar-mi", [3])[0].record_data)
    assert len(counts) == 4
    assert np.rint(sensor["intensity_scale"] * np.asarray(las.echo_energy, np.float64)).max() <= 5  # old counts
    assert counts.max() >= 65470 and counts.min() > 0.9 * 65535  # cos i / r²: within 10 % of each other


def test_streamed_and_held_intensities_agree(tmp_path):
    """The spill keeps energies and the running maximum; points.las is the held scan's, byte
    for byte, whatever the chunk size."""
    cfg = load_scene(text=_plate_scene(0.3) + "[scan]\nchunk_beams = 1\n")
    run_scan(cfg, tmp_path / "s", write_png=False)
    run_scan(load_scene(text=_plate_scene(0.3)), tmp_path / "h", write_png=False)
    assert (tmp_path / "s" / "points.las").read_bytes() == (tmp_path / "h" / "points.las").read_bytes()


@pytest.mark.parametrize("e_max", [1e-9, 3.3e-3, 0.8, 1.0, 17.0, 8.0e4, 6.5535e4 * 3])
def test_scan_intensity_scale_never_clips_and_fills_the_range(e_max):
    s = las_fields.scan_intensity_scale(e_max)
    top = int(las_fields.echo_intensity(np.array([e_max], np.float32), s)[0])
    assert 65535 * (1 - 1e-3) <= s * np.float32(e_max) <= 65535.5 and 65470 <= top <= 65535
    assert float(f"{s:.4g}") == s  # four significant digits: the VLR states it exactly


# --- Extra Bytes no_data ----------------------------------------------------------------------

def test_ids_declare_their_no_data_value(tmp_path):
    """branch_id and tree_id use 4294967295 for "none" and say so (LAS 1.4 R15 §4: option bit 0,
    no_data as an 8-byte unsigned): through laspy and through the descriptor's raw bytes."""
    res = _echo_result()
    path = write_scan_las(res, tmp_path / "e.las")
    las = laspy.read(path)
    ebs = {eb.name.rstrip(b"\0").decode() if isinstance(eb.name, bytes) else eb.name: eb for eb in las.header.vlrs.get("ExtraBytesVlr")[0].extra_bytes_structs}
    for name in ("branch_id", "tree_id"):
        assert ebs[name].options & ebs[name].NO_DATA_BIT_MASK and list(ebs[name].no_data) == [4294967295]
    assert not ebs["range_m"].options & 1  # fields without a "none" declare none
    data = path.read_bytes()
    problems: list = []
    (eb_vlr,) = [v for v in read_vlrs(data, read_header(data), problems)
                 if v["user_id"] == "LASF_Spec" and v["record_id"] == 4]
    raw = {}
    for at in range(0, len(eb_vlr["data"]), EB_DESCRIPTOR_SIZE):
        d = eb_vlr["data"][at:at + EB_DESCRIPTOR_SIZE]
        name = d[4:36].rstrip(b"\0").decode("ascii")
        raw[name] = (d[2], d[3], struct.unpack_from("<Q", d, 40)[0])  # data_type, options, no_data[0]
    assert raw["branch_id"] == raw["tree_id"] == (5, 1, 4294967295)  # uint32, bit 0, U64 no_data
    assert raw["scan_position"][1] & 1 == 0 and raw["scan_position"][2] == 0


# --- EXR integer channels in OpenImageIO --------------------------------------------------------

def test_openimageio_reads_counts_from_half_copies_and_ids_exactly(tmp_path):
    """OpenImageIO scales uint32 channels to 0 … 1 (id / (2³² − 1) as float32); ``n_returns``
    now has a half copy like ``class``; ids (too large for half floats) read exactly with the
    documented uint read (io/exr.py module docstring)."""
    import OpenEXR
    oiio = pytest.importorskip("OpenImageIO")
    res = _echo_result()
    res.element_id[0, :3] = [4294967295, 16777217, 4000000000]  # none, 2^24 + 1, > 2^31
    path = write_scan_exr(res, tmp_path / "e.exr", seed=3)
    with OpenEXR.File(str(path)) as f:
        ch = {k: np.array(v.pixels) for k, v in f.channels().items()}
    assert ch["n_returns_half"].dtype == np.float16 and np.array_equal(ch["n_returns_half"], ch["n_returns"])
    inp = oiio.ImageInput.open(str(path))
    names = list(inp.spec().channelnames)
    try:
        for name in ("n_returns", "branch_id", "tree_id", "echo2.branch_id", "echo2.tree_id"):
            c = names.index(name)
            exact = inp.read_image(0, 0, c, c + 1, "uint")
            assert exact.dtype == np.uint32 and np.array_equal(exact[..., 0], ch[name]), name
            default = inp.read_image(0, 0, c, c + 1, "float")[..., 0]  # what iinfo and viewers see
            np.testing.assert_allclose(default, ch[name] / 4294967295.0, rtol=1e-6)
        c = names.index("n_returns_half")
        assert np.array_equal(inp.read_image(0, 0, c, c + 1, "float")[..., 0], ch["n_returns"].astype(np.float32))
    finally:
        inp.close()
