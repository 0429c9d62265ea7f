"""Range noise from a counter-based normal stream: the same draw for the same echo, always.

Echo (leg, beam, return number) of a scan with seed s gets range += σ·z, z a standard
normal that depends only on (s, leg, beam, return number): the four are hashed with
SplitMix64 into one 64-bit word, which gives two uniforms (53 bits each) and Box–Muller
gives z.  No generator state is carried from one beam to the next, so the result does not
depend on chunk sizes, beam order, threads or worker count.  Ranges are not clipped (a
σ of centimetres never takes a range gated at ``range_min_m`` below 0 in practice).

σ follows one of two laws (``[sensor] noise_model``):

``"snr"`` (default): time-of-flight precision ∝ pulse width / √SNR (Baltsavias 1999,
"Airborne laser scanning: basic relations and formulas", ISPRS J. Photogramm. Remote Sens.
54:199–214, the range-accuracy relation; the OS1 data sheet's repeatability falls with SNR
the same way).  With the echo's SNR proportional to its energy E (shot/background-noise
limited receiver) and anchored at the detection threshold,

    SNR = threshold_snr · E / detection_threshold,
    σ   = range_noise_m · (w / τ) · sqrt(max(noise_ref_snr / SNR, 1)),

w the echo's waveform width (ns) and τ the pulse length: range and reflectance act through
E ∝ ρ·|cos i|/r², incidence also through w (a grazing target smears the echo in range), and
nothing else.  ``range_noise_m`` is the data sheet's precision, reached at ``noise_ref_snr``
and kept above it (a floor: timing jitter and digitisation do not improve with signal, and
data sheets quote their best case; the OS1's reads "±1.5 cm above SNR 250").  Anchors: Ouster
OS1-64 ±1.5 cm from SNR 250 (its data sheet, which also gives ±3 cm at SNR 100 and ±10 cm at
SNR 12, where this law gives 2.4 cm and 6.8 cm: the sheet falls faster than 1/√SNR).  Other
presets' data sheets give a precision without an SNR: it is taken as the floor from the
default reference SNR 100, and every preset's threshold SNR is the default 10 (both
assumptions, stated in docs/guide/sensors.md).

``"range"`` (the former law, no data-sheet basis for its incidence term):

    σ = (range_noise_m + range_noise_per_m · max(r − 1 m, 0)) / max(|cos i|, 0.1)
"""
from __future__ import annotations

import dataclasses

import numpy as np

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)
_MASK64 = (1 << 64) - 1


def _splitmix64(x: np.ndarray) -> np.ndarray:
    """SplitMix64's output function (Steele et al. 2014): a bijection of uint64 that mixes
    every input bit into every output bit (arithmetic wraps modulo 2⁶⁴)."""
    z = x + _GOLDEN
    z = (z ^ (z >> np.uint64(30))) * _M1
    z = (z ^ (z >> np.uint64(27))) * _M2
    return z ^ (z >> np.uint64(31))


def _u64(value) -> np.ndarray:
    """Any integer (array) as uint64, negative values wrapped modulo 2⁶⁴."""
    if isinstance(value, (int, np.integer)):
        return np.uint64(int(value) & _MASK64)
    a = np.asarray(value)
    if a.dtype.kind == "u":
        return a.astype(np.uint64)
    if a.dtype.kind == "i":
        return a.astype(np.int64).view(np.uint64)
    raise TypeError(f"expected integers, got {a.dtype}")


def normal_stream(seed: int, leg: int, beam, return_number) -> np.ndarray:
    """Standard normal z (float64) for each (beam, return_number) of ``leg`` under ``seed``.

    ``beam`` and ``return_number`` broadcast together; the same four keys always give the
    same z, whatever else is drawn."""
    beam_u, ret_u = np.broadcast_arrays(_u64(beam), _u64(return_number))
    with np.errstate(over="ignore"):
        key = _splitmix64(_splitmix64(_u64(seed)) ^ _u64(leg))
        h = _splitmix64(_splitmix64(key ^ beam_u) ^ ret_u)
        a = _splitmix64(h)
        b = _splitmix64(a)
    u1 = ((a >> np.uint64(11)).astype(np.float64) + 0.5) * 2.0**-53  # (0, 1): log is finite
    u2 = (b >> np.uint64(11)).astype(np.float64) * 2.0**-53
    return np.sqrt(-2.0 * np.log(u1)) * np.cos(2.0 * np.pi * u2)


def noise_sigma_m(range_m, cos_incidence, range_noise_m: float, range_noise_per_m: float) -> np.ndarray:
    """σ (m) of the range error of echoes at ``range_m`` with ``cos_incidence`` (the
    ``"range"`` law, module docstring)."""
    r = np.asarray(range_m, np.float64)
    cos = np.maximum(np.abs(np.asarray(cos_incidence, np.float64)), 0.1)
    return (range_noise_m + range_noise_per_m * np.maximum(r - 1.0, 0.0)) / cos


def snr_sigma_m(energy, width_ns, *, range_noise_m: float, pulse_length_ns: float,
                detection_threshold: float, noise_ref_snr: float, threshold_snr: float) -> np.ndarray:
    """σ (m) of echoes of ``energy`` and waveform ``width_ns`` under the ``"snr"`` law
    (module docstring)."""
    e = np.asarray(energy, np.float64)
    snr = threshold_snr * e / detection_threshold
    with np.errstate(divide="ignore"):
        ratio = np.where(snr > 0, noise_ref_snr / snr, np.inf)
    return range_noise_m * (np.asarray(width_ns, np.float64) / pulse_length_ns) * np.sqrt(np.maximum(ratio, 1.0))


NOISE_MODELS = ("snr", "range")


def apply_range_noise(echoes, *, seed: int, leg: int = 0, range_noise_m: float = 0.0,
                      range_noise_per_m: float = 0.0, noise_model: str = "range",
                      pulse_length_ns: float | None = None, detection_threshold: float | None = None,
                      noise_ref_snr: float = 100.0, threshold_snr: float = 10.0):
    """``echoes`` (a :class:`~simlidar_mi.lidar.waveform.Echoes`) with noisy ranges.

    Returns the same object when both noise terms are 0, else a copy with ``range_m``
    replaced.  ``noise_model`` ``"range"``: σ from the noiseless range and the echo's cos
    incidence; ``"snr"``: σ from its energy and width (needs ``pulse_length_ns`` and
    ``detection_threshold``; ``range_noise_per_m`` must be 0)."""
    if range_noise_m < 0 or range_noise_per_m < 0:
        raise ValueError(f"range noise must be ≥ 0, got {range_noise_m}, {range_noise_per_m}")
    if noise_model not in NOISE_MODELS:
        raise ValueError(f"noise_model must be one of {NOISE_MODELS}, got {noise_model!r}")
    if range_noise_m == 0 and range_noise_per_m == 0:
        return echoes
    if noise_model == "snr":
        if range_noise_per_m:
            raise ValueError("range_noise_per_m applies to the 'range' noise law only")
        if not (pulse_length_ns and pulse_length_ns > 0 and detection_threshold and detection_threshold > 0):
            raise ValueError("the 'snr' noise law needs pulse_length_ns and detection_threshold > 0")
        sigma = snr_sigma_m(echoes.energy, echoes.width_ns, range_noise_m=range_noise_m,
                            pulse_length_ns=pulse_length_ns, detection_threshold=detection_threshold,
                            noise_ref_snr=noise_ref_snr, threshold_snr=threshold_snr)
    else:
        sigma = noise_sigma_m(echoes.range_m, echoes.cos_incidence, range_noise_m, range_noise_per_m)
    z = normal_stream(seed, leg, echoes.beam, echoes.return_number)
    return dataclasses.replace(echoes, range_m=np.asarray(echoes.range_m, np.float64) + sigma * z)
