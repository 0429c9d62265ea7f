"""The physical scanner's chunks (issue #7; streamed in issue #8): divergent sub-rays traced,
their energies, echoes from the waveform, range noise, and each beam's first return.

:class:`PhysicalTracer` runs one chunk of at most ``chunk_beams`` beams (``[scan]
chunk_beams``) and ``chunk_rays`` sub-rays (at least one beam) at a time:

1. the beam's S sub-rays (divergence × dot matrix, :func:`~simlidar_mi.lidar.sensor.subray_offsets`)
   are traced by the range integrator (``trace_subrays``);
2. with energies (``model.needs_energy``), sub-ray j returns E_j = w_j·ρ_j·|cos i_j|·(R_ref/r_j)²
   (:func:`~simlidar_mi.lidar.waveform_fast.subray_energy`, the law of :mod:`~simlidar_mi.lidar.sensor`), the echoes come from
   :func:`~simlidar_mi.lidar.waveform.detect_echoes` (read from the trace's float32 arrays by
   :func:`~simlidar_mi.lidar.waveform_fast.detect_subray_echoes`, the same bits as
   :func:`~simlidar_mi.lidar.waveform_fast.reference_echoes`; under ``waveform_reader =
   "kernel"`` the beams whose sub-rays meet one surface are read by the Dr.Jit kernel of
   ``plugins/waveform_reader.py`` right after the trace and only the others on the host,
   :func:`~simlidar_mi.lidar.waveform_fast.kernel_echoes`) and range noise from :mod:`~simlidar_mi.lidar.noise`, keyed by
   (seed, leg, beam, return number); echo 1 gives the first-return arrays;
3. without (range limits alone, or divergence with ``detection = "nearest"``), a beam's first
   return is its nearest sub-ray inside [range_min_m, range_max_m] (under ``hit_rule =
   "any"`` its nearest vegetation sub-ray).

``hit_fraction`` is the profile-weighted share of the beam's sub-rays whose first hit is
vegetation.  The next chunk is traced (on Dr.Jit's threads) while the host reads this one.
"""
from __future__ import annotations

import time

import numpy as np

from ..geometry import CLASS_CODES
from .noise import apply_range_noise
from .sensor import SensorModel, subray_offsets
from .waveform import NO_ID
from .waveform_fast import detect_subray_echoes, kernel_echoes, reference_echoes, subray_energy  # noqa: F401


class PhysicalTracer:
    """A real scanner's scan of one pattern, traced on demand chunk by chunk: made by
    :func:`~simlidar_mi.lidar.scan.physical_tracer` (the Mitsuba sensor and integrator of
    the pattern), read whole by :func:`~simlidar_mi.lidar.scan.scan_physical` and streamed by
    :func:`~simlidar_mi.lidar.stream_sensor.stream_physical_scan`.  Every step is per beam
    or keyed by the global beam index, so a beam's values do not depend on its chunk."""

    def __init__(self, settings, pattern, lidar, integrator, scene, model, metadata: dict, *,
                 seed: int, leg: int, chunk_beams: int, chunk_rays: int, beam0: int = 0):
        self.settings, self.pattern, self._lidar = settings, pattern, lidar
        self._integrator, self._scene = integrator, scene
        self.energy = model.needs_energy
        self.model, self.seed, self.leg = model, int(seed), int(leg)
        self._offsets, w_sub = subray_offsets(model)
        n_dot = (pattern.footprint + 1) ** 2
        self.n_sub = n_dot * len(self._offsets)               # sub-rays per beam, laid out (q, j)
        self._weight = np.tile(w_sub, n_dot) / n_dot          # Σ = 1 per beam
        self.n_beams = pattern.n_rows * pattern.n_cols
        self.beam0 = int(beam0)                               # a tile's first beam in the whole scan
        self.per_chunk = max(1, min(int(chunk_beams), int(chunk_rays) // self.n_sub))
        # Single-surface beams read by the Dr.Jit kernel (plugins/waveform_reader.py) beside the trace
        self.kernel_reader = (self.energy and model.waveform_reader == "kernel"
                              and self.n_sub <= getattr(integrator, "read_max_subrays", 0))
        self.n_chunks = -(-self.n_beams // self.per_chunk)
        self.trace_s = self.echo_s = 0.0
        self.metadata = dict(metadata, sub_rays_per_beam=self.n_sub, seed=self.seed, leg=self.leg)

    def chunks(self):
        """Yield (first beam, beams, arrays) per chunk: flat ``range`` (float32, escape where a
        beam has no return), ``cls``, ``elem``, ``frac``, ``tree`` (None for one plant),
        ``n_ret``, ``inten`` (None unless intensity is on) and ``echoes`` (None without
        energies; beams are global flat indices)."""
        model, pattern, escape = self.model, self.pattern, self.pattern.escape_m
        n_sub = self.n_sub
        firsts = list(range(0, self.n_beams, self.per_chunk))

        def launch(b0):  # Dr.Jit runs the kernel on its threads; .numpy() waits for it
            # A tile's sensor starts up to a packet before the tile (lidar.packets).
            return self._integrator.trace_subrays(self._scene, self._lidar, self._offsets,
                                                  self.beam0 - self._lidar.first_beam + b0,
                                                  min(self.per_chunk, self.n_beams - b0), normals=self.energy)

        ahead = launch(firsts[0]) if firsts else None
        for i, b0 in enumerate(firsts):
            n = min(self.per_chunk, self.n_beams - b0)
            t1 = time.perf_counter()
            out = ahead
            # Views of the kernel's arrays (``out`` lives until the next chunk): read, never edited.
            # All taken before the next launch: .numpy() waits for every kernel queued.
            read = (self._integrator.read_waveforms(out, n_sub, self._weight, model)
                    if self.kernel_reader else None)
            host = {k: v.numpy().reshape(n, n_sub) for k, v in out.items()}
            read_h = None if read is None else {k: v.numpy() for k, v in read.items()}
            # The next chunk traces while the host reads this one (the same kernels, the same bits).
            ahead = launch(firsts[i + 1]) if i + 1 < len(firsts) else None
            self.trace_s += time.perf_counter() - t1
            t = host["t"]  # float32; the nearest-hit path reads float64
            c = host["class"].astype(np.uint8)
            e = host["element_id"]
            tr = host.get("tree_id")
            veg = (c == CLASS_CODES["wood"]) | (c == CLASS_CODES["leaf"])
            part = {"range": np.full(n, escape, np.float32), "cls": np.zeros(n, np.uint8),
                    "elem": np.full(n, NO_ID, np.uint32), "frac": (veg.astype(np.float64) @ self._weight).astype(np.float32),
                    "tree": None if tr is None else np.full(n, NO_ID, np.uint32),
                    "n_ret": np.zeros(n, np.uint8), "inten": None, "echoes": None}
            if self.energy:
                # float32, as traced: the detector reads float64 where it needs it
                cos_i, rho = host["cos_incidence"], host["reflectance"]
                t1 = time.perf_counter()
                g0 = self.beam0 + b0
                echoes = _echoes(model, t, c, e, tr, cos_i, rho, self._weight,
                                 np.arange(g0, g0 + n, dtype=np.int64), seed=self.seed, leg=self.leg,
                                 read=read_h)
                self.echo_s += time.perf_counter() - t1
                first = echoes.return_number == 1
                beams = echoes.beam[first] - g0
                part["range"][beams] = echoes.range_m[first]
                part["cls"][beams] = echoes.cls[first]
                part["elem"][beams] = echoes.element_id[first]
                if tr is not None and echoes.tree_id is not None:
                    part["tree"][beams] = echoes.tree_id[first]
                if model.intensity:
                    part["inten"] = np.zeros(n, np.float32)
                    part["inten"][beams] = echoes.energy[first]
                part["n_ret"][beams] = echoes.number_of_returns[first]
                part["echoes"] = echoes
            else:  # range limits alone: each beam's nearest sub-ray inside them
                t = t.astype(np.float64)
                inside = (t >= model.range_min_m) & (t <= model.range_max_m)
                r = np.where(inside, t, np.inf)
                if pattern.hit_rule == "any" and n_sub > 1:
                    r_veg = np.where(veg, r, np.inf)
                    r = np.where(np.isfinite(r_veg).any(axis=1, keepdims=True), r_veg, r)
                j = np.argmin(r, axis=1)
                at = np.arange(n)
                r1 = r[at, j]
                got = np.isfinite(r1)
                part["range"][:] = np.where(got, r1, escape)
                part["cls"][:] = np.where(got, c[at, j], CLASS_CODES["escape"])
                part["elem"][:] = np.where(got, e[at, j], NO_ID)
                if tr is not None:
                    part["tree"][:] = np.where(got, tr[at, j], NO_ID)
                part["n_ret"][:] = got
            yield b0, n, part


def _echoes(model: SensorModel, t, c, e, tr, cos_i, rho, weight, beam_index, *, seed: int, leg: int,
            read: dict | None = None):
    if read is not None:
        echoes = kernel_echoes(model, read, t, cos_i, rho, c, e, tr, weight, beam_index)
    else:
        echoes = detect_subray_echoes(model, t, cos_i, rho, c, e, tr, weight, beam_index)
    if model.noise:
        echoes = apply_range_noise(echoes, seed=seed, leg=leg, range_noise_m=model.range_noise_m,
                                   range_noise_per_m=model.range_noise_per_m, noise_model=model.noise_model,
                                   pulse_length_ns=model.pulse_length_ns,
                                   detection_threshold=model.detection_threshold,
                                   noise_ref_snr=model.noise_ref_snr, threshold_snr=model.threshold_snr)
    return echoes
