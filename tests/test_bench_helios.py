"""bench/bench_helios.py: the HELIOS++ inputs it writes reproduce our sweep pulse by pulse.

The export runs on a tiny orchard (one tree of 3 iterations, 3 sweeps).  The HELIOS pulses
are rebuilt from the written XML alone (survey legs, scanner settings, mount rotations)
with the script's model of HELIOS's mirror and platform stepping, and compared with the
beams our own scan settings fire.  Running HELIOS++ itself needs ``HELIOS=/path/helios++``
(and ``HELIOS_ASSETS`` = the folder holding its spectra/, if not found by default).
"""
from __future__ import annotations

import dataclasses
import importlib.util
import math
import os
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

import simlidar_mi as sm

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def bh():
    spec = importlib.util.spec_from_file_location("bench_helios", REPO / "bench" / "bench_helios.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules["bench_helios"] = mod
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="module")
def ex(bh, tmp_path_factory):
    return bh.export(tmp_path_factory.mktemp("helios"), trees=1, iterations=3, sweeps=3)


def _ref(value: str, out: Path) -> tuple[Path, str]:
    path, _, ident = value.partition("#")
    return Path(path), ident


def test_xml_is_well_formed_and_references_resolve(ex):
    names = ["scanner.xml", "platform.xml", "scene.xml", "survey_single.xml", "survey_fwf.xml"]
    for name in names:
        ET.parse(ex.out / name)  # raises on malformed XML
    for mode in ("single", "fwf"):
        survey = ET.parse(ex.surveys[mode]).getroot().find("survey")
        for key, tag in (("scene", "scene"), ("platform", "platform"), ("scanner", "scanner")):
            path, ident = _ref(survey.get(key), ex.out)
            assert path.is_file()
            assert [e for e in ET.parse(path).getroot().iter(tag) if e.get("id") == ident], (key, ident)
    parts = ET.parse(ex.out / "scene.xml").getroot().iter("param")
    objs = [Path(p.get("value")) for p in parts if p.get("key") == "filepath"]
    assert [p.name for p in objs] == ["wood.obj", "ground.obj"] and all(p.is_file() for p in objs)
    scanners = {s.get("id"): s for s in ET.parse(ex.out / "scanner.xml").getroot().iter("scanner")}
    assert scanners["tractor_fwf"].find("FWFSettings").get("beamSampleQuality") == "3"   # 1 + 6 + 12 rays
    assert scanners["tractor_single"].find("FWFSettings").get("beamSampleQuality") == "1"
    assert float(scanners["tractor_fwf"].get("beamDivergence_rad")) == pytest.approx(3e-4)
    assert float(scanners["tractor_fwf"].get("accuracy_m")) == 0.0


def _plan_from_xml(ex, mode: str):
    """The HELIOS survey's pulses, read from its XML only."""
    survey = ET.parse(ex.surveys[mode]).getroot().find("survey")
    legs = survey.findall("leg")
    p0, s0 = legs[0].find("platformSettings"), legs[0].find("scannerSettings")
    p1 = legs[1].find("platformSettings")
    assert s0.get("active") == "true" and legs[1].find("scannerSettings").get("active") == "false"
    rots = ET.parse(ex.out / "platform.xml").getroot().find("platform/scannerMount").findall("rot")
    assert [(r.get("axis"), float(r.get("angle_deg"))) for r in rots][0] == ("z", -90.0)
    rate, speed = float(s0.get("pulseFreq_hz")), float(p0.get("movePerSec_m"))
    y0, y1 = float(p0.get("y")), float(p1.get("y"))
    plan = {"scan_freq_hz": float(s0.get("scanFreq_hz")), "phi_deg": float(rots[1].get("angle_deg")),
            "vmin_deg": float(s0.get("verticalAngleMin_deg")), "vmax_deg": float(s0.get("verticalAngleMax_deg")),
            "y_start_m": y0, "n_steps": math.floor((y1 - y0) / (speed / rate)) + 1}
    sweep = dataclasses.replace(ex.sweep, x0_m=float(p0.get("x")), z0_m=float(p0.get("z")),
                                pulse_rate_hz=rate, speed_m_s=speed)
    return sweep, plan


@pytest.mark.parametrize("mode", ["single", "fwf"])
def test_helios_pulses_are_our_pulses(bh, ex, mode):
    sweep, plan = _plan_from_xml(ex, mode)
    ho, hd = bh.helios_pulses(sweep, plan)
    # Our side from our own scan settings: the scene with the very overrides of the runs.
    cfg = sm.load_scene(bh.SCENE, ex.overrides["size"] + ex.overrides["scan"])
    geo = sm.generate(cfg)
    st = sm.resolve_settings(cfg["scan"], cfg["ground"], *geo.bounds_m(), cfg.source, geo.near_x_m,
                             pulse_rate_hz=cfg["sensor"]["pulse_rate_hz"],
                             speed_m_s=cfg["platform"]["speed_m_s"], dy_given=True)
    pat = st.pattern()
    assert (st.n_positions, st.n_angles) == (3, 601)
    assert st.dy_m == pytest.approx(0.002, rel=1e-12)
    o = (pat.row_origin_m[:, None, :] + pat.col_time_s[None, :, None] * pat.velocity_m_s).reshape(-1, 3)
    d = np.broadcast_to(pat.col_dir[None], (st.n_positions, st.n_angles, 3)).reshape(-1, 3)
    assert len(o) == 3 * 601 and len(ho) == (3 + bh.EXTRA_SWEEPS) * 601   # extra sweeps are cut
    np.testing.assert_allclose(ho[:len(o)], o, rtol=0, atol=1e-9)
    np.testing.assert_allclose(hd[:len(o)], d, rtol=0, atol=1e-12)
    o2, d2 = ex.sweep.pulses()
    np.testing.assert_allclose(o2, o, rtol=0, atol=1e-12)
    np.testing.assert_allclose(d2, d, rtol=0, atol=1e-12)


def test_mirror_turn_is_one_sweep(bh):
    """HELIOS's mirror (step 2π·f/f_p, reset to −π at π) repeats every 360°/Δθ pulses, so
    the sweep rate is our f = f_p·Δθ/360°."""
    a = bh.mirror_angles(50.0, 72_000.0, 5 * 1440)
    assert a[719] == -math.pi and a[719 + 1440] == -math.pi and a[719 + 2880] == -math.pi
    np.testing.assert_array_equal(a[720:720 + 1440], a[720 + 1440:720 + 2880])
    np.testing.assert_allclose(np.diff(a[720:720 + 1439]), math.radians(0.25), rtol=1e-9)


def test_obj_holds_the_native_triangles(bh, ex):
    text = (ex.out / "wood.obj").read_text().split("\n")
    v = np.array([[float(x) for x in ln.split()[1:]] for ln in text if ln.startswith("v ")])
    f = np.array([[int(x) for x in ln.split()[1:]] for ln in text if ln.startswith("f ")]) - 1
    assert len(f) == ex.n_triangles and f.min() == 0 and f.max() == len(v) - 1
    cfg = sm.load_scene(bh.SCENE, ex.overrides["size"] + ex.overrides["scan"])
    v_native, f_native, origin = bh.wood_triangles(cfg, sm.generate(cfg))
    np.testing.assert_array_equal(v, v_native)        # 17 digits: the float64 bits come back
    np.testing.assert_array_equal(f, f_native)
    rel = v - origin
    assert np.array_equal(rel.astype(np.float32).astype(np.float64), rel)  # the f32 mesh, exactly
    toml = (ex.out / "scene_obj.toml").read_text()
    assert 'type = "obj"' in toml and "origin_m = [" in toml


@pytest.mark.skipif(not os.environ.get("HELIOS"), reason="needs HELIOS=/path/to/helios++")
def test_helios_fires_our_pulses(bh, ex):
    # its --assets folders (v2.0.2: the source tree, python/pyhelios and python/pyhelios/data), ':'-separated
    assets = [p for p in os.environ.get("HELIOS_ASSETS", "").split(os.pathsep) if p]
    res = bh.run_helios(ex, "single", os.environ["HELIOS"], pulse_log=True, assets=assets)
    chk = res["pulse_check"]
    assert chk["helios_pulses"] == chk["our_pulses"] == 3 * 601
    assert chk["max_origin_gap_m"] < 1e-3 and chk["max_direction_gap"] < 1e-3
    # from its scene cache (run_helios checks HELIOS's log says which): the same points
    cached = bh.run_helios(ex, "single", os.environ["HELIOS"], assets=assets, cached=True)
    assert {k: cached[k] for k in ("wood", "ground", "points")} == {k: res[k] for k in ("wood", "ground", "points")}
