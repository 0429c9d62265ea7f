"""The docs' picture of a virtual hemispherical photo beside a real one (docs/images/fisheye_pair.png).

Left: ``simlidar-mi fisheye scenes/forest_small.toml`` through the FC-E8 lens (position 4, the
plot's centre); middle and right: hemispheR's chestnut photo (Coolpix 4500 + FC-E8, © 2022
Francesco Chianucci, MIT licence; in examples/photos with its licence) and its classified mask
from ``simlidar-mi fisheye-photo``.  Run from the clone's root::

    .venv/bin/python bench/make_fisheye_figure.py OUT_DIR
"""
from __future__ import annotations

import subprocess
import sys
import tempfile
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from PIL import Image  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
PHOTO = REPO / "examples/photos/hemispheR/circular_coolpix4500+FC-E8_chestnut.jpg"
CLI = Path(sys.executable).with_name("simlidar-mi")


def main(out: Path) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        subprocess.run([str(CLI), "fisheye", "scenes/forest_small.toml", "--out", str(tmp / "v"),
                        "--set", 'fisheye.projection="FC-E8"'], check=True, cwd=REPO, capture_output=True)
        subprocess.run([str(CLI), "fisheye-photo", str(PHOTO), "--lens", "FC-E8", "--out", str(tmp / "r")],
                       check=True, cwd=REPO, capture_output=True)
        virtual = Image.open(tmp / "v" / "fisheye_4.png").convert("RGB")
        mask = Image.open(next((tmp / "r").glob("*_mask.png"))).convert("RGB")
        photo = Image.open(PHOTO).convert("RGB")
        fig, axes = plt.subplots(1, 3, figsize=(10.5, 3.7), dpi=90)
        for ax, img, title in zip(axes, (virtual, photo, mask),
                                  ("virtual: forest_small, FC-E8 lens", "real: chestnut, FC-E8 (hemispheR)",
                                   "real: classified (blue Otsu)")):
            img.thumbnail((600, 600))
            ax.imshow(img)
            ax.set_title(title, fontsize=9)
            ax.set_axis_off()
        fig.tight_layout()
        out.mkdir(parents=True, exist_ok=True)
        fig.savefig(out / "fisheye_pair.png")
        print(out / "fisheye_pair.png")


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else REPO / "docs" / "images")
