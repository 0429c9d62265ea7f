"""Command line: the canopy-camera sub-commands (``gapfraction``, ``fisheye``, ``fisheye-photo``,
``evaluate-photo``, ``compare``, ``synthetic-photo``) and ``evaluate-als``.

Kept beside cli.py so that neither grows past the module size limit; cli.py calls
:func:`register` with its ``command`` decorator and shared argument helpers (passed in, so this
module never imports cli.py: no import cycle).
"""
from __future__ import annotations

import argparse
import functools


class checked:  # noqa: N801  (used as an argparse type=, like int)
    """An argparse ``type=`` from :mod:`simlidar_mi.config.bounds` (``factory`` "option" or
    "option_list"; ``key`` appends that scene key's interval and reason), built when first used:
    importing the config loads numpy, which must not happen while the parser is built (an early
    Ctrl-C would then not know its command)."""

    def __init__(self, factory: str, *args, key: str | None = None, **kw):
        self._spec = (factory, args, key, kw)
        self.__name__ = args[0].__name__ if factory == "option" else "numbers"  # as bounds names them

    @functools.cached_property
    def _convert(self):
        from .config import bounds  # noqa: PLC0415
        factory, args, key, kw = self._spec
        return getattr(bounds, factory)(*args, *(bounds.BOUNDS[key] if key else ()), **kw)

    @property
    def bounds(self):
        return self._convert.bounds

    def __call__(self, text: str):
        return self._convert(text)


def r_note(stats) -> str:
    """The line under ``compare``'s table saying why r shows "-" where it does: r is Pearson's
    correlation of measured against virtual P0 across one zenith's rows (the strawberry paper's:
    across its four leaf densities), so a zenith with one row, or with rows whose values do not
    vary, has none."""
    import math  # noqa: PLC0415
    undefined = [s for s in stats if not math.isfinite(s["r"])]
    if not undefined:
        return "r: Pearson's r of measured against virtual P0 across each zenith's rows"
    one = [s for s in undefined if s["n"] < 2]

    def zeniths(ss):
        return ", ".join(f"'{s['zenith_deg']}' (the zeniths pooled)" if isinstance(s["zenith_deg"], str)
                         else f"{s['zenith_deg']:g}°" for s in ss)
    parts = []
    if one:
        parts.append(f"one row at {zeniths(one)}")
    if len(one) < len(undefined):
        parts.append(f"values that do not vary at {zeniths([s for s in undefined if s['n'] >= 2])}")
    return ("r: '-' where it is undefined (" + "; ".join(parts) + "): r correlates measured and "
            "virtual P0 across one zenith's rows, so it needs two or more rows there, e.g. one per "
            "extraction step (the paper's Table 5: its four leaf densities)")


def register(command, scene_args, overrides) -> None:
    """Register this module's sub-commands through cli.py's ``command`` decorator."""

    def image_args(p: argparse.ArgumentParser, out_help: str, tables: str) -> None:
        scene_args(p)
        p.add_argument("--out", required=True, metavar="DIR", help=out_help)
        p.add_argument("--no-images", action="store_true", help=f"write only the {tables}")

    def _gapfraction_args(p: argparse.ArgumentParser) -> None:
        image_args(p, "output folder: gap_fraction.csv, gap_fraction.json, a mask PNG and a "
                      "coverage EXR per image", "CSV and JSON")

    @command("gapfraction", "Gap-fraction images (orthographic/perspective, 0/15/30°) of a "
             "random_leaves or strawberry scene: P0 table, masks, coverage EXRs", _gapfraction_args)
    def _gapfraction_run(args: argparse.Namespace) -> int:
        from .canopy.gapfraction import run_gapfraction

        run = run_gapfraction(args.scene, args.out, overrides(args), write_images=not args.no_images,
                              progress=True)
        n = len(run.replicate_images)
        print(f"p0: mean over {n} replicate plot{'s' if n > 1 else ''}; p0_sd: its seed-to-seed SD "
              f"(the SD between plots / √{n})")
        print(f"{'camera':<12}  {'zenith':>6}  {'step':>4}  {'p0':>7}  {'p0_sd':>7}  {'lai':>6}  "
              f"{'spp':>4}  {'size':>10}  {'seconds':>7}")
        for s in run.summary:
            print(f"{s.camera:<12}  {s.zenith_deg:>6g}  {s.step:>4}  {s.p0:7.4f}  {s.p0_sd:7.4f}  "
                  f"{s.lai:6.3f}  {s.spp:>4}  {f'{s.width}x{s.height}':>10}  {s.seconds:7.3f}")
        print(f"wrote {run.files['csv']} and {len(run.files) - 3} image files")
        return 0

    def _fisheye_args(p: argparse.ArgumentParser) -> None:
        image_args(p, "output folder: fisheye_gap.csv, fisheye_positions.csv, and per camera "
                      "position a coverage EXR and a binary PNG", "CSV tables")

    @command("fisheye", "Virtual hemispherical photographs (fisheye, [fisheye] keys) at a grid or "
             "transect of positions: ring/sector gap-fraction table, coverage EXRs, binary PNGs",
             _fisheye_args)
    def _fisheye_run(args: argparse.Namespace) -> int:
        from .canopy.fisheye_run import fisheye_scene, run_fisheye
        from .config import load_scene
        from .truth.run import truth_geometry

        cfg = load_scene(args.scene, overrides(args))
        geometry, _ = truth_geometry(cfg)  # plants and primitives; a gap-fraction scene's canopy
        run = run_fisheye(cfg, fisheye_scene(cfg, geometry), geometry.bounds_m(), args.out,
                          write_images=not args.no_images, progress=True)
        lo, hi = run.tables[0].ring_lo_deg, run.tables[0].ring_hi_deg
        print("ring gap fraction (solid-angle weighted) per position")
        print(f"{'pos':>3}  {'x_m':>7}  {'y_m':>7}  {'z_m':>5}  " + "  ".join(f"{a:g}-{b:g}°".rjust(7) for a, b in zip(lo, hi)))
        for k, (img, tab) in enumerate(zip(run.images, run.tables)):
            x, y, z = img.camera.position_m
            print(f"{k:>3}  {x:7.2f}  {y:7.2f}  {z:5.2f}  " + "  ".join(f"{g:7.4f}" for g in tab.ring_gap))
        print(f"{len(run.images)} images, {run.seconds:.2f} s; wrote {run.files['csv']}")
        return 0

    def _fisheye_photo_args(p: argparse.ArgumentParser) -> None:
        p.add_argument("photos", nargs="+", metavar="PHOTO", help="fisheye photographs (JPEG, PNG, TIFF)")
        p.add_argument("--out", required=True, metavar="DIR",
                       help="output folder: fisheye_photo_gap.csv and a binary PNG per photo")
        p.add_argument("--lens", default="equidistant",
                       help="projection (equidistant, equisolid, orthographic, stereographic), a named "
                            "lens (FC-E8, Nikkor-10.5, Sigma-4.5, Sigma-8, FC-E9, Nikkor-8) or polynomial")
        p.add_argument("--coeffs", type=checked("option_list", key="fisheye.coeffs"), default=None, metavar="K1,K2,...",
                       help="polynomial lens: rho = sum k_i theta^i, theta in radians, rho relative to the circle")
        p.add_argument("--circle", type=checked("option_list", "[0, 1e6]", "pixels", sizes=(3,)), default=None, metavar="XC,YC,R",
                       help="image circle in pixels from the top-left corner (default: detected; "
                            "full frame: the half-diagonal)")
        p.add_argument("--format", default="circular", choices=("circular", "fullframe"),
                       help="circular image or full-frame (diagonal spans 180 degrees)")
        p.add_argument("--method", default="blue-otsu", choices=("blue-otsu", "canopeo"),
                       help="blue-otsu: sky vs canopy looking up; canopeo: green plants looking down")
        p.add_argument("--rings", type=checked("option_list", key="fisheye.rings_deg"), default=None, metavar="DEG,...",
                       help="zenith ring edges in degrees (default 0,15,30,45,60,75,90)")
        p.add_argument("--sectors", type=checked("option", int, key="fisheye.n_sectors"), default=8, metavar="N",
                       help="azimuth sectors (default 8)")
        p.add_argument("--heading", type=checked("option", float, key="fisheye.heading_deg"), default=90.0, metavar="DEG",
                       help="scene azimuth at the photo's top, counter-clockwise from +x (default 90: +y)")
        p.add_argument("--downscale", type=int, default=1, choices=(1, 2, 4, 8),
                       help="analyse the photo at 1/N of its size")
        p.add_argument("--lai", action="store_true",
                       help="also each photo's LAI by the gap-fraction methods of evaluate-photo "
                            "(Miller, Lang-Xiang, 57.5 degrees, LAI-2200): fisheye_photo_lai.csv")

    @command("fisheye-photo", "Ring/sector gap fractions of real fisheye photographs (the table of "
             "`fisheye`): circle, lens projection, classification", _fisheye_photo_args)
    def _fisheye_photo_run(args: argparse.Namespace) -> int:
        from .canopy.fisheye import DEFAULT_RINGS_DEG
        from .canopy.photo_fisheye import run_fisheye_photos

        results = run_fisheye_photos(args.photos, args.out, lens=args.lens, coeffs=args.coeffs,
                                     circle=args.circle, format=args.format, method=args.method,
                                     rings_deg=args.rings or DEFAULT_RINGS_DEG, n_sectors=args.sectors,
                                     heading_deg=args.heading, downscale=args.downscale, lai=args.lai)
        for r in results:
            xc, yc, rad = r.circle_px
            print(f"{r.path.name}: circle {xc:.1f},{yc:.1f},{rad:.1f} px{' (detected)' if r.detected else ''}, "
                  f"gap {r.gap_fraction:.4f}" + (f", blue threshold {r.threshold:g}" if r.threshold is not None else ""))
            print("  ring gap " + "  ".join(f"{a:g}-{b:g}°: {g:.4f}" for a, b, g in
                                            zip(r.table.ring_lo_deg, r.table.ring_hi_deg, r.table.ring_gap)))
            if r.lai is not None:
                print("  LAI " + "  ".join(f"{m}: {r.lai[m]:.3f}" for m in ("miller", "miller_lx", "hinge_57",
                                                                              "lai2200")))
        print(f"wrote {args.out}/fisheye_photo_gap.csv")
        return 0

    def _evaluate_photo_args(p: argparse.ArgumentParser) -> None:
        scene_args(p)
        p.add_argument("--out", required=True, metavar="DIR",
                       help="output folder: photo_scores.csv/json/png, photo_positions.csv")

    @command("evaluate-photo", "Run the gap-fraction LAI methods (Miller, 57.5°, Lang–Xiang, LAI-2200, "
             "Chen–Cihlar) at a scene's [fisheye] positions and score them against its truth",
             _evaluate_photo_args)
    def _evaluate_photo_run(args: argparse.Namespace) -> int:
        from .truth.photo_scores import evaluate_photo

        out = evaluate_photo(args.scene, args.out, overrides(args), progress=True)
        print(f"{'method':<12} {'target':<6} {'scale':<9} {'n':>4} {'cover':>6} {'truth':>7} "
              f"{'est':>7} {'bias':>7} {'RMSE':>7}   (LAI, PAI: m2/m2)")
        for r in out.scores:
            print(f"{r['method']:<12} {r['target']:<6} {r['scale']:<9} {r['n']:>4} "
                  f"{100 * r['coverage']:5.1f}% {r['truth_mean']:7.3f} {r['estimate_mean']:7.3f} "
                  f"{r['bias']:+7.3f} {r['rmse']:7.3f}")
        print(f"wrote {args.out}/photo_scores.csv and {len(out.files) - 1} more outputs")
        return 0

    def _compare_args(p: argparse.ArgumentParser) -> None:
        p.add_argument("manifest", metavar="MANIFEST.csv",
                       help="CSV pairing photos or measured P0 with scene, camera, zenith_deg, step "
                            "(see simlidar_mi.canopy.compare; example: scenes/strawberry_manifest.csv)")
        p.add_argument("--out", required=True, metavar="DIR",
                       help="output folder: comparison.csv, pairs.csv, readings.csv, comparison.png, masks")
        p.add_argument("--no-readings", dest="readings", action="store_false",
                       help="skip the second render of strawberry scenes under the other petiole reading "
                            "(readings.csv)")


    @command("compare", "Virtual vs measured gap fraction from a manifest: RMSE, bias and (with two "
             "or more rows per zenith) r per view zenith (the strawberry paper's Table 5) and the "
             "measured-vs-virtual plot (Fig. 4)",
             _compare_args)
    def _compare_run(args: argparse.Namespace) -> int:
        import math

        from .canopy.compare import compare

        res = compare(args.manifest, args.out, progress=True, readings=args.readings)
        print(f"{'row':>4}  {'camera':<12}  {'zenith':>6}  {'step':>4}  {'measured':>8}  "
              f"{'virtual':>7}  {'sd':>6}  {'sd/plot':>7}  {'reps':>4}  {'diff':>7}")
        for p in res.pairs:
            print(f"{p.row.row:>4}  {p.row.camera:<12}  {p.row.zenith_deg:>6g}  {p.row.step_label:>4}  "
                  f"{p.p0_measured:8.4f}  {p.p0_virtual:7.4f}  {p.p0_virtual_sd:6.4f}  "
                  f"{p.p0_virtual_sd_plot:7.4f}  {p.replicates:>4}  {p.difference:+7.4f}")

        def f(v, fmt):
            return "-" if not math.isfinite(v) else format(v, fmt)
        print(f"\n{'zenith':>6}  {'n':>3}  {'r':>6}  {'rmse':>7}  {'rmse_r':>7}  {'bias':>8}  "
              f"{'± se':>6}  {'bias_r':>7}  {'scatter':>7}  {'paper: rmse':>11}  {'bias':>6}  {'scatter':>7}")
        for s in res.stats:
            z = s["zenith_deg"] if isinstance(s["zenith_deg"], str) else f"{s['zenith_deg']:g}"
            print(f"{z:>6}  {s['n']:>3}  {f(s['r'], '.3f'):>6}  {s['rmse']:7.4f}  {s['rmse_r']:7.2%}  "
                  f"{s['bias']:+8.4f}  {f(s['bias_se'], '.4f'):>6}  {s['bias_r']:+7.2%}  "
                  f"{f(s['scatter'], '.4f'):>7}  {f(s['paper_rmse'], '.3f'):>11}  "
                  f"{f(s['paper_bias'], '.3f'):>6}  {f(s['paper_scatter'], '.4f'):>7}")
        print(r_note(res.stats))
        print("\n95 % intervals (bias: t, Welch-Satterthwaite df; rmse, r: bootstrap of the replicate plots)")
        for s in res.stats:
            z = s["zenith_deg"] if isinstance(s["zenith_deg"], str) else f"{s['zenith_deg']:g}"
            verdict = {"yes": "0 inside: the gap cannot be told from the noise",
                       "no": "0 outside: the gap is more than the noise"}.get(s["bias_inside_ci"], "no interval")
            print(f"{z:>6}  bias {f(s['bias_ci_low'], '+.4f')}…{f(s['bias_ci_high'], '+.4f')} "
                  f"(df {f(s['ci_df'], '.1f')})  rmse {f(s['rmse_ci_low'], '.4f')}…{f(s['rmse_ci_high'], '.4f')}  "
                  f"r {f(s['r_ci_low'], '.3f')}…{f(s['r_ci_high'], '.3f')}  [{s['ci_basis']}]  {verdict}")
        if res.readings:
            from .canopy.compare import PETIOLE_READINGS, READINGS_NOTE
            print(f"\nboth petiole readings (strawberry rows; the scenes' own: {res.own_reading}):")
            print(f"{'reading':<8}  {'zenith':>6}  {'n':>3}  {'bias':>8}  {'± se':>6}  {'rmse':>7}  what")
            for name, sts in res.readings.items():
                for s in sts:
                    z = s["zenith_deg"] if isinstance(s["zenith_deg"], str) else f"{s['zenith_deg']:g}"
                    print(f"{name:<8}  {z:>6}  {s['n']:>3}  {s['bias']:+8.4f}  {f(s['bias_se'], '.4f'):>6}  "
                          f"{s['rmse']:7.4f}  {PETIOLE_READINGS.get(name, '')}")
            print(READINGS_NOTE)
        print(f"wrote {', '.join(str(f) for f in res.files.values())}")
        return 0


    def _synthetic_photo_args(p: argparse.ArgumentParser) -> None:
        scene_args(p)
        p.add_argument("--out", required=True, metavar="DIR",
                       help="output folder: synthetic_photo.csv, photo and Canopeo-mask PNGs")


    @command("synthetic-photo", "Photo-like RGB renders of a gap-fraction scene's views, classified "
             "by Canopeo and checked against the coverage P0", _synthetic_photo_args)
    def _synthetic_photo_run(args: argparse.Namespace) -> int:
        from .canopy.synthetic_photo import run_synthetic_photos

        checks = run_synthetic_photos(args.scene, args.out, overrides(args), progress=True)
        print(f"{'camera':<12}  {'zenith':>6}  {'step':>4}  {'p0 coverage':>11}  {'p0 canopeo':>10}  {'diff':>7}")
        for c in checks:
            im = c.image
            print(f"{im.camera.kind:<12}  {im.camera.zenith_deg:>6g}  {im.step:>4}  {c.p0_coverage:11.4f}  "
                  f"{c.p0_canopeo:10.4f}  {c.p0_canopeo - c.p0_coverage:+7.4f}")
        print(f"wrote {args.out}/synthetic_photo.csv and {2 * len(checks)} PNG files")
        return 0

    def _evaluate_als_args(p: argparse.ArgumentParser) -> None:
        scene_args(p)
        p.add_argument("--points", required=True, metavar="LAS",
                       help="the scan's points (points.las of `scan`: its classification is the true class)")
        p.add_argument("--out", required=True, metavar="DIR",
                       help="output folder: als_scores.json, *_scores.csv, truth_*.tif, dtm_*.tif, chm_*.tif, PNGs")
        p.add_argument("--cell", type=checked("option", float, key="truth.raster_cell_m"), default=None, metavar="M",
                       help="raster cell in metres (default [truth] raster_cell_m, 0.5)")
        p.add_argument("--subsamples", type=checked("option", int, key="truth.raster_subsamples"), default=None,
                       metavar="K", help="K x K vertical truth rays a cell (default [truth] raster_subsamples, 8)")
        p.add_argument("--ground-method", action="append", default=[], metavar="MODULE:FUNC",
                       help="also score f(points) -> bool array (True: ground); points: dict of x, y, z, "
                            "return_number, number_of_returns, intensity (repeatable; MODULE may be a .py path)")
        p.add_argument("--tree-method", action="append", default=[], metavar="MODULE:FUNC",
                       help="also score f(chm, grid) -> (n, 3) tree tops x, y, height (repeatable)")
        p.add_argument("--max-distance", type=checked("option", float, "(0, 100]", "metres"), default=3.0,
                       metavar="M", help="largest horizontal distance of a matched tree pair (default 3 m)")
        p.add_argument("--max-height-diff", type=checked("option", float, "(0, 100]", "metres"), default=3.0,
                       metavar="M", help="largest height difference of a matched tree pair (default 3 m)")
        p.add_argument("--min-height", type=checked("option", float, "[0, 200]", "metres"), default=2.0,
                       metavar="M", help="lowest CHM height a detected tree may have (default 2 m)")
        p.add_argument("--no-images", action="store_true", help="write no PNGs")

    @command("evaluate-als", "Score ground filters (CSF, PMF), CHMs and tree detectors of an airborne "
             "scan against the scene's exact terrain, canopy and trees", _evaluate_als_args)
    def _evaluate_als_run(args: argparse.Namespace) -> int:
        from .truth.als_evaluate import evaluate_als

        run = evaluate_als(args.scene, args.points, args.out, overrides(args), ground_plugins=args.ground_method,
                           tree_plugins=args.tree_method, cell_m=args.cell, subsamples=args.subsamples,
                           max_distance_m=args.max_distance, max_height_diff_m=args.max_height_diff,
                           min_height_m=args.min_height, images=not args.no_images, progress=True)
        print(f"{'ground filter':<16} {'type I':>8} {'type II':>8} {'total':>8} {'kappa':>7} {'DTM RMSE':>9} "
              f"{'bias':>8}")
        for r in run.ground:
            print(f"{r['method']:<16} {r['type_I']:8.4f} {r['type_II']:8.4f} {r['total_error']:8.4f} "
                  f"{r['kappa']:7.4f} {r['dtm_rmse_m']:9.4f} {r['dtm_bias_m']:+8.4f}")
        for r in run.chm:
            print(f"CHM {r['chm']:<8} {r['stratum']:<7} RMSE {r['rmse_m']:.3f} m, bias {r['bias_m']:+.3f} m")
        print(f"{'tree detector':<24} {'rate':>6} {'prec.':>6} {'F':>6} {'h RMSE':>7} {'h bias':>7}")
        for r in run.trees:
            if r["group"] == "all":
                print(f"{r['method']:<24} {r['detection_rate']:6.3f} {r['precision']:6.3f} {r['f_score']:6.3f} "
                      f"{r['height_rmse_m']:7.3f} {r['height_bias_m']:+7.3f}")
        print(f"wrote {args.out}/als_scores.json and {len(run.files) - 1} more outputs")
        return 0
