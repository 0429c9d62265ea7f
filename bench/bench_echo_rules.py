"""Echo counts under the two waveform echo rules on the included echo scenes.

One scan per scene (held, nothing written): every chunk's sub-ray returns are read by
:func:`~simlidar_mi.lidar.waveform.detect_echoes` under both ``echo_rule`` values on the
same sub-rays, so the two columns differ only by the rule.  Per scene and rule: beams with
0 / 1 / 2 / 3+ echoes, and echoes per class (ground, wood, leaf) by return number 1 / 2 / 3+.
Run: ``.venv/bin/python bench/bench_echo_rules.py [--set KEY=VALUE ...] [SCENE ...]``.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _machine import machine  # noqa: E402

from simlidar_mi.geometry import CLASS_CODES  # noqa: E402
from simlidar_mi.lidar import physical  # noqa: E402
from simlidar_mi.lidar.survey import run_scan  # noqa: E402
from simlidar_mi.lidar.waveform import ECHO_RULES  # noqa: E402

SCENES = ("scenes/orchard_lms511.toml", "scenes/orchard_vlp16_tractor.toml",
          "scenes/forest_airborne_echoes.toml")
NAMES = {v: k for k, v in CLASS_CODES.items()}


def _tally(acc, ech, beams):
    n = np.bincount(np.searchsorted(beams, ech.beam), minlength=len(beams)) if len(ech) else np.zeros(len(beams), int)
    acc["beams"] += np.bincount(np.minimum(n, 3), minlength=4)
    for code in (1, 2, 3):
        sel = ech.cls == code
        acc[NAMES[code]] += np.bincount(np.minimum(ech.return_number[sel], 3), minlength=4)[1:]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("scenes", nargs="*", default=list(SCENES))
    ap.add_argument("--set", action="append", default=[])
    a = ap.parse_args()
    print(machine())
    original = physical.detect_echoes
    for scene in a.scenes:
        acc = {rule: {"beams": np.zeros(4, int), "ground": np.zeros(3, int), "wood": np.zeros(3, int),
                      "leaf": np.zeros(3, int)} for rule in ECHO_RULES}

        def both(*args, **kw):
            beams = np.unique(np.asarray(args[6], np.int64))
            out = {rule: original(*args, **{**kw, "echo_rule": rule}) for rule in ECHO_RULES}
            for rule, ech in out.items():
                _tally(acc[rule], ech, beams)
            return out[kw.get("echo_rule", "amplitude")]

        physical.detect_echoes = both
        t = time.perf_counter()
        try:
            run_scan(scene, None, a.set)
        finally:
            physical.detect_echoes = original
        print(f"\n{scene} {' '.join(a.set)} ({time.perf_counter() - t:.0f} s)")
        print("| rule | beams | 0 | 1 | 2 | 3+ | ground r1/r2/r3+ | wood r1/r2/r3+ | leaf r1/r2/r3+ |")
        print("|---|---:|---:|---:|---:|---:|---|---|---|")
        for rule in ECHO_RULES:
            c = acc[rule]
            tot = int(c["beams"].sum())
            cells = [f"{int(v):,} ({100 * v / tot:.2f} %)" for v in c["beams"]]
            cls = ["/".join(f"{int(v):,}" for v in c[k]) for k in ("ground", "wood", "leaf")]
            print(f"| {rule} | {tot:,} | " + " | ".join(cells) + " | " + " | ".join(cls) + " |")


if __name__ == "__main__":
    main()
