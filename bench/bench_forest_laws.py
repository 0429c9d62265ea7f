"""The forests page's tables of the random-tree laws and the crown rule, with the current presets.

    .venv/bin/python bench/bench_forest_laws.py [--parts branching,means,crown] [--trees 200]

``branching``: L1 drawn per tree against per branch (``lateral_branching_per``), ``--trees``
trees a preset (seeds 0…n−1): branches, crown radius, leaf-centroid height over tree height and
the share of branching decisions made with the flag true, mean ± SD between trees.
``means``: the per-tree means on (the presets' ``*_tree_cv``) and off (0), ``--trees // 2``
trees a preset: the between-tree SD of a tree's mean leaf length, leaves and branches a tree.
``crown``: the crown rule's ``crown_factor`` swept on ``scenes/forest_4species.toml`` (its seed,
its count): trees, trees a species, the share with a neighbour's trunk inside their crown.
Each part prints a Markdown table; trees are grown one species at a time and dropped.
"""
from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import numpy as np

from simlidar_mi.config import load_scene
from simlidar_mi.forest.params import forest_params_from_scene
from simlidar_mi.forest.stand import make_forest
from simlidar_mi.plants.random_tree import iter_random_trees
from simlidar_mi.plants.tree_params import SPECIES_PRESETS, TREE_CV

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "bench"))
from _machine import machine  # noqa: E402


def _ms(x, fmt):
    x = np.asarray(x, float)
    return f"{x.mean():{fmt}} ± {x.std(ddof=1):{fmt}}"


def branching(n: int) -> None:
    print("| preset (flag p) | reading | branches | crown radius m | leaf-centroid height / tree height "
          "| share of daughters off their mother's apex |\n|---|---|---|---|---|---|")
    for name, P in SPECIES_PRESETS.items():
        for per in ("tree", "branch"):
            Q = dataclasses.replace(P, lateral_branching_per=per)
            nb, cr, lc, fl = [], [], [], []
            for t in iter_random_trees(Q, range(n)):
                nb.append(len(t.branches))
                cr.append(t.crown_radius_m)
                lc.append(float(t.leaf_table.centre_m[:, 2].mean()) / t.height_m)
                fl.append(t.branching)
            head = f"{name} ({P.lateral_branching.p:g})" if per == "tree" else ""
            print(f"| {head} | per {per} | {_ms(nb, '.0f')} | {_ms(cr, '.2f')} | {_ms(lc, '.3f')} | "
                  f"{_ms(fl, '.2f')} |", flush=True)


def means(n: int) -> None:
    print("| preset | per-tree means | between-tree SD of mean leaf length (mm) | leaves per tree "
          "| branches per tree |\n|---|---|---|---|---|")
    for name, P in SPECIES_PRESETS.items():
        for on in (True, False):
            Q = P if on else dataclasses.replace(P, **{k: 0.0 for k in TREE_CV})
            ll, nl, nb = [], [], []
            for t in iter_random_trees(Q, range(n)):
                ll.append(1e3 * float(t.leaf_table.length_m.mean()))
                nl.append(t.n_leaves)
                nb.append(len(t.branches))
            cv = " / ".join(f"{getattr(P, k):.2f}" for k in TREE_CV)
            print(f"| {name if on else ''} | {f'on ({cv})' if on else 'off (0)'} | "
                  f"{np.std(ll, ddof=1):.2f} (mean {np.mean(ll):.1f}) | {_ms(nl, '.0f')} | {_ms(nb, '.0f')} |",
                  flush=True)


def crown(factors) -> None:
    cfg = load_scene(REPO / "scenes" / "forest_4species.toml")
    base = forest_params_from_scene(cfg)
    print("| thinning | Poisson points | trees | per species | trees with a neighbour's trunk in their crown "
          "| s |\n|---|---|---|---|---|---|")
    for k in factors:
        t0 = time.perf_counter()
        f = make_forest(dataclasses.replace(base, crown_factor=k), cfg.seed)
        s = f.summary()
        per = " / ".join(str(sp["count"]) for sp in s["species"])
        drawn = sum(sp["candidates_drawn"] for sp in s["species"])
        print(f"| `crown_factor = {k:g}` | {drawn} | {s['n_trees']} | {per} | "
              f"{100 * s['crown_overlap_share']:.1f} % | {time.perf_counter() - t0:.1f} |", flush=True)
        del f


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--parts", default="branching,means,crown")
    ap.add_argument("--trees", type=int, default=200)
    ap.add_argument("--crown-factors", default="0,0.5,0.6,0.65,0.7")
    a = ap.parse_args()
    print(f"Machine: {machine()}  \nDate: {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}\n")
    parts = a.parts.split(",")
    if "branching" in parts:
        branching(a.trees)
        print()
    if "means" in parts:
        means(a.trees // 2)
        print()
    if "crown" in parts:
        crown([float(x) for x in a.crown_factors.split(",")])


if __name__ == "__main__":
    main()
