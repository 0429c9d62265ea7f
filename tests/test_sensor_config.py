"""[sensor], [materials] and [[primitive]] reflectance: defaults, impossible values refused with
file, key and value, and what resolve_sensor makes of them (None = the old first-return path)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from simlidar_mi.config import load_scene
from simlidar_mi.errors import ConfigError
from simlidar_mi.lidar.sensor import (AUTO_S_MAX, AUTO_S_MIN, auto_beam_samples, resolve_sensor,
                                      subray_offsets)

PLATE = '[[primitive]]\ntype = "box"\nmin_m = [5.0, 0.0, 0.0]\nmax_m = [5.01, 1.0, 2.0]\n'


def _scene(tmp_path, body: str):
    path = tmp_path / "scene.toml"
    path.write_text(body + PLATE)
    return path


@pytest.mark.parametrize("key, value, words", [
    ("sensor.divergence_mrad", "-1.0", "≥ 0"),
    ("sensor.max_returns", "0", "≥ 1"),
    ("sensor.detection_threshold", "0.0", "(0, 1)"),
    ("sensor.detection_threshold", "1.0", "(0, 1)"),
    ("sensor.detection_threshold", "-0.5", "(0, 1)"),
    ("sensor.pulse_length_ns", "0.0", "> 0"),
    ("sensor.beam_samples", "-3", "≥ 0"),
    ("sensor.beam_profile", '"tophat"', "gaussian"),
    ("sensor.range_noise_m", "-0.01", "≥ 0"),
    ("sensor.range_noise_per_m", "0.001", "noise_model = \"range\" only"),
    ("sensor.noise_model", '"sqrt"', "snr"),
    ("sensor.echo_rule", '"loudest"', "amplitude"),
    ("sensor.threshold_snr", "0.0", "> 0"),
    ("sensor.range_min_m", "-1.0", "≥ 0"),
    ("sensor.range_at_10pct_m", "0.0", "> 0"),
    ("sensor.intensity", "1", "true/false"),
    ("materials.wood", "1.5", "[0, 1]"),
    ("materials.leaf", "-0.1", "[0, 1]"),
    ("materials.ground", "nan", "finite"),
])
def test_impossible_sensor_values_name_file_key_value(tmp_path, key, value, words):
    section, leaf = key.split(".")
    path = _scene(tmp_path, f"[{section}]\n{leaf} = {value}\n")
    with pytest.raises(ConfigError) as exc:
        load_scene(path)
    assert exc.value.file == str(path) and exc.value.key == key
    assert words in str(exc.value)
    assert repr(exc.value.value) in str(exc.value)


@pytest.mark.parametrize("value", [-0.01, 1.01])
def test_primitive_reflectance_outside_unit_interval_is_refused(tmp_path, value):
    path = tmp_path / "scene.toml"
    path.write_text(PLATE + PLATE + f"reflectance = {value}\n")
    with pytest.raises(ConfigError) as exc:
        load_scene(path)
    assert exc.value.key == "primitive[1].reflectance" and exc.value.value == value
    assert exc.value.file == str(path) and "[0, 1]" in str(exc.value)


def test_unknown_sensor_key_is_refused(tmp_path):
    path = _scene(tmp_path, "[sensor]\ndivergence = 3.0\n")
    with pytest.raises(ConfigError, match="unknown key") as exc:
        load_scene(path)
    assert exc.value.key == "sensor.divergence"


def test_range_max_must_exceed_range_min(tmp_path):
    path = _scene(tmp_path, "[sensor]\nrange_min_m = 5.0\nrange_max_m = 5.0\n")
    with pytest.raises(ConfigError, match="range_min_m") as exc:
        load_scene(path)
    assert exc.value.key == "sensor.range_max_m" and exc.value.value == 5.0
    with pytest.raises(ConfigError) as exc:  # an override is blamed as the --set argument
        load_scene(_scene(tmp_path, "[sensor]\nrange_min_m = 5.0\n"), ["sensor.range_max_m=2.0"])
    assert exc.value.file == "--set sensor.range_max_m=2.0"


def test_preset_is_accepted_as_a_string(tmp_path):
    cfg = load_scene(_scene(tmp_path, '[sensor]\npreset = "sick-lms511"\ndivergence_mrad = 11.9\n'))
    assert cfg["sensor"]["preset"] == "sick-lms511"
    with pytest.raises(ConfigError) as exc:
        load_scene(_scene(tmp_path, "[sensor]\npreset = 3\n"))
    assert exc.value.key == "sensor.preset"


def test_no_sensor_section_or_every_effect_off_resolves_to_none(tmp_path):
    assert resolve_sensor(load_scene(_scene(tmp_path, ""))) is None
    # Defaults, materials and a beam profile change nothing: still the old path.
    off = "[sensor]\nbeam_profile = \"uniform\"\nmax_returns = 1\npulse_length_ns = 5.0\n[materials]\nwood = 0.9\n"
    assert resolve_sensor(load_scene(_scene(tmp_path, off))) is None
    assert resolve_sensor(load_scene(_scene(tmp_path, "[materials]\nwood = 0.5\n"))) is None
    # A pulse rate alone times the pattern (lidar.platforms); the beams are the old ones.
    assert resolve_sensor(load_scene(_scene(tmp_path, "[sensor]\npulse_rate_hz = 10000.0\n"))) is None


@pytest.mark.parametrize("body, effect", [
    ("divergence_mrad = 2.0", "divergence"), ("max_returns = 3", "echoes"),
    ("intensity = true", "intensity"), ("range_noise_m = 0.01", "noise"),
    ('range_noise_per_m = 0.001\nnoise_model = "range"', "noise"), ("range_max_m = 80.0", "range_limits"),
    ("range_min_m = 0.5", "range_limits"),
])
def test_each_effect_alone_gives_a_model(tmp_path, body, effect):
    model = resolve_sensor(load_scene(_scene(tmp_path, f"[sensor]\n{body}\n")))
    assert model is not None
    assert [k for k, v in model.effects_on().items() if v] == [effect]
    assert model.to_dict()["effects"] == [effect]


def test_materials_and_r_ref(tmp_path):
    model = resolve_sensor(load_scene(_scene(tmp_path, "[sensor]\nintensity = true\nrange_at_10pct_m = 50.0\n"
                                                       "detection_threshold = 0.1\n[materials]\nleaf = 0.6\n")))
    assert model.class_reflectance().tolist() == pytest.approx([0.0, 0.20, 0.35, 0.6])
    assert model.r_ref_m == pytest.approx(50.0)  # threshold 0.1: R_ref is the datasheet range
    model = resolve_sensor(load_scene(_scene(tmp_path, "[sensor]\nintensity = true\n")))
    assert model.r_ref_m == pytest.approx(40.0 * math.sqrt(0.2))


def test_auto_beam_samples_rule():
    # π/4·(γ r / d)²: 10 mrad at 10 m over 1 cm branches = π/4·100 → 79
    assert auto_beam_samples(10.0, 10.0, 0.01) == math.ceil(math.pi / 4 * 100)
    assert auto_beam_samples(0.1, 1.0, 0.05) == AUTO_S_MIN
    assert auto_beam_samples(50.0, 100.0, 0.001) == AUTO_S_MAX
    assert auto_beam_samples(0.0, 10.0, 0.01) == 1


def test_subray_layout_matches_the_profile_quantiles():
    from simlidar_mi.lidar.sensor import SensorModel
    S, gamma = 4096, 8e-3
    off, w = subray_offsets(SensorModel(divergence_mrad=8.0, beam_samples=S, beam_profile="uniform"))
    a = np.hypot(off[:, 0], off[:, 1])
    assert w.sum() == pytest.approx(1.0) and off.shape == (S, 2)
    assert a.max() < gamma / 2 and np.mean(a ** 2) == pytest.approx((gamma / 2) ** 2 / 2, rel=1e-3)
    off, w = subray_offsets(SensorModel(divergence_mrad=8.0, beam_samples=S))
    a = np.hypot(off[:, 0], off[:, 1])
    # Gaussian I ∝ exp(−2a²/w²): E[a²] = w²/2 and 1 − 1/e² of the energy within a < w = γ/2.
    assert np.mean(a ** 2) == pytest.approx((gamma / 2) ** 2 / 2, rel=2e-2)
    assert np.mean(a < gamma / 2) == pytest.approx(1 - math.exp(-2), abs=1 / S)
    # Centroid on the axis (the golden-angle spiral balances), to a fraction of the spacing.
    assert np.abs(off.mean(axis=0)).max() < 0.01 * gamma


def test_detection_reading_is_validated_and_sets_whether_energies_are_computed(tmp_path):
    path = _scene(tmp_path, '[sensor]\ndivergence_mrad = 3.0\ndetection = "first"\n')
    with pytest.raises(ConfigError) as exc:
        load_scene(path)
    assert exc.value.key == "sensor.detection" and exc.value.value == "first"
    assert "waveform" in str(exc.value) and "nearest" in str(exc.value)
    wave = resolve_sensor(load_scene(_scene(tmp_path, "[sensor]\ndivergence_mrad = 3.0\n")))
    assert wave.detection == "waveform" and wave.needs_energy and wave.max_returns == 1
    assert wave.to_dict()["detection"] == "waveform"
    near = resolve_sensor(load_scene(_scene(tmp_path, '[sensor]\ndivergence_mrad = 3.0\ndetection = "nearest"\n')))
    assert near.detection == "nearest" and not near.needs_energy
    # without divergence the reading changes nothing: one thin ray, no energies unless asked
    limits = resolve_sensor(load_scene(_scene(tmp_path, "[sensor]\nrange_max_m = 50.0\n")))
    assert not limits.needs_energy
