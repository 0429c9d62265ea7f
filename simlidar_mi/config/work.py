"""Each command's work estimated from the keys before anything is allocated, and refused past a
budget with one line naming the key that sizes it.

Every key has its own range (:mod:`simlidar_mi.config.bounds`); what a run costs is a product of
several (pixels × samples × views × replicates, trees × segments × facets, beams × sub-rays), so
a run whose every key lies in range may still ask for more memory or rays than a machine gives.
:func:`check_work` multiplies the keys a command reads into

- **rays** traced, checked against ``[scan] max_rays`` (a knob: the one ray budget of scans and
  renders), and
- **bytes** held at once, checked against :func:`memory_budget`: half of the memory available
  when the run starts (``MemAvailable``), and half of the address-space limit if one is set.

The byte counts are estimates per element (a triangle with its BVH share and the Python copies,
a render sample's state), chosen on the high side; what they guard against are the runs that
would grow past all memory, not a tight fit.  The key named is the first factor of the product
that a ``--set`` gave, else the first the scene file gave (the one the user changed), else the
first.
"""
from __future__ import annotations

import os

from ..errors import ConfigError

#: Bytes per triangle of a built scene: vertices and normals (float32), ids, Mitsuba's copy
#: and its BVH share, the numpy arrays the generators keep (an estimate on the high side).
BYTES_PER_TRIANGLE = 256
#: Bytes a branch segment holds besides its triangles (p0, p1, diameter, order, ids; float64).
BYTES_PER_SEGMENT = 128
#: Bytes a render holds per pixel: the film's planes, the coverage and numpy copies (float32 and
#: float64); measured: 512² pixels of `gapfraction`, `fisheye` and `synthetic-photo` peak at
#: 140-190 MB whole processes, whatever the samples (BENCHMARKS §15).
BYTES_PER_PIXEL = 64
#: Bytes per sample: samples are drawn in passes, not held (4 → 64 spp at 512²: +26 MB, 1.7 B a
#: sample; 8 → 128 spp of a photo: +0 MB); kept on the high side.
BYTES_PER_SAMPLE = 4
#: Bytes per sub-ray of a scan chunk on the host (range, class, ids, normals, energies: float32)
#: and the echo reader's per-sub-ray arrays.
BYTES_PER_SUBRAY = 200
#: sub-rays a scan traces at once (lidar.scan's chunks): ~1 M, ~0.2 GB with the echoes (4 M: ~0.75 GB; BENCHMARKS §8b).
DEFAULT_CHUNK_RAYS = 1 << 20
#: Bytes per forest candidate point of the thinning (x, y, marks; float64).
BYTES_PER_CANDIDATE = 64
#: L-system segments of one apple tree at 5 generations (scenes/apple_orchard.toml: 1066) and
#: their growth per generation (3509 / 1066 at 6; 3.3×).
SEGMENTS_AT_5, GROWTH = 1100, 3.4
#: Leaf triangles per strawberry leaf (3 leaflets and a petiole: 432 triangles per 42-leaf plant).
TRIANGLES_PER_STRAWBERRY_LEAF = 12


def memory_budget() -> int:
    """Half the memory available now (``/proc/meminfo`` MemAvailable, else the physical pages
    free) and, when the process has an address-space limit (RLIMIT_AS), half of that."""
    avail = None
    try:
        with open("/proc/meminfo", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    avail = int(line.split()[1]) * 1024
                    break
    except OSError:
        pass
    if avail is None:
        try:
            avail = os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
        except (ValueError, OSError, AttributeError):
            avail = 8 << 30
    budget = avail // 2
    try:
        import resource
        soft = resource.getrlimit(resource.RLIMIT_AS)[0]
        if soft != resource.RLIM_INFINITY and soft > 0:
            budget = min(budget, soft // 2)
    except (ImportError, OSError, ValueError):
        pass
    return int(budget)


#: Keys whose larger values make less work (a cell size): the message says to raise them.
RAISE_TO_SHRINK = frozenset({"terrain.cell_m"})


def _blame(cfg, factors: list[str]) -> str:
    """The first of ``factors`` (dotted keys) a --set gave, else the first the scene file gave,
    else the first."""
    return next((k for k in factors if k in cfg.overridden),
                next((k for k in factors if cfg.gave(k)), factors[0]))


def _value(cfg, dotted: str):
    section, _, leaf = dotted.rpartition(".")
    return cfg[section][leaf]


def _refuse(cfg, factors: list[str], what: str, amount: float, limit: float, unit: str, fix: str):
    key = _blame(cfg, factors)
    todo = " or ".join(f"{'raise' if k in RAISE_TO_SHRINK else 'lower'} {k}" for k in [key] + [k for k in factors
                                                                                           if k != key])
    raise ConfigError(f"{what} ≈ {amount:.3g} {unit} exceed {limit:.3g} {unit} ({fix}); {todo}",
                      file=cfg.source_of(key), key=key, value=_value(cfg, key))


class Budget:
    """What a run may use: rays (``[scan] max_rays``) and bytes (:func:`memory_budget`)."""

    def __init__(self, cfg, memory: int | None = None):
        self.cfg = cfg
        self.rays = int(cfg["scan"]["max_rays"])
        self.bytes = memory_budget() if memory is None else int(memory)

    def memory(self, what: str, n_bytes: float, factors: list[str]) -> None:
        if not n_bytes <= self.bytes:
            _refuse(self.cfg, factors, what, n_bytes / 1e9, self.bytes / 1e9, "GB",
                    "half the memory available to this run")

    def trace(self, what: str, rays: float, factors: list[str]) -> None:
        if not rays <= self.rays:
            _refuse(self.cfg, factors, what, rays, self.rays, "rays", "scan.max_rays")


# --- the estimates, one per kind of work --------------------------------------------------
def geometry(cfg, b: Budget) -> None:
    """The plants a scene generates, from its sections' keys (vineyards and the scan's beams
    have their own count guards: vineyard.max_elements, scan.max_beams)."""
    facets = cfg["scene"]["facets"] if cfg["scene"]["representation"] == "mesh" else 0
    if cfg.has("orchard"):
        o, t = cfg["orchard"], cfg["orchard.tree"]
        segs = o["n_trees"] * SEGMENTS_AT_5 * GROWTH ** (t["iterations"] - 5)
        per = BYTES_PER_SEGMENT + 2 * facets * BYTES_PER_TRIANGLE
        if cfg.has("orchard.leaves") and cfg["orchard.leaves"]["season"] == "leaf-on":
            lv = cfg["orchard.leaves"]
            per += lv["leaves_per_m"] * cfg["orchard.tree"]["h0_m"] * lv["sides"] * BYTES_PER_TRIANGLE
        b.memory(f"{segs:.3g} branch segments of {facets} facets", segs * per,
                 ["orchard.n_trees", "orchard.tree.iterations", "scene.facets",
                  "orchard.leaves.leaves_per_m", "orchard.leaves.sides"])
    if cfg.has("strawberry"):
        s = cfg["strawberry"]
        leaves = s["rows"] * s["plants_per_row"] * (s["leaves_per_plant_mean"] + 3 * s["leaves_per_plant_sd"])
        b.memory(f"{leaves:.3g} strawberry leaves", leaves * TRIANGLES_PER_STRAWBERRY_LEAF * BYTES_PER_TRIANGLE,
                 ["strawberry.rows", "strawberry.plants_per_row", "strawberry.leaves_per_plant_mean",
                  "strawberry.leaves_per_plant_sd"])
    if cfg.has("random_leaves"):
        r = cfg["random_leaves"]
        tris = r["n_leaves"] * (r["n_sides"] if r["shape"] == "disc" else 2)
        # a periodic plot is built with its 8 neighbour copies (canopy.random_leaves)
        b.memory(f"{r['n_leaves']} leaves × 9 periodic copies", 9 * tris * BYTES_PER_TRIANGLE,
                 ["random_leaves.n_leaves", "random_leaves.n_sides"])
    if cfg.has("forest"):
        x0, x1, y0, y1 = cfg["forest"]["domain_m"]
        lam = sum(sp["background_per_m2"] + sum(abs(float(bp.get("C_per_m2", 0.0))) for bp in sp["bumps"] or ())
                  for sp in cfg.arrays["species"])
        cand = lam * (x1 - x0) * (y1 - y0)  # the thinning's dominating Poisson process
        b.memory(f"{cand:.3g} candidate trees on the {x1 - x0:g} m × {y1 - y0:g} m domain",
                 cand * BYTES_PER_CANDIDATE, ["forest.domain_m"])
    if cfg.has("terrain") and cfg["terrain"]["file"] is None:  # a DEM's size is its file's
        t = cfg["terrain"]
        x0, x1, y0, y1 = t["extent_m"] or ([a + s * 20.0 for a, s in zip(cfg["forest"]["domain_m"], (-1, 1, -1, 1))]
                                           if cfg.has("forest") else [-50.0, 50.0, -50.0, 50.0])
        tris = 2.0 * ((x1 - x0) / t["cell_m"] + 2) * ((y1 - y0) / t["cell_m"] + 2)
        b.memory(f"{tris:.3g} terrain triangles", tris * BYTES_PER_TRIANGLE, ["terrain.cell_m", "terrain.extent_m"])


def _render(b: Budget, what: str, views: float, pixels: float, spp: int, factors: list[str],
            depth: int = 1, kept: float = 0.0) -> None:
    """A series of ``views`` images of ``pixels`` pixels at ``spp`` samples: rays traced (× the
    path ``depth``), one image's pixels and samples held, ``kept`` bytes of results."""
    b.memory(f"{what}: {pixels:.3g} pixels × {spp} samples, {kept / 1e9:.3g} GB of results kept",
             pixels * (BYTES_PER_PIXEL + spp * BYTES_PER_SAMPLE) + kept, factors)
    b.trace(f"{what}: {views:.3g} images × {pixels:.3g} pixels × {spp} samples"
            + (f" × {depth} bounces" if depth > 1 else ""), views * pixels * spp * depth, factors)


def gapfraction(cfg, b: Budget) -> None:
    g = cfg["gapfraction"]
    views = len(g["cameras"]) * len(g["zeniths_deg"]) * g["replicates"]
    px = float(g["resolution"]) ** 2
    _render(b, "gap-fraction images", views, px, g["spp"],
            ["gapfraction.resolution", "gapfraction.spp", "gapfraction.replicates"],
            kept=views * px * 4)


def synthetic_photo(cfg, b: Budget) -> None:
    g, p = cfg["gapfraction"], cfg["photo_render"]
    views = len(g["cameras"]) * len(g["zeniths_deg"])
    px = float(g["resolution"]) ** 2
    _render(b, "synthetic photos", views, px, p["spp"],
            ["photo_render.spp", "photo_render.max_depth", "gapfraction.resolution"],
            depth=p["max_depth"], kept=views * px * 16)


def _positions(cfg) -> tuple[int, str]:
    f = cfg["fisheye"]
    if f["layout"] == "grid":
        return f["grid_n"][0] * f["grid_n"][1], "fisheye.grid_n"
    if f["layout"] == "transect":
        return f["transect_n"], "fisheye.transect_n"
    return len(f["points_m"] or [0]), "fisheye.points_m"


def fisheye(cfg, b: Budget, sampler: str = "fisheye") -> None:
    f = cfg["fisheye"]
    n, pos_key = _positions(cfg)
    rings = len(f["rings_deg"])
    tables = n * rings * f["n_sectors"] * 8 * 4  # gap, pixels, solid angle, ... per cell (float64)
    if sampler == "rays":
        lm = cfg["lai_methods"]
        rays = len(lm["rings_deg"]) * lm["n_sectors"] * lm["rays_per_cell"]
        b.memory("ray fans", rays * BYTES_PER_PIXEL + tables, ["lai_methods.rays_per_cell", "lai_methods.n_sectors"])
        b.trace("ray fans", n * rays, ["lai_methods.rays_per_cell", "lai_methods.n_sectors", pos_key])
        return
    px = float(f["resolution"]) ** 2 / (1.5 if f["format"] == "fullframe" else 1.0)
    _render(b, "fisheye images", n, px, f["spp"], ["fisheye.resolution", "fisheye.spp", pos_key],
            kept=tables + n * px * 4)  # every position's coverage image (float32) is kept
    b.memory("gap tables", tables, ["fisheye.n_sectors", pos_key])


def scan_subrays(cfg, b: Budget) -> None:
    """A scan chunk's sub-rays: (chunk of beams) × dot-matrix sub-beams × sub-rays per beam."""
    s = cfg["sensor"]
    dots = (cfg["scan"]["footprint"] + 1) ** 2
    per_beam = dots * max(1, s["beam_samples"] if s["divergence_mrad"] > 0 else 1)
    chunk = min(cfg["scan"]["chunk_beams"], max(1, DEFAULT_CHUNK_RAYS // per_beam)) * per_beam
    b.memory(f"a scan chunk of {chunk:.3g} sub-rays ({per_beam} per beam)", chunk * BYTES_PER_SUBRAY,
             ["sensor.beam_samples", "scan.footprint", "scan.chunk_beams"])


#: Bytes a truth-raster cell holds: its centre (x, y), DTM, DSM and CHM (float64), tree id (int32)
#: and the float32 copies written; and a ray of one band of vertical rays (truth.als_truth: the
#: sub-sample positions, terrain, hit heights and ids, and the tracer's tables).
BYTES_PER_RASTER_CELL, BYTES_PER_RASTER_RAY = 64, 120
#: Vertical rays traced at once (truth.als_truth.CHUNK_RAYS).
RASTER_CHUNK_RAYS = 1 << 21


def forest_truth(cfg, b: Budget) -> None:
    """``forest --truth-rasters``: k × k vertical rays a cell of ``[truth] raster_cell_m`` over the domain."""
    if not cfg["forest"]["truth_rasters"]:
        return
    x0, x1, y0, y1 = cfg["forest"]["domain_m"]
    cell, k = cfg["truth"]["raster_cell_m"], cfg["truth"]["raster_subsamples"]
    cells = max(1.0, -(-(x1 - x0) // cell)) * max(1.0, -(-(y1 - y0) // cell))
    factors = ["truth.raster_cell_m", "truth.raster_subsamples", "forest.domain_m"]
    b.memory(f"truth rasters of {cells:.3g} cells", cells * BYTES_PER_RASTER_CELL
             + min(cells * k * k, RASTER_CHUNK_RAYS) * BYTES_PER_RASTER_RAY, factors)
    b.trace(f"truth rasters: {cells:.3g} cells × {k}² vertical rays", cells * k * k, factors)


#: What each command's run builds: a list of estimates.
COMMAND_WORK = {
    "scan": (geometry, scan_subrays), "evaluate": (geometry, scan_subrays), "measure": (geometry,),
    "study": (geometry, scan_subrays),  # its base scene, with the --set every orchard gets
    "preview": (geometry,), "truth": (geometry,), "forest": (geometry, forest_truth),
    "gapfraction": (geometry, gapfraction), "synthetic-photo": (geometry, synthetic_photo),
    "fisheye": (geometry, fisheye),
    "evaluate-photo": (geometry, lambda c, b: fisheye(c, b, c["lai_methods"]["sampler"])),
}


def check_work(cfg, command: str, memory: int | None = None) -> None:
    """Refuse ``command`` on scene ``cfg`` when its estimated rays or memory exceed the budget
    (:class:`Budget`; ``memory`` in bytes instead of :func:`memory_budget`), with a
    :class:`~simlidar_mi.errors.ConfigError` naming the key that sizes the work."""
    b = Budget(cfg, memory)
    for estimate in COMMAND_WORK.get(command, ()):
        estimate(cfg, b)

