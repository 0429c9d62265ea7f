"""Chunk size against time and memory for a streamed scan (issue #8, "Streaming scans").

    .venv/bin/python bench/bench_chunks.py [--dtheta 0.0625] [--repeat 2] [--sizes 65536,...]

Runs ``simlidar-mi scan scenes/simlidar_table3_7x4.toml --set scan.dtheta_deg=D --set
scan.chunk_beams=C`` in a fresh process for each chunk size C (rounds interleaved, so a
change of load hits every size alike), under ``/usr/bin/time``: wall seconds, CPU seconds and
peak RSS; the trace and write seconds come from ``measures.json``. Checks that ``scan.exr``,
``points.las`` and ``scan.png`` are the same at every size (the streaming promise): the LAS and
PNG byte for byte, the EXR in every channel's pixels and every header attribute but
``scene_sha256`` (which hashes the scene with its overrides, the chunk size among them).
Prints a markdown table (medians) and writes it to bench/out/chunks.md.
"""
from __future__ import annotations

import argparse
import hashlib
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "bench"))
from _machine import machine  # noqa: E402

SCENE = "scenes/simlidar_table3_7x4.toml"
FILES = ("scan.exr", "points.las", "scan.png")


def md5(path: Path) -> str:
    h = hashlib.md5()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 22), b""):
            h.update(block)
    return h.hexdigest()


def exr_digest(path: Path) -> str:
    """md5 of every channel's pixels and of the header without ``scene_sha256`` (the hash of the
    scene as run, overrides included, so it names the chunk size)."""
    import OpenEXR  # noqa: PLC0415
    h = hashlib.md5()
    f = OpenEXR.File(str(path))
    for k, v in sorted(f.header().items()):
        if k != "scene_sha256":
            h.update(f"{k}={v!r}".encode())
    for k, ch in sorted(f.channels().items()):
        h.update(k.encode())
        h.update(ch.pixels.tobytes())
    return h.hexdigest()


def one(chunk: int, dtheta: float, out: Path) -> dict:
    env = dict(os.environ, PYTHONPATH=str(REPO))
    cmd = ["/usr/bin/time", "-f", "RSSKB %M %U %S %e", sys.executable, "-P", "-m", "simlidar_mi.cli", "scan",
           SCENE, "--out", str(out), "--set", f"scan.dtheta_deg={dtheta}", "--set", f"scan.chunk_beams={chunk}",
           "--set", "scan.max_beams=300000000"]
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=REPO)
    if proc.returncode:
        raise SystemExit(f"failed at chunk {chunk}:\n{proc.stderr[-3000:]}")
    rss_kb, user, sys_s, wall = [ln for ln in proc.stderr.splitlines() if ln.startswith("RSSKB")][-1].split()[1:]
    seconds = json.loads((out / "measures.json").read_text())["seconds"]
    return {"wall_s": float(wall), "cpu_s": float(user) + float(sys_s), "rss_mb": int(rss_kb) / 1024,
            "scan_s": seconds.get("scan", float("nan")), "write_s": seconds.get("write", float("nan")),
            "md5": {f: exr_digest(out / f) if f.endswith(".exr") else md5(out / f) for f in FILES}}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dtheta", type=float, default=0.0625, help="scan.dtheta_deg (0.0625: 4196 × 2404 = 10.1 M beams)")
    ap.add_argument("--sizes", default="65536,262144,1048576,4194304,16777216", help="chunk_beams values")
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--out", type=Path, default=REPO / "bench" / "out" / "chunks.md")
    args = ap.parse_args()
    sizes = [int(s) for s in args.sizes.split(",")]
    load0 = open("/proc/loadavg").read().split()[:3]
    res: dict[int, list[dict]] = {c: [] for c in sizes}
    work = Path(tempfile.mkdtemp(prefix="bench_chunks_"))
    try:
        for r in range(args.repeat):
            for c in sizes:
                out = work / f"c{c}_{r}"
                res[c].append(one(c, args.dtheta, out))
                shutil.rmtree(out)
                print(f"round {r} chunk {c}: {res[c][-1]['wall_s']:.2f} s", file=sys.stderr)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    load1 = open("/proc/loadavg").read().split()[:3]
    digests = {json.dumps(x["md5"], sort_keys=True) for c in sizes for x in res[c]}
    med = statistics.median
    lines = [f"Machine: {machine()}; load average {' / '.join(load0)} → {' / '.join(load1)}; "
             f"`scan.dtheta_deg={args.dtheta}`; median of {args.repeat} fresh processes per size.", "",
             "| chunk_beams | wall (s) | CPU (s) | trace (s) | write (s) | peak RSS (MB) |",
             "|---:|---:|---:|---:|---:|---:|"]
    for c in sizes:
        xs = res[c]
        lines.append(f"| {c:,} | {med(x['wall_s'] for x in xs):.2f} | {med(x['cpu_s'] for x in xs):.2f} | "
                     f"{med(x['scan_s'] for x in xs):.2f} | {med(x['write_s'] for x in xs):.2f} | "
                     f"{med(x['rss_mb'] for x in xs):.0f} |")
    lines += ["", "Same bytes at every chunk size (" + ", ".join(FILES) + "): "
              + ("yes" if len(digests) == 1 else f"NO ({len(digests)} different digests)")]
    text = "\n".join(lines)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(text + "\n")
    print(text)
    if len(digests) != 1:
        raise SystemExit(1)


if __name__ == "__main__":
    main()
