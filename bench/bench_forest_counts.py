"""Requested against obtained tree counts per species, in both count modes, on the included forests.

    .venv/bin/python bench/bench_forest_counts.py [--seeds N]

For each scene: the stand of its own seed with ``count = "stand"`` (the default with the crown
rule) and ``count = "poisson"`` (the paper's reading), as a Markdown table; with ``--seeds N``
also the mean stand count of ``forest_small.toml`` over seeds 0..N-1 in the ``--seed-modes``
(default both; ``"stand"`` grows every candidate of that explicit forest, ~5× the time).
"""
from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

import numpy as np

from simlidar_mi.config import load_scene
from simlidar_mi.forest.params import forest_params_from_scene
from simlidar_mi.forest.stand import make_forest

SCENES = Path(__file__).resolve().parents[1] / "scenes"


def with_mode(params, mode):
    return dataclasses.replace(params, species=tuple(dataclasses.replace(s, count=mode)
                                                     for s in params.species))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=0)
    ap.add_argument("--seed-modes", default="stand,poisson")
    ap.add_argument("--scenes", nargs="*", default=["forest_small.toml", "forest_4species.toml"])
    a = ap.parse_args()
    print("| scene (seed) | count | species | requested ∫λ (trees/ha) | obtained (trees/ha) | candidates drawn (× λ) | reached | crown overlap | s |")
    print("|---|---|---|---|---|---|---|---|---|")
    for name in a.scenes:
        cfg = load_scene(SCENES / name)
        base = forest_params_from_scene(cfg)
        for mode in ("stand", "poisson"):
            t0 = time.perf_counter()
            f = make_forest(with_mode(base, mode), cfg.seed)
            dt = time.perf_counter() - t0
            s = f.summary()
            for sp in s["species"]:
                print(f"| {name} ({cfg.seed}) | {mode} | {sp['name']} | {sp['requested_count']:.1f} "
                      f"({sp['requested_density_per_ha']:.1f}) | {sp['count']} ({sp['density_per_ha']:.1f}) | "
                      f"{sp['candidates_drawn']} ({sp['candidate_factor']:.2f}) | "
                      f"{'yes' if sp['count_reached'] else 'no'} | {100 * s['crown_overlap_share']:.1f} % | {dt:.1f} |")
    if a.seeds:
        cfg = load_scene(SCENES / "forest_small.toml")
        base = forest_params_from_scene(cfg)
        for mode in a.seed_modes.split(","):
            c = np.array([make_forest(with_mode(base, mode), s).placement.count_after for s in range(a.seeds)])
            print(f"forest_small {mode}, seeds 0-{a.seeds - 1}: mean {np.round(c.mean(0), 2).tolist()} "
                  f"± SE {np.round(c.std(0, ddof=1) / np.sqrt(a.seeds), 2).tolist()}")


if __name__ == "__main__":
    main()
