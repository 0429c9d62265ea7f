"""A real scanner's beam: divergence, echoes, intensity, range noise (``[sensor]``, ``[materials]``).

:func:`resolve_sensor` turns a scene's validated ``[sensor]`` and ``[materials]`` tables into a
:class:`SensorModel`, or None when the scene has no ``[sensor]`` section or turns every
effect off; then the scan takes the first-return path of SIMLIDAR and writes the same bytes
as before.

Divergence: each beam (and each sub-beam of the paper's dot matrix, ``scan.footprint``)
carries S divergent sub-rays laid on a Vogel (sunflower) spiral in the beam's angular
cross-section, all of weight 1/S; the profile enters through the radii (inverse CDF):

- uniform (a disc of full angle γ): a_j = (γ/2)·sqrt((j + ½)/S);
- gaussian (intensity ∝ exp(−2a²/w²), w = γ/2 the 1/e² half-angle):
  a_j = w·sqrt(−ln(1 − (j + ½)/S)/2);

azimuth φ_j = j·(golden angle), γ = divergence_mrad·1e-3 rad.  A sub-ray's direction is
d + tan(a_x)·u + tan(a_y)·v normalised, with (u, v) ⟂ d.  A beam with a dot matrix of
(P+1)² sub-beams fires (P+1)²·S rays, each of weight 1/((P+1)²·S).

Energy of sub-ray j (Lambertian target): E_j = w_j·ρ_j·|cos i_j|·(R_ref/r_j)², with
R_ref = range_at_10pct_m·sqrt(threshold/0.1), so a 10 % target at normal incidence that
fills the beam at ``range_at_10pct_m`` returns exactly the detection threshold.  E is a
share of the emitted pulse's energy after the 1/r² law; escapes return 0, the ground's
normal is +z.

Detection (``detection``): with divergence, a real receiver reports only what its waveform
shows above the threshold, so by default (``"waveform"``) every divergent scan computes the
energies and runs :func:`~simlidar_mi.lidar.waveform.detect_echoes`, even with
``max_returns = 1``: a twig met by 1 of 64 sub-rays returns nothing unless its echo reaches
the threshold.  ``"nearest"`` keeps the geometric reading (a beam returns its nearest sub-ray
hit, no energies, faster); BENCHMARKS.md §7 measures how far the two readings differ.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

GOLDEN_ANGLE_RAD = math.pi * (3.0 - math.sqrt(5.0))
AUTO_S_MIN, AUTO_S_MAX = 7, 256
AUTO_FEATURE_M = 0.01      # auto S without branches: a 1 cm feature
AUTO_FAR_RANGE_M = 30.0    # auto S without a scene to measure
#: Range whose full-beam 100 % normal-incidence echo reads LAS intensity 65535 when the sensor
#: gives no ``range_min_m`` (a typical scanner's blind zone); nearer echoes may then clip.
INTENSITY_RANGE_DEFAULT_M = 0.5


@dataclass(frozen=True)
class SensorModel:
    """The resolved ``[sensor]`` and ``[materials]`` values (see the module docstring)."""

    divergence_mrad: float = 0.0
    beam_profile: str = "gaussian"
    beam_samples: int = 1          # S, resolved (never 0 here)
    beam_samples_auto: bool = False
    max_returns: int = 1
    detection: str = "waveform"    # with divergence: "waveform" (thresholded echoes) or "nearest"
    pulse_length_ns: float = 3.0
    detection_threshold: float = 0.02
    range_min_m: float = 0.0
    range_max_m: float = math.inf
    range_noise_m: float = 0.0
    range_noise_per_m: float = 0.0
    echo_rule: str = "amplitude"   # waveform.detect_echoes: "amplitude" or "basin"
    waveform_reader: str = "kernel"  # single-surface beams read by the Dr.Jit kernel or numpy
    noise_model: str = "snr"       # noise.apply_range_noise: "snr" or "range"
    noise_ref_snr: float = 100.0
    threshold_snr: float = 10.0
    intensity: bool = False
    pulse_rate_hz: float = 0.0
    range_at_10pct_m: float = 40.0
    wavelength_nm: float | None = None
    preset: str | None = None
    reflectance_wood: float = 0.35
    reflectance_leaf: float = 0.45
    reflectance_ground: float = 0.20

    @property
    def r_ref_m(self) -> float:
        """R_ref of the energy law: a 10 % target filling the beam at normal incidence at
        ``range_at_10pct_m`` returns exactly the detection threshold."""
        return self.range_at_10pct_m * math.sqrt(self.detection_threshold / 0.1)

    @property
    def intensity_range_m(self) -> float:
        """r_I of the LAS intensity scale: ``range_min_m``, or :data:`INTENSITY_RANGE_DEFAULT_M`."""
        return self.range_min_m if self.range_min_m > 0 else INTENSITY_RANGE_DEFAULT_M

    @property
    def intensity_scale(self) -> float:
        """LAS intensity counts per unit of echo energy E: 65535·r_I²/R_ref², so the largest E
        inside the range limits, a 100 % Lambertian target at normal incidence filling the beam
        at r_I (E = (R_ref/r_I)²), reads 65535 and none clips (io/las.py)."""
        return 65535.0 * (self.intensity_range_m / self.r_ref_m) ** 2

    @property
    def noise(self) -> bool:
        return self.range_noise_m > 0 or self.range_noise_per_m > 0

    @property
    def needs_energy(self) -> bool:
        """Echo energies (and so |cos i| per sub-ray) are needed: echoes, intensity, noise
        (its σ follows the echo energy, or 1/|cos i| under the old law), or divergence read as a receiver does (``detection =
        "waveform"``: only echoes above the threshold return, even with one return).  With
        ``detection = "nearest"`` divergence alone reports the nearest sub-ray hit."""
        return (self.max_returns > 1 or self.intensity or self.noise
                or (self.divergence_mrad > 0 and self.detection == "waveform"))

    def effects_on(self) -> dict[str, bool]:
        """Which of the scanner's effects this model turns on."""
        return {
            "divergence": self.divergence_mrad > 0,
            "echoes": self.max_returns > 1,
            "intensity": self.intensity,
            "noise": self.noise,
            "range_limits": self.range_min_m > 0 or math.isfinite(self.range_max_m),
            "pulse_rate": self.pulse_rate_hz > 0,
        }

    def class_reflectance(self) -> np.ndarray:
        """ρ per class code (escape, ground, wood, leaf), float32."""
        return np.array([0.0, self.reflectance_ground, self.reflectance_wood, self.reflectance_leaf],
                        np.float32)

    def to_dict(self) -> dict:
        d = asdict(self)
        d["range_max_m"] = None if not math.isfinite(self.range_max_m) else self.range_max_m
        d["r_ref_m"] = self.r_ref_m
        d["intensity_range_m"] = self.intensity_range_m
        d["intensity_scale"] = self.intensity_scale
        d["effects"] = [k for k, v in self.effects_on().items() if v]
        return d


def auto_beam_samples(divergence_mrad: float, far_range_m: float | None = None,
                      feature_m: float | None = None) -> int:
    """S for ``beam_samples = 0``: enough sub-rays that their spacing at the scene's farthest
    range is below its typical feature (the median branch diameter).

    The footprint of full angle γ at range r is a disc of diameter D = γ·r; S rays over it
    are spaced sqrt(πD²/(4S)), so S = ceil(π/4·(γ·r/d)²), clamped to [7, 256] (7: the
    smallest Vogel layout with a centre and a ring; 256: the cost cap).  Defaults: r = 30 m,
    d = 1 cm."""
    if divergence_mrad <= 0:
        return 1
    r = AUTO_FAR_RANGE_M if far_range_m is None or not math.isfinite(far_range_m) else float(far_range_m)
    d = AUTO_FEATURE_M if feature_m is None or not feature_m > 0 else float(feature_m)
    s = math.ceil(math.pi / 4 * (divergence_mrad * 1e-3 * r / d) ** 2)
    return int(min(max(s, AUTO_S_MIN), AUTO_S_MAX))


def resolve_sensor(cfg, *, far_range_m: float | None = None,
                   feature_m: float | None = None) -> SensorModel | None:
    """The scene's scanner model, or None when it has no ``[sensor]`` section or every effect
    is off (then the old first-return path runs and writes the same bytes).  A pulse rate
    alone also gives None: it times the beam pattern, which both paths fire the same way.

    ``cfg`` is a :class:`~simlidar_mi.config.SceneConfig`; ``far_range_m`` and ``feature_m``
    feed :func:`auto_beam_samples` when ``beam_samples = 0``."""
    if not cfg.has("sensor"):
        return None
    s, m = cfg["sensor"], cfg["materials"]
    div = float(s["divergence_mrad"])
    auto = int(s["beam_samples"]) == 0
    if div <= 0:
        n_sub = 1
    elif auto:
        far = far_range_m
        if s["range_max_m"] is not None:
            far = min(far, s["range_max_m"]) if far is not None else s["range_max_m"]
        n_sub = auto_beam_samples(div, far, feature_m)
    else:
        n_sub = int(s["beam_samples"])
    model = SensorModel(
        divergence_mrad=div, beam_profile=s["beam_profile"], beam_samples=n_sub,
        beam_samples_auto=auto and div > 0, max_returns=int(s["max_returns"]),
        detection=s["detection"],
        pulse_length_ns=float(s["pulse_length_ns"]), detection_threshold=float(s["detection_threshold"]),
        range_min_m=float(s["range_min_m"]),
        range_max_m=math.inf if s["range_max_m"] is None else float(s["range_max_m"]),
        range_noise_m=float(s["range_noise_m"]), range_noise_per_m=float(s["range_noise_per_m"]),
        echo_rule=s["echo_rule"], waveform_reader=s["waveform_reader"], noise_model=s["noise_model"], noise_ref_snr=float(s["noise_ref_snr"]),
        threshold_snr=float(s["threshold_snr"]), intensity=bool(s["intensity"]), pulse_rate_hz=float(s["pulse_rate_hz"]),
        range_at_10pct_m=float(s["range_at_10pct_m"]), wavelength_nm=s["wavelength_nm"],
        preset=s["preset"], reflectance_wood=float(m["wood"]), reflectance_leaf=float(m["leaf"]),
        reflectance_ground=float(m["ground"]))
    # The pulse rate only times the pattern (lidar.platforms); alone it needs no sub-ray physics.
    physics = {k: v for k, v in model.effects_on().items() if k != "pulse_rate"}
    return model if any(physics.values()) else None


def subray_offsets(model: SensorModel) -> tuple[np.ndarray, np.ndarray]:
    """Angular offsets (S, 2) in radians (a_x, a_y in the beam's (u, v) frame) and weights
    (S,) summing to 1, on the Vogel spiral of the module docstring."""
    n = int(model.beam_samples) if model.divergence_mrad > 0 else 1
    if n <= 1 or model.divergence_mrad <= 0:
        return np.zeros((1, 2)), np.ones(1)
    gamma = model.divergence_mrad * 1e-3
    u = (np.arange(n) + 0.5) / n  # mid-quantiles of the radial CDF
    if model.beam_profile == "uniform":
        a = 0.5 * gamma * np.sqrt(u)
    else:
        a = 0.5 * gamma * np.sqrt(-np.log1p(-u) / 2.0)
    phi = np.arange(n) * GOLDEN_ANGLE_RAD
    return np.stack([a * np.cos(phi), a * np.sin(phi)], axis=1), np.full(n, 1.0 / n)


def gaussian_share(edge_offset_rad: float, divergence_mrad: float) -> float:
    """Share of a Gaussian beam's energy on the side x > −edge of a straight edge at angular
    offset ``edge_offset_rad`` from the axis: ½(1 + erf(√2·x/w)), w = γ/2 (closed form
    the tests compare sub-ray hit shares with)."""
    w = 0.5 * divergence_mrad * 1e-3
    return 0.5 * (1.0 + math.erf(math.sqrt(2.0) * edge_offset_rad / w))
