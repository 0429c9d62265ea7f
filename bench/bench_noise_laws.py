"""Range-noise σ per echo under the two noise laws on the included noisy echo scenes.

One held scan per scene; σ of every echo under ``noise_model = "snr"`` (default) and
``"range"`` (the former law) from its noiseless range, energy, width and cos i, with the
scene's own ``range_noise_m``: percentiles per class.
Run: ``.venv/bin/python bench/bench_noise_laws.py``.
"""
from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _machine import machine  # noqa: E402

from simlidar_mi.geometry import CLASS_CODES  # noqa: E402
from simlidar_mi.lidar.noise import noise_sigma_m, snr_sigma_m  # noqa: E402
from simlidar_mi.lidar.survey import run_scan  # noqa: E402

SCENES = ("scenes/orchard_lms511.toml", "scenes/orchard_vlp16_tractor.toml",
          "scenes/forest_airborne_echoes.toml")


def main() -> None:
    print(machine())
    print("| scene | range_noise_m | class | echoes | snr σ p10/p50/p90 (mm) | range σ p10/p50/p90 (mm) |")
    print("|---|---:|---|---:|---|---|")
    for scene in SCENES:
        t = time.perf_counter()
        res = run_scan(scene, None, ["sensor.intensity=true"]).result
        s = res.sensor
        e = res.echoes
        sigma0 = s["range_noise_m"] or 0.01
        snr = snr_sigma_m(e.energy, e.width_ns, range_noise_m=sigma0, pulse_length_ns=s["pulse_length_ns"],
                          detection_threshold=s["detection_threshold"], noise_ref_snr=s["noise_ref_snr"],
                          threshold_snr=s["threshold_snr"])
        old = noise_sigma_m(e.range_m, e.cos_incidence, sigma0, 0.0)
        for name in ("ground", "wood", "leaf"):
            sel = e.cls == CLASS_CODES[name]
            if not sel.any():
                continue
            q = lambda x: "/".join(f"{1e3 * v:.1f}" for v in np.percentile(x[sel], [10, 50, 90]))  # noqa: E731
            print(f"| {Path(scene).stem} | {sigma0} | {name} | {int(sel.sum()):,} | {q(snr)} | {q(old)} |")
        print(f"<!-- {scene}: {time.perf_counter() - t:.0f} s -->")


if __name__ == "__main__":
    main()
