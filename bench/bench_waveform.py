"""Echo detection and range noise throughput on synthetic beams (issue 7, part A).

Each beam: ~40 % of its S sub-rays on a branch at 5–20 m (σ 2 cm of range spread), the
rest on ground 20–25 m away (σ 5 cm), 10 % escaping; τ = 3 ns, threshold 0.02, up to 5
returns.  Run: ``.venv/bin/python bench/bench_waveform.py``.
"""
from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _machine import machine  # noqa: E402

from simlidar_mi.lidar.noise import apply_range_noise  # noqa: E402
from simlidar_mi.lidar.waveform import detect_echoes  # noqa: E402


def main() -> None:
    print(machine())
    print("| beams | sub-rays/beam | detect s | beams/s | sub-rays/s | echoes/beam | noise echoes/s |")
    print("|---|---|---|---|---|---|---|")
    rng = np.random.default_rng(1)
    for b, s in ((100_000, 1), (100_000, 16), (20_000, 64)):
        branch = rng.random((b, s)) < 0.4
        r = np.where(branch, rng.uniform(5, 20, (b, 1)) + rng.normal(0, 0.02, (b, s)),
                     rng.uniform(20, 25, (b, 1)) + rng.normal(0, 0.05, (b, s)))
        r[rng.random((b, s)) < 0.1] = np.inf
        e = np.where(np.isfinite(r), 0.5 / s, 0.0)
        z = np.zeros((b, s))
        t = time.perf_counter()
        ech = detect_echoes(r, e, z.astype(np.uint8), z.astype(np.uint32), None, z, np.arange(b),
                            pulse_length_ns=3.0, detection_threshold=0.02, max_returns=5)
        dt = time.perf_counter() - t
        t = time.perf_counter()
        apply_range_noise(ech, seed=1, range_noise_m=0.01)
        dn = time.perf_counter() - t
        print(f"| {b:,} | {s} | {dt:.2f} | {b / dt:,.0f} | {b * s / dt:,.0f} | {len(ech) / b:.2f} | "
              f"{len(ech) / dn:,.0f} |")


if __name__ == "__main__":
    main()
