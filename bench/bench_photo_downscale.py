"""How much ``photo-gap --downscale`` moves P0 on the real test photos.

    .venv/bin/python bench/bench_photo_downscale.py [PHOTOS_DIR]

PHOTOS_DIR defaults to ``../shared/data/photos`` (see its PROVENANCE.md). Each photo is
classified with the methods that suit it (nadir: canopeo, exg-otsu; upward: blue-otsu)
at downscale 1, 2, 4 and 8; prints a markdown table of P0 and its change from downscale 1.
"""
from __future__ import annotations

import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "bench"))

CASES = [  # (photo, methods): nadir crop photos, upward cover photos, fisheye images
    ("canopeo/corn_tillage.jpg", ("canopeo", "exg-otsu")),
    ("canopeo/grassland.jpg", ("canopeo", "exg-otsu")),
    ("canopeo/wheat_no_tillage.jpg", ("canopeo", "exg-otsu")),
    ("canopeo/alfalfa.jpg", ("canopeo",)),
    ("coveR2/IMG1.JPG", ("blue-otsu",)),
    ("coveR2/IMG3.JPG", ("blue-otsu",)),
    ("hemispheR/fullframe_D90_Nikkor-10.5_beech.jpg", ("blue-otsu",)),
    ("hemispheR/circular_coolpix4500+FC-E8_chestnut.jpg", ("blue-otsu",)),
    ("hemispheR/circular_downward_D90-8-15.jpg", ("canopeo", "exg-otsu")),
]
FACTORS = (1, 2, 4, 8)


def main() -> None:
    from _machine import machine  # noqa: PLC0415
    from simlidar_mi.canopy.photo import photo_gap  # noqa: PLC0415
    root = Path(sys.argv[1]) if len(sys.argv) > 1 else REPO.parent / "shared" / "data" / "photos"
    print(f"Machine: {machine()}\n")
    print("| photo | size | method | P0 at 1 | ΔP0 at 2 | ΔP0 at 4 | ΔP0 at 8 |")
    print("|---|---|---|---|---|---|---|")
    worst = {f: 0.0 for f in FACTORS[1:]}
    with tempfile.TemporaryDirectory() as tmp:
        for name, methods in CASES:
            for method in methods:
                p0 = {f: photo_gap(root / name, method, mask_dir=tmp, downscale=f) for f in FACTORS}
                w, h = p0[1].image_size
                d = {f: p0[f].p0 - p0[1].p0 for f in FACTORS[1:]}
                for f in d:
                    worst[f] = max(worst[f], abs(d[f]))
                print(f"| {name} | {w}×{h} | {method} | {p0[1].p0:.4f} | "
                      + " | ".join(f"{d[f]:+.4f}" for f in FACTORS[1:]) + " |", flush=True)
    print("\nlargest |ΔP0|: " + ", ".join(f"{worst[f]:.4f} at {f}" for f in FACTORS[1:]))


if __name__ == "__main__":
    main()
