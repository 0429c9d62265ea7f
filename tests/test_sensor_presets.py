"""Named sensors: every built-in preset validates and names a source for every value; presets
fill only what the scene leaves out; user preset files work and their errors name file, key
and value; `simlidar-mi sensors` lists them."""
from __future__ import annotations

import json
import math

import pytest

from simlidar_mi.cli import main
from simlidar_mi.config import load_scene, sensor_preset
from simlidar_mi.errors import ConfigError, SimlidarWarning
from simlidar_mi.config.presets import BUILTIN, UNCHECKED, format_preset, format_table

NAMES = ["sick-lms111", "sick-lms511", "velodyne-vlp16", "ouster-os1-64", "livox-mid70",
         "riegl-vz400i", "riegl-minivux1uav"]


def _scene(name: str, extra: str = "", **kw):
    return load_scene(text=f'[sensor]\npreset = "{name}"\n{extra}', **kw)


def test_the_seven_sensors_of_the_issue_are_built_in():
    assert set(NAMES) <= set(BUILTIN)


@pytest.mark.parametrize("name", NAMES)
def test_every_preset_validates_and_fills_its_values(name):
    cfg = _scene(name)
    p = BUILTIN[name]
    for sec in ("sensor", "platform", "scan"):
        for key, v in p.layer(sec).items():
            assert cfg[sec][key] == v.value, f"{sec}.{key}"
            assert cfg.from_preset[f"{sec}.{key}"] == f"sensor preset '{name}'"
            assert cfg.source_of(f"{sec}.{key}") == f"sensor preset '{name}'"
    assert cfg.source_of("scan.x0_m") == "<scene>"  # untouched keys stay the scene's


@pytest.mark.parametrize("name", NAMES)
def test_every_value_names_a_source_and_unchecked_ones_say_so(name):
    p = BUILTIN[name]
    text = format_preset(p)
    shown, section = {}, None  # dotted key -> its line in the text
    for ln in text.splitlines():
        if not ln.startswith(" "):
            section = ln[1:ln.index("]")] if ln.startswith("[") else ln.split()[0].rstrip(":")
        elif " = " in ln:
            shown[f"{section}.{ln.split(' = ')[0].strip()}"] = ln
    assert set(shown) == set(p.values())
    for dotted, v in p.values().items():
        assert p.sources.get(v.source, "").strip(), f"{name} {dotted}: no source"
        if v.source == "set":  # a setting of this preset says why
            assert v.note.strip(), f"{name} {dotted}: a setting without a reason"
        assert ("*" in shown[dotted].split("(")[0]) == (not v.checked), shown[dotted]
    assert (UNCHECKED in text) == any(not v.checked for v in p.values().values())


def test_datasheet_figures_and_what_the_presets_derive_from_them():
    lms511, vlp, os1 = BUILTIN["sick-lms511"], BUILTIN["velodyne-vlp16"], BUILTIN["ouster-os1-64"]
    assert lms511.sensor["divergence_mrad"].value == 11.9 and lms511.sensor["max_returns"].value == 5
    assert BUILTIN["sick-lms111"].sensor["divergence_mrad"].value == 15.0
    # tractor scanners: pulse rate = sweep rate × pulses per sweep
    for name, sweep_hz in (("sick-lms111", 25.0), ("sick-lms511", 25.0)):
        p = BUILTIN[name]
        assert p.sensor["pulse_rate_hz"].value * p.scan["dtheta_deg"].value / 360 == pytest.approx(sweep_hz)
    # VLP-16: ±15° every 2° in the interleaved firing order, 2.304 µs apart, 55.296 µs cycles
    ch = vlp.platform["channels_deg"].value
    assert sorted(ch) == list(range(-15, 16, 2)) and ch[:4] == [-15, 1, -13, 3]
    assert vlp.platform["channel_offsets_us"].value == pytest.approx([2.304 * i for i in range(16)])
    assert vlp.platform["block_period_us"].value == 55.296
    assert vlp.info["azimuth_step_deg"].value == pytest.approx(0.1991, abs=1e-4)
    assert vlp.sensor["divergence_mrad"].value == pytest.approx(math.sqrt(3.0 * 1.5), abs=1e-3)
    # OS1-64: 64 beams spanning ±16.6°; 0.13° FWHM → 1/e² full angle
    el = os1.platform["channels_deg"].value
    assert len(el) == 64 and el[0] == 16.6 and el[-1] == -16.6
    assert os1.sensor["divergence_mrad"].value == pytest.approx(2.2689 * 1.6986, abs=2e-3)
    assert 64 * 1e6 / os1.platform["block_period_us"].value == pytest.approx(1_310_720)
    mid = BUILTIN["livox-mid70"]
    assert mid.platform["fov_deg"].value == 70.4 and mid.platform["rosette_hz"].value == [7294.0, -4664.0]
    assert BUILTIN["riegl-vz400i"].sensor["divergence_mrad"].value == 0.35
    uav = BUILTIN["riegl-minivux1uav"].platform  # 100 lines/s, 0.36° steps as in the 360° line
    assert uav["pulse_rate_hz"].value / uav["pulses_per_line"].value == pytest.approx(100.0)
    assert uav["swath_deg"].value / uav["pulses_per_line"].value == pytest.approx(360 / 1000)


def test_scene_keys_and_set_overrides_win_over_the_preset():
    cfg = _scene("sick-lms511", "divergence_mrad = 3.0\n[scan]\ndtheta_deg = 0.5\n",
                 overrides=["sensor.max_returns=2"])
    assert cfg["sensor"]["divergence_mrad"] == 3.0 and "sensor.divergence_mrad" not in cfg.from_preset
    assert cfg["scan"]["dtheta_deg"] == 0.5 and "scan.dtheta_deg" not in cfg.from_preset
    assert cfg["sensor"]["max_returns"] == 2 and cfg.source_of("sensor.max_returns").startswith("--set")
    assert cfg["sensor"]["range_at_10pct_m"] == 40.0  # the rest still comes from the preset
    via_set = load_scene(text="", overrides=['sensor.preset="livox-mid70"'])
    assert via_set["platform"]["kind"] == "rosette" and via_set["sensor"]["max_returns"] == 2


def test_a_scene_without_a_preset_is_unchanged():
    cfg = load_scene(text="[scan]\ndtheta_deg = 0.5\n")
    assert cfg.from_preset == {} and cfg["sensor"]["divergence_mrad"] == 0.0
    assert cfg["platform"]["kind"] == "tractor" and cfg["scan"]["dtheta_deg"] == 0.5


def test_another_platform_kind_keeps_the_scene_platform_and_says_so():
    with pytest.warns(SimlidarWarning, match="platform.channels_deg"):
        cfg = _scene("velodyne-vlp16", '[platform]\nkind = "tractor"\n')
    assert cfg["platform"]["kind"] == "tractor" and not cfg.gave("platform.channels_deg")
    assert cfg["sensor"]["max_returns"] == 2  # the sensor's own keys still apply


def test_preset_errors_name_the_preset_when_a_later_check_fails():
    cfg = _scene("sick-lms511")
    exc = cfg.relabel(ConfigError("too wide", file=cfg.source, key="sensor.divergence_mrad", value=11.9))
    assert exc.file == "sensor preset 'sick-lms511'" and exc.key == "sensor.divergence_mrad"


# --- user preset files -------------------------------------------------------------------
PRESET = """\
[sensor]
divergence_mrad = 5.0
max_returns = 3
range_max_m = 30.0
[platform]
kind = "tractor"
[scan]
dtheta_deg = 0.5
[source]
default = "Our lab, beam profile measurement, 2026"
"sensor.max_returns" = "Maker X, manual rev. 2"
"""


def _user(tmp_path, preset_text: str, scene_extra: str = "", ref: str = "sensors/my.toml"):
    (tmp_path / "sensors").mkdir(exist_ok=True)
    (tmp_path / "sensors" / "my.toml").write_text(preset_text)
    scene = tmp_path / "scene.toml"
    scene.write_text(f'[sensor]\npreset = "{ref}"\n{scene_extra}')
    return scene


def test_a_user_preset_file_fills_keys_relative_to_the_scene(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path.parent)  # relative to the scene file, not the working folder
    scene = _user(tmp_path, PRESET, "range_max_m = 25.0\n")
    cfg = load_scene(scene)
    path = str(tmp_path / "sensors" / "my.toml")
    assert cfg["sensor"]["divergence_mrad"] == 5.0 and cfg["sensor"]["max_returns"] == 3
    assert cfg["scan"]["dtheta_deg"] == 0.5 and cfg.from_preset["scan.dtheta_deg"] == path
    assert cfg["sensor"]["range_max_m"] == 25.0  # the scene's key wins
    p = sensor_preset(path)
    assert p.sources[p.sensor["max_returns"].source] == "Maker X, manual rev. 2"
    assert p.sources[p.sensor["divergence_mrad"].source].startswith("Our lab")
    before = cfg.sha256  # the preset file is part of the scene's identity
    (tmp_path / "sensors" / "my.toml").write_text(PRESET.replace("5.0", "6.0"))
    assert load_scene(scene).sha256 != before


def test_a_user_preset_may_start_from_a_built_in(tmp_path):
    scene = _user(tmp_path, '[sensor]\npreset = "sick-lms511"\ndivergence_mrad = 4.6\n')
    cfg = load_scene(scene)
    assert cfg["sensor"]["divergence_mrad"] == 4.6 and cfg["sensor"]["max_returns"] == 5
    p = sensor_preset(tmp_path / "sensors" / "my.toml")
    assert "LMS5xx" in p.sources[p.sensor["max_returns"].source]
    assert p.sources[p.sensor["divergence_mrad"].source] == str(tmp_path / "sensors" / "my.toml")


@pytest.mark.parametrize(("text", "key", "value", "reason"), [
    ("[sensor]\ndivergence_mrad = -1.0\n", "sensor.divergence_mrad", -1.0, "≥ 0"),
    ("[sensor]\ndivergence = 2.0\n", "sensor.divergence", 2.0, "unknown key"),
    ("[platform]\nwaypoints_m = [[0, 0, 0], [1, 0, 0]]\n", "platform.waypoints_m", None, "scene geometry"),
    ("[scan]\nx0_m = 1.0\n", "scan.x0_m", 1.0, "unknown key"),
    ("[optics]\nx = 1\n", "optics", None, "unknown table"),
    ('[sensor]\nmax_returns = 2\n[source]\n"sensor.range_max_m" = "x"\n', "source.sensor.range_max_m",
     "x", "does not set"),
    ('[sensor]\npreset = "other.toml"\n', "sensor.preset", "other.toml", "built-in sensor only"),
    ('[sensor]\npreset = "sick-lms999"\n', "sensor.preset", "sick-lms999", "sick-lms511"),
    ("[sensor\n", None, None, "not valid TOML"),
])
def test_user_preset_errors_name_file_key_and_value(tmp_path, text, key, value, reason):
    scene = _user(tmp_path, text)
    with pytest.raises(ConfigError) as err:
        load_scene(scene)
    e = err.value
    assert e.file == str(tmp_path / "sensors" / "my.toml") and e.key == key and reason in str(e)
    if value is not None:
        assert e.value == value


def test_unknown_names_and_missing_files_blame_the_scene_key(tmp_path):
    scene = tmp_path / "s.toml"
    scene.write_text('[sensor]\npreset = "velodyne-vlp32"\n')
    with pytest.raises(ConfigError, match="built-in: sick-lms111, .*riegl-minivux1uav") as err:
        load_scene(scene)
    assert (err.value.file, err.value.key, err.value.value) == (str(scene), "sensor.preset", "velodyne-vlp32")
    scene.write_text('[sensor]\npreset = "none/here.toml"\n')
    with pytest.raises(ConfigError, match="no sensor preset file") as err:
        load_scene(scene)
    assert (err.value.file, err.value.key) == (str(scene), "sensor.preset")
    with pytest.raises(ConfigError) as err:
        load_scene(text="", overrides=['sensor.preset="nope"'])
    assert err.value.file == '--set sensor.preset="nope"'


# --- command line ------------------------------------------------------------------------
def test_cli_lists_every_preset_with_values_and_sources(capsys):
    assert main(["sensors"]) == 0
    out = capsys.readouterr().out
    for name in NAMES:
        assert sum(ln.startswith(name + " ") for ln in out.splitlines()) == 1  # its table row
        assert f"\n{name}: " in out  # its sources line
    assert "LMS5xx Operating Instructions 8013796/1ALS" in out and UNCHECKED in out
    assert out.strip() == format_table().strip()


def test_cli_shows_one_preset_and_json(capsys, tmp_path):
    assert main(["sensors", "velodyne-vlp16"]) == 0
    out = capsys.readouterr().out
    assert "block_period_us = 55.296" in out and "VLP-16 User Manual 63-9243" in out
    assert main(["sensors", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert [d["name"] for d in data] == list(BUILTIN) and len(data) >= 7
    assert data[1]["sensor"]["max_returns"]["value"] == 5
    (tmp_path / "p.toml").write_text(PRESET)
    assert main(["sensors", str(tmp_path / "p.toml"), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["scan"]["dtheta_deg"]["value"] == 0.5
    assert main(["sensors", "nope"]) == 2
    assert "unknown sensor preset; built-in: sick-lms111" in capsys.readouterr().err
