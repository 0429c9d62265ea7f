"""``simlidar-mi preview``: a shaded side view of a scene, as the scanner looks at it."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .._runtime.mitsuba import check_variant
from .._runtime.progress import make_progress
from ..config import SceneConfig, load_scene
from ..io.atomic import atomic_file, writes_output
from .scene_counts import generated_line
from .survey import build, generate


@writes_output("path", file=True)
def preview(cfg: SceneConfig | str | Path, path: str | Path, *, width: int = 1024,
            spp: int = 16, overrides: list[str] | tuple = (), progress=False) -> Path:
    """A shaded side view of the scene (looking along +x, like the scanner) as PNG.

    ``progress``: see :func:`simlidar_mi._runtime.progress.make_progress` (stages generate, build,
    render, write)."""
    from .._runtime.mitsuba import mitsuba  # noqa: PLC0415
    if not isinstance(cfg, SceneConfig):
        cfg = load_scene(cfg, overrides)
    check_variant(cfg["scene"]["variant"], cfg.source)  # before any work
    step = make_progress(progress).stage("preview", 4, "stage").step
    geometry = generate(cfg)
    step(generated_line(geometry))
    built = build(cfg, geometry)
    step(f"built {built.representation} scene")
    mi = mitsuba(cfg["scene"]["variant"])
    lo, hi = built.bbox_min_m - built.origin_m, built.bbox_max_m - built.origin_m
    centre = 0.5 * (lo + hi)
    extent = hi - lo
    half_w = 0.55 * max(extent[1], 0.6 * extent[2], 1e-3)
    half_h = 0.55 * max(extent[2], 0.3 * extent[1], 1e-3)
    height = max(16, int(round(width * half_h / half_w)))
    eye = [lo[0] - 10.0 * max(extent.max(), 1.0), centre[1], centre[2]]
    sensor = mi.load_dict({
        "type": "orthographic",
        "to_world": mi.ScalarTransform4f.look_at(origin=eye, target=centre.tolist(), up=[0, 0, 1])
        @ mi.ScalarTransform4f.scale([half_w, half_w, 1.0]),  # Mitsuba applies the film aspect to y
        "film": {"type": "hdrfilm", "width": width, "height": height, "pixel_format": "rgb"
                 if "rgb" in mi.variant() else "luminance"},
        "sampler": {"type": "independent", "sample_count": spp},
    })
    shapes = {f"s{j}": s for j, s in enumerate(built.scene.shapes())}
    scene = mi.load_dict({"type": "scene", "integrator": {"type": "direct", "hide_emitters": True},
                          "light": {"type": "constant", "radiance": {"type": "rgb", "value": 0.8}}
                          if "rgb" in mi.variant() else {"type": "constant", "radiance": 0.8},
                          "sun": {"type": "directional", "direction": [1.0, 0.4, -1.0], "irradiance": 2.0},
                          **shapes})
    img = np.array(mi.render(scene, sensor=sensor, spp=spp))
    step(f"rendered {width}×{height} at {spp} spp")
    if img.ndim == 2:
        img = img[..., None]
    lum = img.mean(axis=2)
    fg = lum > 0
    scale = np.percentile(lum[fg], 99.5) if fg.any() else 1.0
    shade = np.clip(lum / max(scale, 1e-6), 0, 1) ** (1 / 2.2)
    # Wood in bark brown on a white background (emitters hidden: background renders 0).
    bark = np.array([0.45, 0.30, 0.18])
    img = np.where(fg[..., None], (0.25 + 0.75 * shade[..., None]) * bark / bark.max(), 1.0)
    from PIL import Image  # noqa: PLC0415
    with atomic_file(path) as tmp:
        Image.fromarray((img * 255).astype(np.uint8)).save(tmp, format="PNG")
    step(f"wrote {path}")
    return Path(path)
