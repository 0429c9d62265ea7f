"""photo-gap on a large photo: wall time and peak memory, per method.

    .venv/bin/python bench/bench_photo_large.py [--size 8000] [--methods canopeo,exg-otsu,blue-otsu]
                                                [--downscale 1,2,4] [--photo FILE]

Makes a synthetic ``size`` × ``size`` JPEG (green blobs on brown soil with pixel noise,
quality 90; seeded, so the same bytes every run) unless ``--photo`` is given, then runs
``photo_gap`` on it in a fresh process per method and downscale, so the peak RSS is that
run's own (VmHWM; it includes the interpreter and numpy/PIL/scikit-image, about 90 MB).
Prints a markdown table.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
from PIL import Image

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "bench"))

ROW = r"""
import json, sys, time
from simlidar_mi.canopy.photo import photo_gap
kw = {} if int(sys.argv[4]) == 1 else {"downscale": int(sys.argv[4])}
t = time.perf_counter()
r = photo_gap(sys.argv[1], sys.argv[2], mask_dir=sys.argv[3], **kw)
dt = time.perf_counter() - t
# VmHWM, not ru_maxrss: Linux carries the parent's peak RSS across fork + exec into ru_maxrss
hwm = [l for l in open("/proc/self/status") if l.startswith("VmHWM:")][0].split()[1]
print(json.dumps({"seconds": dt, "p0": r.p0, "threshold": r.threshold, "n_pixels": r.n_pixels,
                  "peak_rss_mb": int(hwm) / 1024}))
"""


def synthetic_photo(path: Path, size: int, seed: int = 12) -> Path:
    """Green blobs (about 40 % cover) on brown soil, with ±12 pixel noise, as a JPEG."""
    rng = np.random.default_rng(seed)
    coarse = Image.fromarray((rng.random((size // 100 + 1, size // 100 + 1)) * 255).astype(np.uint8))
    field = coarse.resize((size, size), Image.Resampling.BICUBIC)
    img = Image.new("RGB", (size, size), (120, 95, 70))
    leaf = Image.new("RGB", (size, size), (60, 140, 45))
    img.paste(leaf, mask=field.point(lambda v: 255 if v > 150 else 0))
    del leaf, field
    step = 1000  # noise in strips keeps this script's own memory small
    arr = np.asarray(img).copy()
    for y in range(0, size, step):
        noise = rng.integers(-12, 13, size=(min(step, size - y), size, 3), dtype=np.int16)
        arr[y:y + step] = np.clip(arr[y:y + step].astype(np.int16) + noise, 0, 255).astype(np.uint8)
    Image.fromarray(arr).save(path, quality=90)
    return path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=8000)
    ap.add_argument("--methods", default="canopeo,exg-otsu,blue-otsu")
    ap.add_argument("--downscale", default="1")
    ap.add_argument("--photo", type=Path, default=None)
    args = ap.parse_args()
    from _machine import machine  # noqa: PLC0415
    print(f"Machine: {machine()}\n")
    with tempfile.TemporaryDirectory() as tmp:
        photo = args.photo or synthetic_photo(Path(tmp) / f"synthetic_{args.size}.jpg", args.size)
        with Image.open(photo) as im:
            w, h = im.size
        print(f"photo: {photo.name if args.photo else 'synthetic'} {w}x{h}\n")
        print("| method | downscale | s | peak RSS MB | P0 | threshold |")
        print("|---|---|---|---|---|---|")
        for method in args.methods.split(","):
            for f in args.downscale.split(","):
                out = subprocess.run([sys.executable, "-c", ROW, str(photo), method,
                                      str(Path(tmp) / "masks"), f],
                                     capture_output=True, text=True, check=True)
                d = json.loads(out.stdout.strip().splitlines()[-1])
                t = "-" if d["threshold"] is None else f"{d['threshold']:.4g}"
                print(f"| {method} | {f} | {d['seconds']:.1f} | {d['peak_rss_mb']:.0f} | "
                      f"{d['p0']:.4f} | {t} |", flush=True)


if __name__ == "__main__":
    main()
