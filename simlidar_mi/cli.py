"""Command line: a thin shell over the Python API.

Each sub-command is a ``(name, help, add_arguments, run)`` entry in COMMANDS;
``run(args)`` makes one API call and prints or writes its result.
"""
from __future__ import annotations

import argparse
import math
import sys
import warnings
from typing import Callable

from .cli_canopy import checked, register as _register_canopy
from .errors import SimlidarError, SimlidarWarning

Command = tuple[str, str, Callable[[argparse.ArgumentParser], None],
                Callable[[argparse.Namespace], int | None]]
COMMANDS: list[Command] = []


def command(name: str, help: str, add_arguments: Callable[[argparse.ArgumentParser], None]):
    """Decorator registering ``run`` as sub-command ``name``."""
    def deco(run):
        COMMANDS.append((name, help, add_arguments, run))
        return run
    return deco


# --- sub-commands (each block: argument builder + run function calling one API function) ---


def _scene_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("scene", metavar="SCENE.toml", help="scene file (see scenes/)")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override a scene key, e.g. --set scan.dtheta_deg=0.5 (repeatable)")
    p.add_argument("--variant", default=None,
                   help="Mitsuba variant (default llvm_ad_mono; cuda_ad_mono on a GPU)")


def _overrides(args: argparse.Namespace) -> list[str]:
    extra = [f'scene.variant="{args.variant}"'] if getattr(args, "variant", None) else []
    if getattr(args, "truth_rasters", False):  # forest: its errors name the option
        from .config import Override  # noqa: PLC0415  (not while the parser is built: no numpy yet)
        extra.append(Override("forest.truth_rasters=true", "--truth-rasters"))
    return list(args.overrides) + extra


def _scan_args(p: argparse.ArgumentParser) -> None:
    _scene_args(p)
    p.add_argument("--out", required=True, metavar="DIR",
                   help="output folder: scan.exr, scan.png, points.las (points.laz with "
                        "--set scan.points_format=laz), measures.json")
    p.add_argument("--no-las", action="store_true", help="skip points.las / points.laz")
    p.add_argument("--no-png", action="store_true", help="skip scan.png")
    p.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="scan in row tiles on the Dask cluster whose scheduler is ADDRESS (e.g. "
                        "tcp://host:8786; default: $DASK_SCHEDULER_ADDRESS if set, else this process; "
                        "'local' forces this process); the same files; each worker needs this simlidar-mi")
    p.add_argument("--tile-rows", type=_opt(int, "[1, 1e9]", "rows per task"), default=None, metavar="N",
                   help="rows (scan lines, sweeps, positions) per cluster task (default: about 1 M "
                        "beams a tile)")


@command("scan", "Tractor LiDAR scan of a scene: range EXR, range PNG, LAS points, measures", _scan_args)
def _scan_run(args: argparse.Namespace) -> int:
    from .lidar.scene_counts import describe
    from .lidar.survey import run_scan

    run = run_scan(args.scene, args.out, _overrides(args), write_las=not args.no_las,
                   write_png=not args.no_png, progress=True,
                   scheduler=args.scheduler, tile_rows=args.tile_rows)
    m = run.measures
    grids = [(m["N"], m["M"])] if "N" in m else [(leg["N"], leg["M"]) for leg in m["legs"]]
    print(f"{' + '.join(f'{n}×{k}' for n, k in grids)} beams ({m['platform']}), "
          f"{m['n_branches'] + m.get('n_branches_placed', 0):,} branches ({m['representation']}), "
          f"{describe(m)}")
    print("hits: " + ", ".join(f"{m['hits'][k]:,} {k}" for k in ("wood", "leaf", "ground") if k in m["hits"])
          + f"; {m['hits'].get('escape', 0):,} beams hit nothing (escape)")
    areas = [f"{name} = {m[key]:.6g} m²" for name, key in
             (("A_IM", "A_IM_m2"), ("A_PR", "A_PR_m2"), ("A_L", "A_L_m2")) if key in m]
    if areas:
        print(", ".join(areas))
    print("seconds: " + ", ".join(f"{k} {v:.3f}" for k, v in m["seconds"].items()))
    for kind, path in run.files.items():
        print(f"wrote {path}")
    return 0


def _study_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("scene", metavar="SCENE.toml", help="base orchard scene (e.g. scenes/apple_orchard.toml)")
    p.add_argument("--out", required=True, metavar="DIR",
                   help="output folder: study.csv, regression.json, correlations.png, rows/")
    p.add_argument("--workers", type=_opt(int, "[1, 1024]", "local processes"), default=1,
                   help="local Dask worker processes (default 1)")
    p.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="scan on the Dask cluster whose scheduler is ADDRESS (e.g. tcp://host:8786; "
                        "default: $DASK_SCHEDULER_ADDRESS if set, else the local processes of "
                        "--workers; 'local' forces those); each worker needs this simlidar-mi")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="applied to every orchard of the grid (e.g. scan.dtheta_deg=0.5)")
    p.add_argument("--hit-rule", choices=["any", "fraction"], default="any",
                   help="'any' (default, the paper's §3.1): a beam hits when any point of its dot "
                        "matrix does; 'fraction': A_IM weights a beam by its share of sub-beams "
                        "that hit, with the scene's own footprint (the study before this option)")
    p.add_argument("--footprint", type=_opt(int, "scan.footprint"), default=None, metavar="P",
                   help="dot-matrix precision P, (P+1)² sub-beams (default: 2, the paper's, with "
                        "--hit-rule any; the scene's with --hit-rule fraction)")
    p.add_argument("--no-readings", dest="readings", action="store_false",
                   help="skip the re-scans under the paper's other readings (fraction rule, "
                        "far-side limits, the old study) that regression.json compares")
    p.add_argument("--trunk-distances", type=_distances, default=None, metavar="D1,D2,...",
                   help="repeat the grid with the trunks D metres from the scanner line "
                        "(orchard.row_x_m = scan.x0_m + D), e.g. 1.5,2,2.5; regression.json fits "
                        "each distance on its own (default: the scene's own placement; the paper "
                        "does not give it)")
    p.add_argument("--on-mismatch", choices=["recompute", "refuse"], default="recompute",
                   help="rows already in DIR/rows for this grid's orchards but scanned from another "
                        "scene or by other code: 'recompute' (default) rescans them and says which "
                        "and why; 'refuse' stops before any scan, saying the same")


def _opt(kind: type, bound: str, why: str = ""):
    """A checked ``int``/``float`` option type (:func:`simlidar_mi.config.bounds.option`): the
    range of scene key ``bound`` ("scan.footprint"), else the interval ``bound`` ("[1, 12]") and
    ``why``; built when a value is read (:func:`simlidar_mi.cli_canopy.checked`)."""
    return checked("option", kind, key=bound) if bound[0] not in "[(" else checked("option", kind, bound, why)


#: L-system generations of --preset and derive: each multiplies the segments about 3-fold.
GENERATIONS = ("[1, 12]", "each generation multiplies the segments")


def _distances(text: str) -> list[float]:
    """``--trunk-distances 1.5,2,2.5`` → [1.5, 2.0, 2.5] (argparse names the option on error)."""
    try:
        ds = [float(t) for t in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a comma-separated list of metres: {text!r}") from None
    if not ds or not all(math.isfinite(d) and 0 < d <= 1000 for d in ds):
        raise argparse.ArgumentTypeError(f"every distance must be a number of metres in (0, 1000]: {text!r}")
    return ds


@command("study", "SIMLIDAR §5 study: scan the 96-orchard grid, fit A_PR and A_L against A_IM "
         "(resumes an interrupted run)", _study_args)
def _study_run(args: argparse.Namespace) -> int:
    from .lidar.study import paper_grid, run_study

    grid = [list(args.overrides) + g for g in paper_grid()]
    res = run_study(args.scene, args.out, grid, workers=args.workers, progress=True,
                    hit_rule=args.hit_rule, footprint=args.footprint, readings=args.readings,
                    on_mismatch=args.on_mismatch, scheduler=args.scheduler,
                    trunk_distances_m=args.trunk_distances)
    print(f"hit rule {', '.join(res.regression['scan']['hit_rule'])}, footprint P = "
          f"{', '.join(map(str, res.regression['scan']['footprint']))}")
    for key, name in (("A_PR_vs_A_IM", "A_PR"), ("A_L_vs_A_IM", "A_L")):
        fit, paper = res.regression[key], res.regression["paper"][key]
        print(f"{name} = {fit['slope']:.4f}·A_IM (R² {fit['r2']:.3f}, n {fit['n']}); "
              f"paper: {paper['slope']}·A_IM (R² {paper['r2']})")
    boot = res.regression["bootstrap"]["A_PR_vs_A_IM"]
    for what, b in (("this grid's slope", boot["grid"]), ("a study of", boot["paper_size"])):
        if b["n_resamples"]:
            name = what if b is boot["grid"] else f"{what} {b['size']} orchards"
            print(f"A_PR slope, bootstrap 95 % ({b['n_resamples']} resamples, seed {b['seed']}), "
                  f"{name}: {b['slope_2.5%']:.3f} … {b['slope_97.5%']:.3f}")
    if len(res.regression["by_trunk_distance"]) > 1:
        for t in res.regression["by_trunk_distance"]:
            print(f"  trunks {t['trunk_distance_m']:g} m from the scanner line: A_PR = {t['slope']:.4f}·A_IM "
                  f"(R² {t['r2']:.3f}, n {t['n']})")
    for name, fit in res.regression["A_PR_vs_A_IM_by_reading"].items():
        print(f"  reading {name:<8} A_PR = {fit['slope']:.4f}·A_IM (R² {fit['r2']:.3f})  {fit['what']}")
    for path in res.files.values():
        print(f"wrote {path}")
    return 0


def _measure_args(p: argparse.ArgumentParser) -> None:
    # _scene_args with the scene optional: --preset measures a plant without a scene
    p.add_argument("scene", metavar="SCENE.toml", nargs="?", default=None,
                   help="scene file (see scenes/); omit with --preset")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override a scene key, e.g. --set scan.dtheta_deg=0.5 (repeatable)")
    p.add_argument("--variant", default=None,
                   help="Mitsuba variant (default llvm_ad_mono; cuda_ad_mono on a GPU)")
    p.add_argument("--preset", default=None, metavar="NAME",
                   help="measure one plant of a named L-system preset instead of a scene "
                        "(honda-a, ternary, conifer-whorl, ...; an unknown name lists them)")
    p.add_argument("--generations", "-n", type=_opt(int, *GENERATIONS), default=None, metavar="N",
                   help="with --preset: number of generations (default: the preset's)")
    p.add_argument("--seed", type=_opt(int, "scene.seed"), default=0,
                   help="with --preset: seed (default 0)")
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")


@command("measure", "Vegetative measures V_L, A_L, A_PR, A_PR_exact of a scene, without scanning; "
         "with --preset, size, leaf and wood measures of one L-system plant", _measure_args)
def _measure_run(args: argparse.Namespace) -> int:
    import json

    from .errors import ConfigError

    if args.preset is not None:
        from .plants.presets import format_measures, measures_json, preset_measures

        if args.scene is not None:
            raise ConfigError("give a scene file or --preset, not both", key="preset",
                              value=args.preset)
        m = preset_measures(args.preset, args.generations, args.seed)
        print(measures_json(m) if args.json else format_measures(m))
        return 0
    if args.scene is None:
        raise ConfigError("give a scene file (SCENE.toml) or --preset NAME", key="scene",
                          value=None)
    if args.generations is not None:
        raise ConfigError("--generations only applies with --preset", key="generations",
                          value=args.generations)

    from .lidar.survey import load_scene, measure

    m = measure(load_scene(args.scene, _overrides(args)))
    if args.json:
        print(json.dumps(m, indent=2, sort_keys=True))
        return 0
    per_tree = m.get("per_tree", [])
    keys = [k for k in ("n_branches", "V_L_m3", "A_L_m2", "A_PR_m2", "A_PR_exact_m2") if k in m]
    leaf = m.get("leaf_area_per_tree_m2")  # a leaf-on orchard: one more column
    if m.get("n_branches") or "primitive_leaf_area_m2" not in m:  # no table of zeros for a mesh scene
        print("tree    " + "  ".join(f"{k:>14}" for k in keys) + (f"  {'leaf_area_m2':>14}" if leaf else ""))
        for j, row in enumerate(per_tree):
            print(f"{row.get('tree_id', ''):<6}  " + "  ".join(f"{row[k]:>14.6g}" for k in keys)
                  + (f"  {leaf[j]:>14.6g}" if leaf and j < len(leaf) else ""))
        print("total   " + "  ".join(f"{m[k]:>14.6g}" for k in keys)
              + (f"  {m['leaf_area_m2']:>14.6g}" if leaf else ""))
    if "primitive_leaf_area_m2" in m:  # meshes, boxes, cylinders of [[primitive]]: their surfaces
        print(f"primitives: {m['n_leaf_triangles_meshes']:,} leaf triangles in meshes, leaf area "
              f"{m['primitive_leaf_area_m2']:.6g} m² (one-sided), wood surface {m['primitive_wood_area_m2']:.6g} m²")
    if leaf:
        print(f"{m['n_leaves']} leaves, one-sided leaf area {m['leaf_area_m2']:.6g} m²; LAI of the row "
              f"{m['LAI_row']:.4g} = leaf area / {m['row_ground_area_m2']:.6g} m² "
              "(n_trees × spacing_m × row_spacing_m)")
    return 0


def _sensors_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("name", nargs="?", default=None, metavar="NAME",
                   help="one preset in full: a built-in name or a preset .toml file")
    p.add_argument("--json", action="store_true", help="print JSON instead of text")


@command("sensors", "Named sensors ([sensor] preset = NAME): their values and the public "
         "datasheets they come from", _sensors_args)
def _sensors_run(args: argparse.Namespace) -> int:
    import json

    from .config import sensor_preset
    from .config.presets import BUILTIN, format_preset, format_table

    if args.name is not None:
        p = sensor_preset(args.name)
        print(json.dumps(p.to_dict(), indent=2) if args.json else format_preset(p))
    else:
        print(json.dumps([p.to_dict() for p in BUILTIN.values()], indent=2) if args.json
              else format_table())
    return 0


def _preview_args(p: argparse.ArgumentParser) -> None:
    _scene_args(p)
    p.add_argument("--out", default="preview.png", metavar="PNG", help="output PNG (default preview.png)")
    p.add_argument("--width", type=_opt(int, "fisheye.resolution"), default=1024,
                   help="image width in pixels")
    p.add_argument("--spp", type=_opt(int, "photo_render.spp"), default=16, help="samples per pixel")


@command("preview", "Shaded side view of a scene, looking along +x like the scanner, to PNG",
         _preview_args)
def _preview_run(args: argparse.Namespace) -> int:
    from .lidar.preview import preview

    print(f"wrote {preview(args.scene, args.out, width=args.width, spp=args.spp, overrides=_overrides(args), progress=True)}")
    return 0


def _photo_gap_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("photos", nargs="+", metavar="PHOTO", help="8-bit RGB photos (JPEG, PNG, ...)")
    p.add_argument("--method", required=True, choices=["canopeo", "exg-otsu", "blue-otsu"],
                   help="canopeo / exg-otsu for nadir photos, blue-otsu for upward photos")
    p.add_argument("--crop", default=None, metavar="F|x0,y0,x1,y1",
                   help="central fraction kept in each dimension (0.5) or a pixel box")
    p.add_argument("--json", action="store_true",
                   help="print a JSON list of {file, method, threshold, cover, p0, ...}")
    p.add_argument("--out", default=None, metavar="DIR",
                   help="write each photo's mask, <stem>_<method>_mask.png, into DIR (default: no "
                        "files written, the results only)")
    p.add_argument("--mask-dir", dest="out", default=None, help=argparse.SUPPRESS)  # its older name
    p.add_argument("--downscale", type=int, default=1, choices=[1, 2, 4, 8], metavar="F",
                   help="analyse at 1/F of the size (1, 2, 4, 8; JPEGs decode at that size): "
                        "less memory and time, but P0 moves (fine grass at 512 px: 0.03 at 2, "
                        "0.14 at 8; see BENCHMARKS.md)")


@command("photo-gap", "Gap fraction and vegetation cover of real photos (mask PNGs saved)",
         _photo_gap_args)
def _photo_gap_run(args: argparse.Namespace) -> int:
    import json

    from ._runtime.progress import make_progress
    from .errors import PhotoError
    from .canopy.photo import photo_gap
    from .io.atomic import check_output_dir

    if args.out is not None:
        check_output_dir(args.out)  # before any photo is read
    results, failed = [], 0
    prog = make_progress(len(args.photos) > 1)  # one photo: its own line is the progress
    with prog.stage("photo-gap", len(args.photos), "photo") as st:
        for photo in args.photos:
            try:  # one bad photo should not hide the others' results
                results.append(photo_gap(photo, args.method, args.crop, mask_dir=args.out,
                                         write_mask=args.out is not None, downscale=args.downscale,
                                         progress=len(args.photos) == 1 and sys.stderr.isatty()))
            except PhotoError as exc:
                failed += 1
                prog.write(f"simlidar-mi photo-gap: error: {exc}")  # above the bar, if any
            st.update(note=f"{failed} failed" if failed else None)
    if not results:
        return 2  # nothing to print: stdout stays empty (no '[]', no header)
    if args.json:
        keys = ("file", "method", "threshold", "cover", "p0", "n_pixels", "n_transparent", "crop",
                "downscale", "mask_file")
        print(json.dumps([{k: r.to_dict()[k] for k in keys} for r in results], indent=2))
    else:
        w = max(len(str(r.file)) for r in results)
        print(f"{'file':<{w}}  {'method':<9}  {'threshold':>9}  {'cover':>6}  {'p0':>6}  "
              f"{'pixels':>9}  mask")
        for r in results:
            t = "-" if r.threshold is None else f"{r.threshold:.4g}"
            print(f"{str(r.file):<{w}}  {r.method:<9}  {t:>9}  {r.cover:6.4f}  {r.p0:6.4f}  "
                  f"{r.n_pixels:>9}  {r.mask_file or '-'}")
    return 2 if failed else 0


def _derive_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--generations", "-n", type=_opt(int, *GENERATIONS), required=True, metavar="N",
                   help="number of rewrites of the axiom F (the paper uses 4-7)")
    p.add_argument("--stochastic", action="store_true",
                   help="use the three-successor stochastic grammar (0.33/0.33/0.34)")
    p.add_argument("--seed", type=_opt(int, "scene.seed"), default=0,
                   help="seed of the stochastic choices (default 0)")


@command("derive", "Print the SIMLIDAR apple L-system derivation in the paper's Table 1 notation",
         _derive_args)
def _derive_run(args: argparse.Namespace) -> int:
    from .plants.apple import apple_derivation_string

    print(apple_derivation_string(args.generations, stochastic=args.stochastic, seed=args.seed))
    return 0


def _forest_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("scene", metavar="SCENE.toml", help="scene with [forest] and [[species]] (see scenes/)")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override a scene key, e.g. --set forest.instancing=false (repeatable)")
    p.add_argument("--out", required=True, metavar="DIR",
                   help="output folder: trees.csv, leaves.parquet, layout.png, preview.png, stand.ply, "
                        "forest.json (and truth_*.tif with --truth-rasters)")
    p.add_argument("--truth-rasters", action="store_true",
                   help="also cast the truth DTM, DSM, CHM and top tree id (truth_*.tif at [truth] "
                        "raster_cell_m) and add top_cells and overtopped to trees.csv (same as --set "
                        "forest.truth_rasters=true)")


@command("forest", "Random forest (seed 004): Poisson-placed random trees; tree and leaf tables, "
         "layout and preview pictures, PLY/OBJ export", _forest_args)
def _forest_run(args: argparse.Namespace) -> int:
    from .truth.forest_truth import run_forest

    run = run_forest(args.scene, args.out, _overrides(args), progress=True)
    s = run.summary
    print(f"{s['n_trees']} trees ({s['removed_by_thinning']} candidates removed by the "
          f"{s['min_distance_m']:g} m distance and crown_factor {s['crown_factor']:g} rules; "
          f"{100 * s['crown_overlap_share']:.1f} % with a neighbour's trunk in their crown), "
          f"{s['n_branches']} branches, {s['n_leaves']} leaves; "
          f"instancing {'on: ' + str(s['n_prototypes']) + ' prototypes' if s['instancing'] else 'off'}")
    for sp in s["species"]:
        short = "" if sp["count_reached"] else f"; SHORT of its target {sp['target_count']}"
        print(f"  {sp['name']:<16} {sp['count']:>7} trees, {sp['density_per_ha']:.2f}/ha  (requested "
              f"{sp['requested_count']:.1f}, {sp['requested_density_per_ha']:.2f}/ha, as the "
              f"{sp['count_mode']} count; {sp['candidates_drawn']} candidates drawn at "
              f"{sp['candidate_factor']:.2f}×λ, {sp['removed_by_thinning']} removed{short})")
        th = sp["thinning"]
        print(f"  {'':<16} thinning: expected ∫λ {th['expected']:.1f}, drawn {th['drawn']}, "
              f"removed {th['removed']}, final {th['final']} ({th['final_minus_expected']:+.1f})")
    fo = s["foliage"]
    for sp in fo["species"]:
        if sp["n_trees"]:
            needle = (f"; needle area {sp['needle_area_m2']:.0f} m², crown needle LAI "
                      f"{sp['crown_needle_lai']:.2f}" if "needle_area_m2" in sp else "")
            print(f"  {sp['name']:<16} leaves {sp['mean_leaf_area_per_tree_m2']:.0f} m² a tree, crown "
                  f"LAI {sp['crown_lai']:.2f}, domain LAI {sp['domain_lai']:.3f}{needle}")
    print(f"stand LAI {fo['lai']:.3f} over the domain, {fo['lai_over_crowns'] or 0:.2f} over the "
          f"{fo['crown_union_m2']:.0f} m² of crowns (needle-area LAI {fo['needle_lai']:.3f})")
    if "truth_rasters" in s:
        t, g = s["truth_rasters"], s["truth_rasters"]["grid"]
        print(f"truth rasters: {g['nx']} × {g['ny']} cells of {g['cell_m']:g} m, {t['subsamples']}² rays a "
              f"cell; {t['n_overtopped']} of {t['n_trees']} trees overtopped; CRS {t['crs']}")
    print(f"leaf table: {s['leaf_table']}, export: {s['export']}; seconds: "
          + ", ".join(f"{k} {v:.2f}" for k, v in s["seconds"].items()))
    for path in run.files.values():
        print(f"wrote {path}")
    return 0


def _truth_args(p: argparse.ArgumentParser) -> None:
    _scene_args(p)
    p.add_argument("--out", required=True, metavar="DIR",
                   help="output folder: truth.nc, truth_summary.csv, truth_profiles.png")
    p.add_argument("--voxel", type=_opt(float, "truth.voxel_m"), default=None, metavar="M",
                   help="voxel side in metres (same as --set truth.voxel_m=M; default 0.1)")


@command("truth", "Exact canopy ground truth of a scene on a voxel grid: leaf/wood area, wood "
         "volume, LAD, PAD, LAI, canopy profiles, TRV, LWA", _truth_args)
def _truth_run(args: argparse.Namespace) -> int:
    from .config import Override
    from .truth.run import run_truth
    # errors in it name the option typed, not a --set or the scene's key
    extra = [Override(f"truth.voxel_m={args.voxel!r}", f"--voxel {args.voxel!r}")] if args.voxel is not None else []
    run = run_truth(args.scene, args.out, _overrides(args) + extra, progress=True)
    for row in run.summary:
        if row["quantity"] in ("total_leaf_area_m2", "total_wood_area_m2", "total_wood_volume_m3",
                               "LAI", "mean_canopy_height_m", "mean_canopy_width_m", "TRV_m3_ha",
                               "LWA_m2_ha"):
            v = row["value"]
            print(f"{row['quantity']:<22} {v:.6g} {row['unit']}" if isinstance(v, float)
                  else f"{row['quantity']:<22} {v or '-'} {row['unit']}")
    for path in run.files.values():
        print(f"wrote {path}")
    return 0


def _evaluate_args(p: argparse.ArgumentParser) -> None:
    _scene_args(p)
    p.add_argument("--out", required=True, metavar="DIR",
                   help="output folder: scores.csv/json, profiles.csv/png, scatter.png, truth.nc, "
                        "estimates/*.nc, grid.nc, scan/")
    p.add_argument("--estimator", action="append", default=[], metavar="MODULE:FUNC",
                   help="also score f(scan_dir, grid) -> Dataset or dict with PAD_m2_m3 (repeatable; "
                        "MODULE may be a .py path)")
    p.add_argument("--estimator-cmd", action="append", default=[], metavar="CMD",
                   help='also score a command writing a grid NetCDF, e.g. "python my.py {las} {grid} {out}" '
                        "(placeholders {las} {exr} {grid} {out}; repeatable)")
    p.add_argument("--voxel", type=_opt(float, "truth.voxel_m"), default=None, metavar="M",
                   help="voxel side in metres (default [truth] voxel_m, 0.1)")
    p.add_argument("--row-spacing", type=_opt(float, "truth.row_spacing_m"), default=None, metavar="M",
                   help="row spacing in metres: adds TRV and LWA (truth and point cloud) to scores.json")
    p.add_argument("--weights", choices=("equal", "energy"), default="equal",
                   help="echo weights of the multi-return estimators (scans with a [sensor])")
    p.add_argument("--min-beams", type=_opt(float, "[0, 1e9]", "beams per voxel"), default=5.0, metavar="N",
                   help="beams that must enter a voxel for it to be scored and for a beam-based estimate (default 5)")
    p.add_argument("--G", dest="G", type=_opt(float, "(0, 1]", "a mean projection"), default=0.5, metavar="G",
                   help="mean projection of unit plant area along the beams (default 0.5: spherical leaf angles)")


@command("evaluate", "Scan a scene, compute its canopy truth, run LiDAR estimators (built-in and "
         "plug-in) and score them per voxel and per height bin", _evaluate_args)
def _evaluate_run(args: argparse.Namespace) -> int:
    from .truth.evaluate import evaluate

    run = evaluate(args.scene, args.out, _overrides(args), estimators=args.estimator,
                   commands=args.estimator_cmd, voxel_m=args.voxel, row_spacing_m=args.row_spacing,
                   weights=args.weights, min_beams=args.min_beams, G=args.G, progress=True)
    print(f"{'estimator':<26} {'scale':<8} {'n':>7} {'cover':>6} {'R2':>7} {'RMSE':>8} {'bias':>8}  "
          "(PAD m2/m3; abstentions as 0; cover: share of true area estimated)")
    for r in run.scores:
        print(f"{r['estimator']:<26} {r['scale']:<8} {r['n']:>7} {100 * r['coverage_area']:5.1f}% {r['r2']:7.3f} "
              f"{r['rmse']:8.3f} {r['bias']:+8.3f}")
    print(f"wrote {args.out}/scores.csv and {len(run.files) - 1} more outputs")
    return 0


_register_canopy(command, _scene_args, _overrides)  # gapfraction, fisheye, evaluate-photo, compare, synthetic-photo (cli_canopy.py)


class _Parser(argparse.ArgumentParser):
    """argparse with one line on a usage error, ``simlidar-mi CMD: error: argument --x: ...``
    (exit 2), like every other error; ``--help`` shows the usage."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message}\n")


def build_parser() -> argparse.ArgumentParser:
    from ._version import __version__
    p = _Parser(prog="simlidar-mi", description=__doc__.splitlines()[0])
    p.add_argument("--version", action="version", version=f"simlidar-mi {__version__}")
    sub = p.add_subparsers(dest="command", required=True)
    for name, help_, add_args, run in COMMANDS:
        sp = sub.add_parser(name, help=help_, description=help_)
        add_args(sp)
        sp.set_defaults(_run=run)
    return p


def main(argv: list[str] | None = None) -> int:
    """Run one command; its exit status: 0, 2 on an error (one line), 130 on Ctrl-C, 143
    on SIGTERM (one line each).

    With ``argv`` None (the program's own command line) an interrupted run ends the
    process at once, after cleaning up: interpreter shutdown with Mitsuba's threads
    stopped mid-work can abort (rc 134) instead of exiting 130.  A finished run ends the
    same way (:func:`_exit_now`): its files are closed and in place by then, and the
    interpreter's teardown of Mitsuba, Dr.Jit and the arrays took 0.1 s after a scan."""
    from ._runtime.signals import raise_on_interrupt, received, start_program

    if argv is None:  # the program itself, not a caller's main([...]): process-wide settings
        start_program()
    args = build_parser().parse_args(argv)
    out = getattr(args, "out", None)
    if isinstance(out, str) and not out.strip():  # an empty path would silently mean the current folder
        print(f"simlidar-mi {args.command}: error: --out {out!r} names no output: give a path ('.' for "
              "the current folder)", file=sys.stderr)
        return 2
    raise_on_interrupt()  # from here Ctrl-C and SIGTERM unwind, so staging folders and locks go
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("always", SimlidarWarning)
            warnings.showwarning = _one_line_warning(args.command)
            _check_work(args)
            rc = args._run(args)
    except KeyboardInterrupt as exc:
        return _interrupted(args.command, exc, argv)
    except BrokenPipeError:  # stdout's reader left (`| head`): the files are written; say no more
        # (before `except Exception`, which it is)
        _silence_stdout()
        rc = 0
    except Exception as exc:
        if received() is not None:  # a library turned our KeyboardInterrupt into its own error
            return _interrupted(args.command, None, argv)
        if not isinstance(exc, SimlidarError):
            raise
        print(f"simlidar-mi {args.command}: error: {exc}", file=sys.stderr)
        rc = 2
    if argv is None:
        _exit_now(int(rc or 0))
    return int(rc or 0)


def _check_work(args: argparse.Namespace) -> None:
    """Refuse, before anything is built, a command whose work estimated from its scene's keys
    exceeds the budget (:func:`simlidar_mi.config.work.check_work`). A scene that does not
    load is left to the command, which reports it as it always has."""
    from .config.work import COMMAND_WORK, check_work
    if args.command not in COMMAND_WORK or getattr(args, "scene", None) is None:
        return
    from .config import load_scene
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the command's own load shows them once
            cfg = load_scene(args.scene, _overrides(args))
    except SimlidarError:
        return
    check_work(cfg, args.command)


def _silence_stdout() -> None:
    """Send whatever else is printed to stdout (and its flush at exit) to /dev/null: the pipe's
    reader is gone, and a second BrokenPipeError at exit would print a traceback."""
    import os  # noqa: PLC0415
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    except (OSError, ValueError):  # stdout has no file descriptor (a caller's StringIO)
        pass


def _interrupted(command: str, exc: BaseException | None, argv: list[str] | None) -> int:
    """One line, then 130 (Ctrl-C) or 143 (SIGTERM); the program itself ends at once."""
    import signal  # noqa: PLC0415

    from ._runtime.signals import Terminated, exit_status, received  # noqa: PLC0415
    if exc is None:
        exc = Terminated() if received() == signal.SIGTERM else KeyboardInterrupt()
    word, rc = exit_status(exc)
    if argv is None:  # a second Ctrl-C now would print a traceback over the one line
        for signum in (signal.SIGINT, signal.SIGTERM):
            signal.signal(signum, signal.SIG_IGN)
    print(f"simlidar-mi {command}: {word}", file=sys.stderr)
    if argv is None:
        _flush_and_exit(rc)
    return rc


def _exit_now(rc: int) -> None:
    """End the process with ``rc`` after the exit handlers (``atexit``: logging, Dask,
    temporary folders) but without the interpreter's teardown of every module and object
    (BENCHMARKS.md §8e).  Only for the program's own command line: a caller of
    :func:`main` gets its return value."""
    import atexit  # noqa: PLC0415
    import threading  # noqa: PLC0415
    for thread in threading.enumerate():  # as a normal exit does first: wait for the others
        if thread is not threading.current_thread() and not thread.daemon:
            thread.join()
    atexit._run_exitfuncs()  # then the exit handlers
    _flush_and_exit(rc)


def _flush_and_exit(rc: int) -> None:
    import os  # noqa: PLC0415
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):  # a closed pipe: nothing more can be said
            pass
    os._exit(rc)


def _one_line_warning(command: str):
    """``warnings.showwarning`` printing our warnings as ``simlidar-mi CMD: warning: ...``."""
    default = warnings.showwarning

    def show(message, category, filename, lineno, file=None, line=None):
        if issubclass(category, SimlidarWarning):
            print(f"simlidar-mi {command}: warning: {message}", file=sys.stderr)
        else:
            default(message, category, filename, lineno, file, line)
    return show


if __name__ == "__main__":
    sys.exit(main())
