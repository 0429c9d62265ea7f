"""Branch counts of SIMLIDAR Table 3 against the spread of our trees over seeds.

    .venv/bin/python bench/bench_table3_counts.py [--seeds 200]

The paper's Table 3 lists one total branch count per (iterations, trees) and does not say
whether those orchards were pruned; its counts exceed the deterministic grammar's
(7·(3^n − 1)/2), so they are stochastic. For iterations 4–7 and one stochastic tree per seed
(``orchard(..., n_trees=1, seed=s)``, s = 0 … seeds−1, the stream a scene file gives tree 0)
this prints, for unpruned, subtree-pruned (default) and segment-pruned trees, the mean, SD
and 5–95 % range of the branch count, and where each paper row's count per tree
(total / trees) falls among the mean counts of that many trees (trees are independent:
Monte Carlo resampling of the single-tree sample, fixed seed).
A second table measures what subtree instead of segment pruning removes from
``scenes/apple_orchard.toml`` (segments, A_PR, A_L, V_L), at its 5 iterations and at 7.
Markdown on stdout, also bench/out/table3_counts.md. Plain numpy: no Mitsuba scene is built.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "bench"))
from _machine import machine  # noqa: E402

from simlidar_mi.config import load_scene  # noqa: E402
from simlidar_mi.plants.measures import wood_measures  # noqa: E402
from simlidar_mi.plants.apple import AppleTreeParams, orchard  # noqa: E402
from simlidar_mi.lidar.survey import generate  # noqa: E402

#: SIMLIDAR Table 3: (iterations, trees) -> total branches.
PAPER_BRANCHES = {
    (4, 1): 360, (5, 1): 1497, (6, 1): 5564, (7, 1): 15168,
    (4, 2): 928, (5, 2): 3056, (6, 2): 10415, (7, 2): 29779,
    (4, 3): 1011, (5, 3): 5112, (6, 3): 15229, (7, 3): 48250,
    (4, 4): 2064, (5, 4): 4991, (6, 4): 20020, (7, 4): 44658,
}
#: (label, AppleTreeParams pruning keywords)
VARIANTS = [("unpruned", dict(pruning=False)),
            ("pruned, subtree (default)", dict(pruning=True, pruning_mode="subtree")),
            ("pruned, segment", dict(pruning=True, pruning_mode="segment"))]
ITERATIONS = (4, 5, 6, 7)
RESAMPLES = 20_000


def sample_counts(iterations: int, n_seeds: int) -> dict[str, np.ndarray]:
    """Branch counts and A_PR = Σ d·h of one stochastic tree per seed, per variant."""
    out = {}
    for label, kw in VARIANTS:
        p = AppleTreeParams(iterations, stochastic=True, **kw)
        n, a = np.empty(n_seeds), np.empty(n_seeds)
        for s in range(n_seeds):
            t = orchard(p, 1, 2.0, seed=s)
            n[s], a[s] = len(t), float(np.sum(t.diameter * t.length))
        out[label], out[label + " A_PR"] = n, a
    return out


def means_of_k(x: np.ndarray, k: int, rng: np.random.Generator) -> np.ndarray:
    """Mean branch count of ``k`` independent trees drawn from sample ``x`` (resampled)."""
    if k == 1:
        return x
    return rng.choice(x, size=(RESAMPLES, k)).mean(axis=1)


def percentile_of(x: np.ndarray, v: float) -> float:
    """Share of the sample below ``v`` (ties count half), in %."""
    return 100.0 * (np.count_nonzero(x < v) + 0.5 * np.count_nonzero(x == v)) / len(x)


def spread_tables(n_seeds: int) -> str:
    rng = np.random.default_rng(0)
    samples = {it: sample_counts(it, n_seeds) for it in ITERATIONS}
    det = {it: [len(orchard(AppleTreeParams(it, **kw), 1, 2.0)) for _, kw in VARIANTS]
           for it in ITERATIONS}
    rows = [f"Spread of one stochastic tree over {n_seeds} seeds (branch count; "
            "deterministic tree for reference):", "",
            "| iterations | variant | mean | SD | 5 % | 95 % | min | max | deterministic |",
            "|---|---|---|---|---|---|---|---|---|"]
    for it in ITERATIONS:
        for j, (label, _) in enumerate(VARIANTS):
            x = samples[it][label]
            lo, hi = np.percentile(x, [5, 95])
            rows.append(f"| {it} | {label} | {x.mean():,.0f} | {x.std(ddof=1):,.0f} | {lo:,.0f} | "
                        f"{hi:,.0f} | {x.min():,.0f} | {x.max():,.0f} | {det[it][j]:,} |")
    rows += ["", "What subtree instead of segment pruning removes, per tree over the same seeds "
             "(mean, and 5–95 % range):", "",
             "| iterations | segments removed % | A_PR removed % |", "|---|---|---|"]
    for it in ITERATIONS:
        s = samples[it]
        seg, sub = s["pruned, segment"], s["pruned, subtree (default)"]
        dn = 100 * (seg - sub) / seg
        da = 100 * (s["pruned, segment A_PR"] - s["pruned, subtree (default) A_PR"]) / s[
            "pruned, segment A_PR"]
        rows.append(f"| {it} | {dn.mean():.1f} ({np.percentile(dn, 5):.1f}–"
                    f"{np.percentile(dn, 95):.1f}) | {da.mean():.1f} ({np.percentile(da, 5):.1f}–"
                    f"{np.percentile(da, 95):.1f}) |")
    rows += ["", "Where each paper row falls: its count per tree (total / trees), its percentile "
             "among the mean counts of that many of our trees, and their 5–95 % range:", "",
             "| iterations | trees | paper total | paper per tree | "
             + " | ".join(f"{lab}: percentile (5–95 %)" for lab, _ in VARIANTS)
             + " |", "|---|---|---|---|" + "---|" * len(VARIANTS)]
    inside = {label: [] for label, _ in VARIANTS}
    for it in ITERATIONS:
        for k in (1, 2, 3, 4):
            total = PAPER_BRANCHES[(it, k)]
            per = total / k
            cells = []
            for label, _ in VARIANTS:
                m = means_of_k(samples[it][label], k, rng)
                lo, hi = np.percentile(m, [5, 95])
                ok = lo <= per <= hi
                inside[label] += [f"{it}×{k}"] if ok else []
                cells.append(f"{percentile_of(m, per):.1f} % ({lo:,.0f}–{hi:,.0f})"
                             + ("" if ok else " **out**"))
            rows.append(f"| {it} | {k} | {total:,} | {per:,.1f} | " + " | ".join(cells) + " |")
    rows += [""] + [f"- {label}: {len(v)} of {len(PAPER_BRANCHES)} paper rows inside the 5–95 % "
                    f"range ({', '.join(v)})." for label, v in inside.items()]
    return "\n".join(rows)


def orchard_table() -> str:
    scene = REPO / "scenes" / "apple_orchard.toml"
    rows = ["| scene | pruning | segments | A_PR m² | A_L m² | V_L dm³ |", "|---|---|---|---|---|---|"]
    for extra, name in (([], "apple_orchard.toml (5 iterations, 4 trees)"),
                        (["orchard.tree.iterations=7"], "same, iterations = 7")):
        got = {}
        for label, over in (("none", ["orchard.tree.pruning=false"]),
                            ("segment", ['orchard.tree.pruning_mode="segment"']),
                            ("subtree (default)", [])):
            m = wood_measures(generate(load_scene(scene, extra + over)).branches).to_dict()
            got[label] = m
            rows.append(f"| {name} | {label} | {m['n_branches']:,} | {m['A_PR_m2']:.4f} | "
                        f"{m['A_L_m2']:.4f} | {1e3 * m['V_L_m3']:.3f} |")
        a, b = got["segment"], got["subtree (default)"]
        share = {k: 100 * (a[k] - b[k]) / a[k] for k in ("n_branches", "A_PR_m2", "A_L_m2", "V_L_m3")}
        rows.append(f"| {name} | subtree vs segment | −{share['n_branches']:.1f} % | "
                    f"−{share['A_PR_m2']:.2f} % | −{share['A_L_m2']:.2f} % | −{share['V_L_m3']:.2f} % |")
    return "\n".join(rows)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=200, help="trees per iteration count")
    a = ap.parse_args()
    t = time.perf_counter()
    parts = [f"Machine: {machine()}  \nDate: {time.strftime('%Y-%m-%d')}  \n"
             f"Command: `.venv/bin/python bench/bench_table3_counts.py --seeds {a.seeds}`",
             spread_tables(a.seeds), "Subtree against segment pruning on the demo scene:\n\n"
             + orchard_table(), f"Run time: {time.perf_counter() - t:.0f} s"]
    text = "\n\n".join(parts) + "\n"
    out = REPO / "bench" / "out"
    out.mkdir(parents=True, exist_ok=True)
    (out / "table3_counts.md").write_text(text)
    print(text)


if __name__ == "__main__":
    main()
