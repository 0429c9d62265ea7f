"""Regenerate simlidar_mi/io/_viridis_lut.py: matplotlib's viridis as a 256 × 3 uint8 table.

The range PNG colours beams from this table so that writing it never imports matplotlib
(1–2 s of import and a full-resolution figure). The table is matplotlib's own byte
colours, ``colormaps["viridis"](range(256), bytes=True)``: the same bytes matplotlib's
``imshow`` wrote into the old scan.png. Run after a matplotlib upgrade that changes viridis
(tests/test_range_png.py compares the stored table with matplotlib's):

    .venv/bin/python bench/make_viridis_lut.py
"""
from __future__ import annotations

import textwrap
from pathlib import Path

import numpy as np
from matplotlib import __version__ as mpl_version
from matplotlib import colormaps

OUT = Path(__file__).resolve().parents[1] / "simlidar_mi" / "io" / "_viridis_lut.py"


def main() -> None:
    rgb = np.asarray(colormaps["viridis"](np.arange(256), bytes=True))[:, :3].astype(np.uint8)
    hexdata = rgb.tobytes().hex()
    lines = textwrap.wrap(hexdata, 96)
    body = "\n".join(f'    "{line}"' for line in lines)
    OUT.write_text(
        '"""matplotlib\'s viridis colormap as 256 RGB bytes (generated: do not edit).\n\n'
        f"Written by bench/make_viridis_lut.py from matplotlib {mpl_version}'s\n"
        '``colormaps["viridis"](range(256), bytes=True)``; entry i colours the normalised\n'
        "range t with min(floor(256 t), 255) = i, as matplotlib's Colormap does.\n"
        '"""\n'
        "VIRIDIS_RGB_HEX = (\n" + body + "\n)\n", encoding="utf-8")
    print(f"wrote {OUT} (matplotlib {mpl_version})")


if __name__ == "__main__":
    main()
