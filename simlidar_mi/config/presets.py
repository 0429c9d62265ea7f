"""Named sensors: the [sensor]/[platform]/[scan] keys a real scanner implies, with their sources.

A scene's ``[sensor] preset = "sick-lms511"`` (or a path to a user preset ``.toml``) fills the
keys the scene does not give, before validation (:func:`apply_preset`, called by
:func:`simlidar_mi.config.load_scene`); the scene's own keys and ``--set`` overrides win.
Every value names the public document it comes from; a value marked ``checked=False`` was
recalled from that document but not checked against it here, and says so wherever it is shown.

Single-number divergence: the model takes one full angle γ (1/e² of a Gaussian beam). Where a
datasheet gives two axes, the preset keeps both (``info``) and uses their geometric mean, the
circular beam with the same footprint area; where it gives a FWHM, γ = FWHM·√(2/ln 2).

This module is base-level (config.py imports it; it imports neither config nor lidar/): the
scene schema and the value check are passed in.
"""
from __future__ import annotations

import copy
import math
import stat
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

from .checks import decode_toml, parse_toml
from ..errors import ConfigError

# [platform] / [scan] keys a sensor implies; the rest (positions, paths, speeds) belong to the scene
PLATFORM_KEYS = ("kind", "channels_deg", "channel_offsets_us", "block_period_us", "rotation_hz",
                 "rosette_hz", "fov_deg", "elevation_deg", "azimuth_deg", "swath_deg",
                 "pulse_rate_hz", "pulses_per_line")
SCAN_KEYS = ("dtheta_deg",)
LAYERS = ("sensor", "platform", "scan")
#: A user preset file is a few dozen lines; anything larger is not one (checked before reading).
MAX_PRESET_BYTES = 1 << 20
UNCHECKED = "recalled, not checked against the datasheet"
FWHM_TO_E2 = math.sqrt(2.0 / math.log(2.0))  # Gaussian: 1/e² full width = FWHM × 1.699


@dataclass(frozen=True)
class Value:
    """One preset value, the id of the document it comes from and how it was read."""

    value: Any
    source: str
    note: str = ""
    checked: bool = True  # False: recalled from the source, not checked against it here

    def to_dict(self, sources: dict[str, str]) -> dict:
        return {"value": self.value, "source": sources.get(self.source, self.source),
                "note": self.note, "checked": self.checked}


@dataclass(frozen=True)
class SensorPreset:
    """A named sensor: the keys it fills per section, what they come from, and extra datasheet
    figures (``info``) the model does not take as keys (per-axis divergence, field of view)."""

    name: str
    title: str
    sources: dict[str, str]
    sensor: dict[str, Value]
    platform: dict[str, Value] = field(default_factory=dict)
    scan: dict[str, Value] = field(default_factory=dict)
    info: dict[str, Value] = field(default_factory=dict)
    note: str = ""
    label: str = ""  # how errors name it: "sensor preset 'x'" or the preset file

    @property
    def kind(self) -> str | None:
        v = self.platform.get("kind")
        return v.value if v else None

    def layer(self, section: str) -> dict[str, Value]:
        return {"sensor": self.sensor, "platform": self.platform, "scan": self.scan}[section]

    def values(self) -> dict[str, Value]:
        """Every value, by dotted key (info under ``info.``)."""
        return {f"{sec}.{k}": v for sec in (*LAYERS, "info")
                for k, v in (self.info if sec == "info" else self.layer(sec)).items()}

    def to_dict(self) -> dict:
        out = {"name": self.name, "title": self.title, "kind": self.kind, "note": self.note,
               "sources": dict(self.sources)}
        for sec in (*LAYERS, "info"):
            layer = self.info if sec == "info" else self.layer(sec)
            out[sec] = {k: v.to_dict(self.sources) for k, v in layer.items()}
        return out


def _geo_mean(a: float, b: float) -> float:
    return round(math.sqrt(a * b), 3)


# --- the built-in sensors -----------------------------------------------------------------
V = Value
_SICK_LMS1XX = "SICK AG, LMS1xx Laser Measurement Sensors, Operating Instructions 8012471/ZN27 (2017-06-09)"
_VLP16_UM = "Velodyne LiDAR, VLP-16 User Manual 63-9243 Rev. D (2018)"
_HELIOS_TLS = "HELIOS++ scanner definitions, data/scanners_tls.xml (3dgeo-heidelberg/helios)"
_HELIOS_ALS = "HELIOS++ scanner definitions, data/scanners_als.xml (3dgeo-heidelberg/helios)"
_SET = "setting chosen for this preset (within the datasheet's choices)"

_VLP16_ORDER = [-15, 1, -13, 3, -11, 5, -9, 7, -7, 9, -5, 11, -3, 13, -1, 15]
_OS1_BEAMS = 64

BUILTIN: dict[str, SensorPreset] = {p.name: p for p in (
    SensorPreset(
        "sick-lms111", "SICK LMS111 (2D, 270°)",
        {"oi": _SICK_LMS1XX, "ds": "SICK AG, LMS111-10100 product data sheet", "set": _SET},
        sensor={
            "divergence_mrad": V(15.0, "oi", "spot diameter = 8 mm + 15 mrad × range"),
            "max_returns": V(2, "ds", "2 echoes evaluated", False),
            "range_min_m": V(0.5, "ds", "", False),
            "range_max_m": V(20.0, "ds", "", False),
            "range_at_10pct_m": V(18.0, "ds", "range at 10 % remission", False),
            "range_noise_m": V(0.012, "ds", "statistical error ±12 mm taken as 1σ", False),
            "wavelength_nm": V(905.0, "ds", "", False),
            "pulse_rate_hz": V(36_000.0, "set", "25 Hz sweeps × 360°/0.25° (25/50 Hz, 0.25/0.5° in ds)"),
        },
        platform={"kind": V("tractor", "set", "a 2D profile scanner: the tractor platform")},
        scan={"dtheta_deg": V(0.25, "set", "finest step of the 25 Hz mode")},
        info={"aperture_deg": V(270.0, "ds", "", False),
              "scan_frequency_hz": V(25.0, "set", "sweeps per second (ds: 25 or 50 Hz)")}),
    SensorPreset(
        "sick-lms511", "SICK LMS511 PRO (2D, 190°, 5 echoes)",
        {"oi21": "SICK AG, LMS5xx Operating Instructions 8013796/1ALS (2021-03)",
         "oi17": "SICK AG, LMS5xx Laser Measurement Sensors, Operating Instructions 8013796/ZM63 (2017-05-09)",
         "oi10": "SICK AG, LMS500 Product Family, Operating Instructions 8013796/UL20 (2010-09-27)",
         "ds": "SICK AG, LMS511-10100 PRO product data sheet", "set": _SET},
        sensor={
            "divergence_mrad": V(11.9, "oi21", "standard-resolution (SR) spot: 370 mm at 30 m minus the "
                                 "13 mm spot at the front screen (oi10) = 357 mm / 30 m"),
            "max_returns": V(5, "oi17", "PRO / Heavy Duty evaluate up to 5 echoes (Lite: 2)"),
            "range_max_m": V(80.0, "ds", "", False),
            "range_at_10pct_m": V(40.0, "ds", "range at 10 % remission", False),
            "wavelength_nm": V(905.0, "ds", "", False),
            "pulse_rate_hz": V(54_000.0, "set", "25 Hz sweeps × 360°/(1/6)° (steps 1/6°…1°, "
                               "25…100 Hz in oi21)"),
        },
        platform={"kind": V("tractor", "set", "a 2D profile scanner: the tractor platform")},
        scan={"dtheta_deg": V(1 / 6, "oi21", "finest angle step (0.1667°), used at 25 Hz")},
        info={"divergence_hr_mrad": V(4.6, "oi10", "high-resolution (HR) variant: 0.0046 rad"),
              "aperture_deg": V(190.0, "ds", "", False),
              "scan_frequency_hz": V(25.0, "set", "sweeps per second (oi21: 25–100 Hz)")},
        note="range noise not entered: the data sheet's statistical error was not checked"),
    SensorPreset(
        "velodyne-vlp16", "Velodyne VLP-16 Puck (16 channels, spinning)",
        {"um": _VLP16_UM,
         "um_e": "Velodyne LiDAR, VLP-16 User Manual 63-9243 Rev. E (2019), appendix on the laser pulse",
         "vls": "Velodyne LiDAR, VLS-128 User Manual, Table F-1 'Beam Divergence'",
         "ds": "Velodyne LiDAR, VLP-16 (Puck) data sheet 63-9229", "helios": _HELIOS_TLS,
         "set": _SET},
        sensor={
            "divergence_mrad": V(_geo_mean(3.0, 1.5), "um_e", "geometric mean of 3.0 mrad horizontal × "
                                 "1.5 mrad vertical (the same pair is checked in 'vls' for the "
                                 "VLS-128; HELIOS++ uses 0.7 mrad)", False),
            "max_returns": V(2, "um", "dual return mode (strongest + last)"),
            "range_max_m": V(100.0, "helios", "rangeMax_m; data sheet 'up to 100 m'"),
            "range_at_10pct_m": V(100.0, "ds", "the data sheet's 100 m names no reflectance; taken "
                                  "as the 10 % range (an assumption)", False),
            "range_noise_m": V(0.03, "helios", "accuracy_m; data sheet ±3 cm typical, taken as 1σ"),
            "wavelength_nm": V(903.0, "helios", ""),
            "pulse_length_ns": V(4.0, "helios", "HELIOS++'s pulseLength_ns, not a Velodyne figure"),
        },
        platform={
            "kind": V("rotating", "set", "multi-channel spinning scanner"),
            "channels_deg": V(list(map(float, _VLP16_ORDER)), "um", "elevations of laser IDs 0–15, "
                              "in firing order"),
            "channel_offsets_us": V([round(2.304 * i, 3) for i in range(16)], "um",
                                    "one firing every 2.304 µs"),
            "block_period_us": V(55.296, "um", "16 firings + recharge = 55.296 µs per cycle"),
            "rotation_hz": V(10.0, "ds", "600 rpm (5–20 Hz selectable)", False),
        },
        info={"pulse_rate_hz": V(round(16 / 55.296e-6, 1), "um", "16 pulses per 55.296 µs, single return"),
              "divergence_horizontal_mrad": V(3.0, "um_e", "", False),
              "divergence_vertical_mrad": V(1.5, "um_e", "", False),
              "azimuth_step_deg": V(round(360 * 10 * 55.296e-6, 4), "um", "at 10 Hz: 360°·f·55.296 µs")},
        note="per-channel vertical offsets (mm) of the optics are not modelled"),
    SensorPreset(
        "ouster-os1-64", "Ouster OS1-64 (64 channels, spinning)",
        {"ds": "Ouster Inc., OS1 High Resolution Imaging Lidar data sheet (64/16-channel edition, "
               "vertical field 33.2°)",
         "hw": "Ouster, OS1 Hardware User Manual for Rev 7 sensors (2023-03)", "set": _SET},
        sensor={
            "divergence_mrad": V(round(math.radians(0.13) * 1e3 * FWHM_TO_E2, 3), "ds",
                                 "0.13° FWHM (64 channels) = 2.27 mrad, × √(2/ln 2) to the 1/e² full angle"),
            "beam_profile": V("gaussian", "ds", "the data sheet states the divergence as a FWHM"),
            "max_returns": V(1, "ds", "1 return (strongest)"),
            "range_min_m": V(0.8, "ds", ""),
            "range_max_m": V(120.0, "ds", "80 % Lambertian target, 100 klx"),
            "range_at_10pct_m": V(40.0, "ds", "10 % Lambertian target, 100 klx"),
            "range_noise_m": V(0.015, "ds", "repeatability ±1.5 cm above SNR 250 (±3 cm at SNR 100, "
                               "±10 cm at SNR 12; the 'snr' noise law gives 2.4 and 6.8 cm there)"),
            "noise_ref_snr": V(250.0, "ds", "the SNR from which the ±1.5 cm figure holds"),
            "wavelength_nm": V(850.0, "ds", "Rev 6/7 sensors: 865 nm band (hw)"),
        },
        platform={
            "kind": V("rotating", "set", "multi-channel spinning scanner"),
            "channels_deg": V([round(16.6 - 33.2 * i / (_OS1_BEAMS - 1), 4) for i in range(_OS1_BEAMS)],
                              "ds", "+16.6° … −16.6° evenly spaced (the sensor's own beam_altitude_angles "
                              "are close to, not exactly, even)"),
            "channel_offsets_us": V([0.0] * _OS1_BEAMS, "set", "all channels of a column fire "
                                    "together (per-beam azimuth offsets not modelled)"),
            "block_period_us": V(1e6 / (10 * 2048), "ds", "2048 columns × 10 Hz: 64 × 2048 × 10 = "
                                 "1 310 720 points/s as stated"),
            "rotation_hz": V(10.0, "ds", "10–20 Hz selectable"),
        },
        info={"vertical_fov_deg": V(33.2, "ds", "Rev 6/7 OS1-64: 45° (hw)", True),
              "divergence_fwhm_deg": V(0.13, "ds", ""),
              "points_per_s": V(1_310_720, "ds", "")},
        note="the newer Rev 6/7 OS1-64 has a 45° field and dual returns; this preset is the "
             "33.2° edition whose data sheet was checked"),
    SensorPreset(
        "livox-mid70", "Livox Mid-70 (rosette, 70.4°)",
        {"um": "Livox Tech, Livox Mid-70 User Manual v1.2 (2021-02)", "helios": _HELIOS_ALS,
         "set": _SET},
        sensor={
            "divergence_mrad": V(_geo_mean(4.887, 0.524), "helios", "geometric mean of 0.28° (4.887 mrad, "
                                 "vertical) × 0.03° (0.524 mrad, horizontal); the same pair is in um"),
            "max_returns": V(2, "um", "dual return mode"),
            "range_min_m": V(0.05, "um", "close-proximity blind zone", False),
            "range_max_m": V(260.0, "um", "80 % reflectivity", False),
            "range_at_10pct_m": V(90.0, "um", "10 % reflectivity", False),
            "range_noise_m": V(0.02, "helios", "accuracy_m; um: 2 cm (1σ at 20 m)"),
            "wavelength_nm": V(905.0, "helios", ""),
            "pulse_rate_hz": V(100_000.0, "helios", "pulseFreqs_Hz; um: 100 000 points/s, first or "
                               "strongest return"),
        },
        platform={
            "kind": V("rosette", "set", "two-prism (Risley) non-repetitive pattern"),
            "rosette_hz": V([7294.0, -4664.0], "helios", "rotorFreq1_Hz / rotorFreq2_Hz: HELIOS++'s "
                            "prism rates; Livox publishes none"),
            "fov_deg": V(70.4, "um", "circular field of view (HELIOS++: 35° half angle)", False),
        },
        info={"divergence_vertical_mrad": V(4.887, "helios", "0.28°"),
              "divergence_horizontal_mrad": V(0.524, "helios", "0.03°")}),
    SensorPreset(
        "riegl-vz400i", "RIEGL VZ-400i (terrestrial, waveform)",
        {"ds": "RIEGL Laser Measurement Systems, RIEGL VZ-400i data sheet (2019–2022 editions)",
         "set": _SET},
        sensor={
            "divergence_mrad": V(0.35, "ds", "", False),
            "max_returns": V(15, "set", "the data sheet says practically unlimited targets per pulse"),
            "range_min_m": V(0.5, "ds", "", False),
            "range_max_m": V(480.0, "ds", "ρ ≥ 90 % at 300 kHz", False),
            "range_at_10pct_m": V(177.0, "ds", "250 m at ρ ≥ 20 % and 300 kHz, scaled by √(10/20) "
                                  "with the model's ρ/r² law", False),
            "range_noise_m": V(0.003, "ds", "precision 3 mm (1σ)", False),
        },
        platform={
            "kind": V("static", "set", "a tripod scanner"),
            "elevation_deg": V([-40.0, 60.0, 0.1], "ds", "field +60°/−40°; the 0.1° step is a "
                               "setting (ds: 0.0024°–0.288°)", False),
            "azimuth_deg": V([0.0, 360.0, 0.1], "set", "full turn at 0.1° steps"),
        },
        info={"pulse_rate_hz": V(300_000.0, "ds", "setting among 100/300/600/1200 kHz", False),
              "accuracy_m": V(0.005, "ds", "", False)},
        note="wavelength not entered: the data sheet says near infrared only"),
    SensorPreset(
        "riegl-minivux1uav", "RIEGL miniVUX-1UAV (airborne, 360° line scanner)",
        {"ds": "RIEGL Laser Measurement Systems, RIEGL miniVUX-1UAV data sheet (2017–2020 editions)",
         "set": _SET},
        sensor={
            "divergence_mrad": V(_geo_mean(1.6, 0.5), "ds", "geometric mean of 1.6 × 0.5 mrad", False),
            "max_returns": V(5, "ds", "up to 5 targets per pulse", False),
            "range_min_m": V(3.0, "ds", "", False),
            "range_at_10pct_m": V(106.0, "ds", "150 m at ρ ≥ 20 %, scaled by √(10/20)", False),
            "range_noise_m": V(0.010, "ds", "precision 10 mm (1σ)", False),
            "wavelength_nm": V(905.0, "ds", "", False),
        },
        platform={
            "kind": V("airborne", "set", "a line scanner on a UAV"),
            "swath_deg": V(90.0, "set", "the downward ±45° of the 360° field"),
            "pulses_per_line": V(250, "set", "100 kHz / 100 lines/s = 1000 pulses per 360°, "
                                 "a quarter of them in the 90° swath"),
            "pulse_rate_hz": V(25_000.0, "set", "the pulses that fall in the swath: 100 kHz × 90/360"),
        },
        info={"pulse_rate_hz": V(100_000.0, "ds", "", False),
              "line_rate_hz": V(100.0, "ds", "scan speed 10–100 lines/s; 100 chosen", False),
              "divergence_axes_mrad": V([1.6, 0.5], "ds", "", False),
              "fov_deg": V(360.0, "ds", "", False)}),
)}
for _p in BUILTIN.values():
    object.__setattr__(_p, "label", f"sensor preset '{_p.name}'")


def names() -> list[str]:
    return list(BUILTIN)


def _is_path(ref: str) -> bool:
    return ref.lower().endswith(".toml") or "/" in ref or "\\" in ref


def builtin(name: str, *, file=None, key="sensor.preset") -> SensorPreset:
    """The built-in preset ``name``; an unknown one is refused with the list of names."""
    p = BUILTIN.get(name.strip().lower())
    if p is None:
        raise ConfigError(f"unknown sensor preset; built-in: {', '.join(BUILTIN)} "
                          "(or a path to a preset .toml file)", file=file, key=key, value=name)
    return p


def load_preset_file(path: str | Path, *, sections: dict, check: Callable) -> SensorPreset:
    """A user preset file: ``[sensor]``, ``[platform]``, ``[scan]`` and ``[source]`` tables.

    ``[source]`` holds ``default = "..."`` and/or ``"section.key" = "..."`` strings; keys
    without one are attributed to the file itself.  ``[sensor] preset`` may name a built-in
    sensor to start from.  ``sections``/``check`` are config's schema and value check."""
    path = Path(path)
    src = str(path)
    try:
        with open(path, "rb") as fh:  # at most the limit, however the file grew since its check
            raw = fh.read(MAX_PRESET_BYTES + 1)
        if len(raw) > MAX_PRESET_BYTES:
            raise ConfigError(f"a sensor preset file holds at most {MAX_PRESET_BYTES} bytes", file=src)
    except OSError as exc:
        raise ConfigError(f"cannot read sensor preset file: {exc.strerror or exc}", file=src) from exc
    text = decode_toml(raw, src, "sensor preset file")
    data = parse_toml(text, src)
    allowed = {"sensor": [k for k in sections["sensor"]], "platform": list(PLATFORM_KEYS),
               "scan": list(SCAN_KEYS)}
    for name, table in data.items():
        if name not in (*LAYERS, "source"):
            raise ConfigError("unknown table in a sensor preset; valid: [sensor], [platform], "
                              "[scan], [source]", file=src, key=name,
                              value=None if isinstance(table, dict) else table)
        if not isinstance(table, dict):
            raise ConfigError("expected a table", file=src, key=name, value=table)
    base = None
    if "preset" in data.get("sensor", {}):
        ref = data["sensor"]["preset"]
        if not isinstance(ref, str) or _is_path(ref):
            raise ConfigError("a preset file may start from a built-in sensor only, not another file",
                              file=src, key="sensor.preset", value=ref)
        base = builtin(ref, file=src)
    sources = data.get("source", {})
    default = sources.get("default", src)
    own: dict[str, dict[str, Value]] = {sec: {} for sec in LAYERS}
    for sec in LAYERS:
        for key, value in data.get(sec, {}).items():
            dotted = f"{sec}.{key}"
            if key == "preset" and sec == "sensor":
                continue
            if key not in allowed[sec] or key not in sections.get(sec, {}):
                what = ("valid: " + ", ".join(k for k in allowed[sec] if k in sections.get(sec, {})
                                               and k != "preset"))
                raise ConfigError(f"unknown key in a sensor preset's [{sec}] "
                                  f"(scene geometry stays in the scene); {what}",
                                  file=src, key=dotted, value=value)
            value = check(sections[sec][key], value, src, dotted)
            own[sec][key] = Value(value, dotted if dotted in sources else "default")
    set_keys = {f"{s}.{k}" for s in LAYERS for k in own[s]}
    for key, text_ in sources.items():
        if not isinstance(text_, str):
            raise ConfigError("a source must be a string naming the document", file=src,
                              key=f"source.{key}", value=text_)
        if key != "default" and key not in set_keys:
            raise ConfigError("names a key this preset does not set", file=src, key=f"source.{key}",
                              value=text_)
    texts = {"default": default, **{k: v for k, v in sources.items() if k != "default"}}
    layers = {sec: dict(own[sec]) for sec in LAYERS}
    if base is not None:
        texts.update({f"{base.name}:{k}": v for k, v in base.sources.items()})
        for sec in LAYERS:
            inherited = {k: Value(v.value, f"{base.name}:{v.source}", v.note, v.checked)
                         for k, v in base.layer(sec).items()}
            layers[sec] = {**inherited, **own[sec]}
    return SensorPreset(path.stem, f"preset file {path.name}" + (f" (from {base.name})" if base else ""),
                        texts, layers["sensor"], layers["platform"], layers["scan"],
                        dict(base.info) if base else {}, label=src)


def resolve(ref: str, *, base_dir: Path, sections: dict, check: Callable, file=None,
            key: str = "sensor.preset") -> SensorPreset:
    """A built-in name or a preset file path (relative paths from ``base_dir``)."""
    if not isinstance(ref, str) or not ref.strip():
        raise ConfigError("must be a built-in sensor name or a path to a preset .toml file",
                          file=file, key=key, value=ref)
    if not _is_path(ref):
        return builtin(ref, file=file, key=key)
    path = Path(ref).expanduser()
    path = path if path.is_absolute() else base_dir / path
    if path.suffix.lower() != ".toml":
        raise ConfigError("a sensor preset file must be a .toml file", file=file, key=key, value=ref)
    try:
        st = path.stat()
    except OSError:
        raise ConfigError(f"no sensor preset file at {path}", file=file, key=key, value=ref) from None
    if not stat.S_ISREG(st.st_mode):
        raise ConfigError(f"{path} is not a regular file", file=file, key=key, value=ref)
    if st.st_size > MAX_PRESET_BYTES:
        raise ConfigError(f"{path} holds {st.st_size} bytes; a sensor preset file holds at most "
                          f"{MAX_PRESET_BYTES} ({MAX_PRESET_BYTES >> 20} MiB)", file=file, key=key, value=ref)
    return load_preset_file(path, sections=sections, check=check)


def apply_preset(data: dict, source: str, *, origin: dict[str, str], base_dir: Path,
                 sections: dict, check: Callable) -> tuple[dict, dict[str, str], list[str]]:
    """Fill the keys a scene (``data``, flattened raw TOML with --set applied) does not give
    from its ``[sensor] preset``.

    Returns (new data, {dotted key: preset label} of the keys filled, dotted keys skipped).
    The preset's [platform] and [scan] keys apply only when the scene's [platform] kind is
    unset or the preset's own: a scene that mounts the sensor on another platform keeps it
    (the skipped keys are returned so the caller can say so).  ``origin`` maps dotted keys to
    the --set argument that gave them; a --set preset path is relative to the working folder."""
    sensor = data.get("sensor")
    if not isinstance(sensor, dict) or sensor.get("preset") is None:
        return data, {}, []
    where = origin.get("sensor.preset", source)
    folder = Path.cwd() if "sensor.preset" in origin else base_dir
    preset = resolve(sensor["preset"], base_dir=folder, sections=sections, check=check, file=where)
    out = copy.deepcopy(data)
    platform = out.get("platform") if isinstance(out.get("platform"), dict) else {}
    scene_kind = platform.get("kind")
    fits = scene_kind is None or preset.kind is None or scene_kind == preset.kind
    filled: dict[str, str] = {}
    skipped: list[str] = []
    for sec in LAYERS:
        for key, v in preset.layer(sec).items():
            table = out.setdefault(sec, {})
            if not isinstance(table, dict) or key in table:
                continue  # the scene's own key (or its bad table, reported by validation) wins
            if sec != "sensor" and not fits:
                skipped.append(f"{sec}.{key}")
                continue
            table[key] = copy.deepcopy(v.value)
            filled[f"{sec}.{key}"] = preset.label
    return out, filled, skipped


# --- text for `simlidar-mi sensors` -------------------------------------------------------
def _fmt(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:.6g}"
    if isinstance(v, list):
        return "[" + ", ".join(_fmt(x) for x in v) + "]"
    return str(v)


def _cell(p: SensorPreset, dotted: str) -> str:
    sec, key = dotted.split(".")
    v = (p.info if sec == "info" else p.layer(sec)).get(key)
    return "-" if v is None else _fmt(v.value) + ("" if v.checked else "*")


def format_table(presets: list[SensorPreset] | None = None) -> str:
    """One line per preset with its key values, then each preset's sources."""
    presets = list(BUILTIN.values()) if presets is None else presets
    cols = (("kind", "platform.kind"), ("div_mrad", "sensor.divergence_mrad"),
            ("returns", "sensor.max_returns"), ("R10%_m", "sensor.range_at_10pct_m"),
            ("max_m", "sensor.range_max_m"), ("noise_m", "sensor.range_noise_m"),
            ("nm", "sensor.wavelength_nm"))
    w = max(len(p.name) for p in presets)
    lines = [f"{'name':<{w}}  " + "  ".join(f"{h:>8}" for h, _ in cols) + "  sensor"]
    for p in presets:
        lines.append(f"{p.name:<{w}}  " + "  ".join(f"{_cell(p, k):>8}" for _, k in cols)
                     + f"  {p.title}")
    lines.append("")
    for p in presets:  # documents only: "set" marks this preset's own settings
        lines.append(f"{p.name}: " + "; ".join(t for s, t in p.sources.items() if s != "set"))
    lines.append(f"\n* {UNCHECKED}; `simlidar-mi sensors NAME` shows every value with its source")
    return "\n".join(lines)


def format_preset(p: SensorPreset) -> str:
    """Every value of one preset with its source id, note and check mark, then the sources."""
    lines = [f"{p.name}: {p.title}"]
    for sec in (*LAYERS, "info"):
        layer = p.info if sec == "info" else p.layer(sec)
        if not layer:
            continue
        lines.append(f"[{sec}]" if sec != "info" else "info (datasheet figures the model takes "
                     "through the keys above, or not at all)")
        for key, v in layer.items():
            mark = "" if v.checked else "*"
            lines.append(f"  {key} = {_fmt(v.value)}{mark}  ({v.source}{': ' + v.note if v.note else ''})")
    lines.append("sources:")
    lines += [f"  {sid}: {text}" for sid, text in p.sources.items()]
    if any(not v.checked for v in p.values().values()):
        lines.append(f"* {UNCHECKED}")
    if p.note:
        lines.append(f"note: {p.note}")
    return "\n".join(lines)
