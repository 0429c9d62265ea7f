"""The landscape stand (bench/scenes/forest_landscape_1km2.toml) generated and flown at 1, 4, 25 and 100 ha.

    .venv/bin/python bench/bench_landscape.py [--ha 1 4 25 100] [--out DIR] [--json FILE]

Each size is a square of side 100·√ha m centred on the 1 km² stand's centre, flown by the same
airborne scanner scaled to it: one line along its middle at 0.866·side above the ground (the
60° swath covers the square), 50 m/s, 4·side pulses a line and 1000·side pulses a second, so
the pulses stay 25 cm apart across and 20 cm along (20 pulses/m²) at every size.  Every size
runs ``simlidar-mi scan … --no-png`` in a fresh process under ``/usr/bin/time -v`` (wall,
CPU, peak resident memory of the process and the children it waited for), writing
points.laz, trajectory.txt, scan.exr and measures.json.  The table gives per-hectare figures
and their ratio to the smallest size: growth no faster than linear in area means ratios ≤ 1
(the prototypes, Mitsuba's start and the scene's build are fixed costs).
"""
from __future__ import annotations

import argparse
import json
import math
import re
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "bench"))
from _machine import machine  # noqa: E402

SCENE = REPO / "bench" / "scenes" / "forest_landscape_1km2.toml"
CENTRE_M = 500.0


def overrides(ha: float) -> list[str]:
    """The scene's keys for a square of ``ha`` hectares (module docstring)."""
    side = 100.0 * math.sqrt(ha)
    lo, hi = CENTRE_M - side / 2, CENTRE_M + side / 2
    return [f"forest.domain_m=[{lo}, {hi}, {lo}, {hi}]", f"platform.start_xy_m=[{CENTRE_M}, {lo}]",
            f"platform.end_xy_m=[{CENTRE_M}, {hi}]", f"platform.altitude_m={0.866 * side}",
            f"platform.pulses_per_line={round(4 * side)}", f"platform.pulse_rate_hz={1000.0 * side}"]


def _time_v(text: str) -> dict:
    """Wall, CPU and peak RSS from ``/usr/bin/time -v``'s report."""
    def field(name):
        return re.search(rf"{re.escape(name)}: (.+)", text).group(1).strip()
    wall = [float(x) for x in field("Elapsed (wall clock) time (h:mm:ss or m:ss)").split(":")]
    wall_s = sum(v * 60 ** (len(wall) - 1 - i) for i, v in enumerate(wall))
    return {"wall_s": wall_s, "cpu_s": float(field("User time (seconds)")) + float(field("System time (seconds)")),
            "peak_rss_gb": int(field("Maximum resident set size (kbytes)")) / 1024 ** 2}


def run(ha: float, out: Path) -> dict:
    cmd = ["/usr/bin/time", "-v", str(REPO / ".venv" / "bin" / "simlidar-mi"), "scan", str(SCENE),
           "--out", str(out), "--no-png"]
    for o in overrides(ha):
        cmd += ["--set", o]
    done = subprocess.run(cmd, capture_output=True, text=True)
    if done.returncode:
        raise SystemExit(f"{ha} ha failed:\n{done.stderr[-3000:]}")
    m = json.loads((out / "measures.json").read_text())
    with open("/proc/loadavg") as fh:
        load = float(fh.read().split()[0])
    hits = m["hits"]
    return {"ha": ha, **_time_v(done.stderr), "stages_s": m["seconds"], "beams": sum(hits.values()),
            "trees": m["n_instances"], "points": sum(v for k, v in hits.items() if k != "escape"),
            "laz_mb": (out / "points.laz").stat().st_size / 1e6, "load_1min_after": load}


def table(rows: list[dict]) -> str:
    base = rows[0]
    lines = ["| area | trees | pulses | wall | CPU | peak RSS | generate / build / scan / write (s) | points.laz |"
             " wall/ha ÷ smallest's | RSS growth beyond the smallest |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        s = r["stages_s"]
        per = (r["wall_s"] / r["ha"]) / (base["wall_s"] / base["ha"])
        lines.append(f"| {r['ha']:g} ha | {r['trees']} | {r['beams'] / 1e6:.2f} M | {r['wall_s']:.1f} s | {r['cpu_s']:.1f} s | "
                     f"{r['peak_rss_gb']:.2f} GB | {s.get('generate', 0):.1f} / {s.get('build', 0):.1f} / "
                     f"{s.get('scan', 0):.1f} / {s.get('write', 0):.1f} | {r['laz_mb']:.0f} MB | {per:.2f} | "
                     f"{r['peak_rss_gb'] - base['peak_rss_gb']:+.2f} GB |")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ha", type=float, nargs="+", default=[1, 4, 25, 100])
    ap.add_argument("--out", type=Path, default=None, help="keep the scans here (default: a temporary folder)")
    ap.add_argument("--json", type=Path, default=None, help="also write the rows as JSON")
    args = ap.parse_args()
    print(machine())
    rows = []
    with tempfile.TemporaryDirectory(prefix="landscape-") as tmp:
        root = args.out or Path(tmp)
        for ha in args.ha:
            rows.append(run(ha, root / f"ha{ha:g}"))
            print(json.dumps(rows[-1]), flush=True)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1) + "\n")
    print(table(rows))


if __name__ == "__main__":
    main()
