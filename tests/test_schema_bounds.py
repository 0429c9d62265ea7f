"""Sizes bounded from the schema (issue 29 §3), tests generated from it: every number-valued key
of every section is driven to its bounds, past them and to NaN and ±infinity, every numeric
command-line option too, and each command's work estimate refuses what would outgrow the machine
with one line naming the key that sizes it.

The bulk runs in-process (load_scene, argparse, :func:`simlidar_mi.config.work.check_work`); the
issue's list of cases runs as real ``simlidar-mi`` processes under an address-space limit
(RLIMIT_AS) with a timeout that only stops a hang.  The counts of trials are in
docs/guide/faults.md and BENCHMARKS.md §15.
"""
from __future__ import annotations

import argparse
import copy
import json
import math
import subprocess
import sys
import warnings

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from simlidar_mi.config import load_scene
from simlidar_mi.config.bounds import BOUNDS, NOT_NUMERIC, numbers, numeric
from simlidar_mi.config.keys import ARRAY_SECTIONS, SECTIONS
from simlidar_mi.config.work import COMMAND_WORK, check_work
from simlidar_mi.errors import ConfigError
from tests.conftest import SCENES

#: A value of the right shape for the list keys whose default is None (the bound is put into
#: its first number).
EXAMPLES = {
    "scene.origin_m": [0.0, 0.0, 0.0], "platform.position_m": [0.0, 0.0, 1.0],
    "platform.waypoints_m": [[0.0, 0.0, 1.0], [1.0, 0.0, 1.0]], "platform.scan_legs": [0],
    "platform.start_xy_m": [0.0, 0.0], "platform.end_xy_m": [10.0, 0.0],
    "platform.azimuth_range_deg": [-135.0, -45.0],
    "strawberry.extraction_fractions": [0.1, 0.1], "strawberry.extraction_counts": [1, 2],
    "fisheye.coeffs": [1.0], "fisheye.area_m": [0.0, 0.0, 1.0, 1.0],
    "fisheye.transect_m": [0.0, 0.0, 1.0, 1.0], "fisheye.points_m": [[0.5, 0.5]],
    "primitive.p0_m": [0.0, 0.0, 0.0], "primitive.p1_m": [0.0, 0.0, 1.0],
    "primitive.min_m": [0.0, 0.0, 0.0], "primitive.max_m": [1.0, 1.0, 1.0],
    "species.bumps": [{"C_per_m2": 0.01, "x0_m": 0.0, "y0_m": 0.0, "h_m2": 1.0, "l_m2": 1.0}],
    "orchard.leaves.angle_distribution": [[45.0, 1.0], [90.0, 1.0]],
    "terrain.extent_m": [-10.0, 10.0, -10.0, 10.0], "terrain.centre_m": [0.0, 0.0],
    "terrain.hills_m": [[0.0, 0.0, 1.0, 1.0]],
}
#: What an [[array]] table needs besides the key under test.
ARRAY_BASE = {"primitive": {"type": "box", "min_m": [0.0, 0.0, 0.0], "max_m": [1.0, 1.0, 1.0]},
              "species": {"name": "a", "preset": "small-tree"}}


def _keys():
    """(dotted, Key, array?) of every number-valued key, in the schema's order."""
    for tables, array in ((SECTIONS, False), (ARRAY_SECTIONS, True)):
        for section, keys in tables.items():
            for name, key in keys.items():
                dotted = f"{section}.{name}"
                if dotted not in NOT_NUMERIC and numeric(key.types, EXAMPLES.get(dotted, key.default)):
                    yield dotted, key, array


KEYS = list(_keys())


def toml(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return "nan" if math.isnan(v) else ("inf" if v > 0 else "-inf") if math.isinf(v) else repr(v)
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, list):
        return "[" + ", ".join(toml(x) for x in v) + "]"
    return "{" + ", ".join(f"{k} = {toml(x)}" for k, x in v.items()) + "}"


def _scene(dotted: str, array: bool, value) -> str:
    section, _, leaf = dotted.rpartition(".")
    if array:
        table = {**ARRAY_BASE[section], leaf: value}
        return f"[[{section}]]\n" + "".join(f"{k} = {toml(v)}\n" for k, v in table.items())
    return f"[{section}]\n{leaf} = {toml(value)}\n"


def _placed(key, dotted: str, x):
    """The key's value holding ``x``: ``x`` itself, or its example list with ``x`` as the
    first number (an int where the list holds ints)."""
    if not (list in key.types and not isinstance(key.default, (int, float))) or (
            key.types == (int, float, list)):
        return x
    base = copy.deepcopy(EXAMPLES.get(dotted, key.default))
    path, first = next(numbers(base))
    if isinstance(first, int) and isinstance(x, float) and math.isfinite(x) and x.is_integer():
        x = int(x)
    target, parts = base, [p for p in path.replace("]", "").replace(".", "[").split("[") if p]
    for p in parts[:-1]:
        target = target[int(p)] if isinstance(target, list) else target[p]
    last = parts[-1]
    if isinstance(target, list):
        target[int(last)] = x
    else:
        target[last] = x
    return base


def _is_int(key, dotted) -> bool:
    if int in key.types and float not in key.types:
        return list not in key.types or key.types == (int, str)
    if list in key.types:
        example = EXAMPLES.get(dotted, key.default)
        return all(isinstance(x, int) for _, x in numbers(example))
    return False


def _edges(key, dotted):
    """(inside values, outside values) of the key's range: its two ends (or the nearest value
    inside an open end), the nearest values past them, NaN, +inf, -inf."""
    b = key.range
    if _is_int(key, dotted):
        lo, hi = int(math.ceil(b.lo)) + b.lo_open * (b.lo == int(b.lo)), int(math.floor(b.hi)) - b.hi_open * (b.hi == int(b.hi))
        return [lo, hi], [lo - 1, hi + 1, math.nan, math.inf]
    lo = float(np.nextafter(b.lo, math.inf)) if b.lo_open else float(b.lo)
    hi = float(np.nextafter(b.hi, -math.inf)) if b.hi_open else float(b.hi)
    below = float(b.lo) if b.lo_open else float(np.nextafter(b.lo, -math.inf))
    above = float(b.hi) if b.hi_open else float(np.nextafter(b.hi, math.inf))
    return [lo, hi], [below, above, math.nan, math.inf, -math.inf]


def _load(dotted, array, value):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return load_scene(text=_scene(dotted, array, value))


def _refused(dotted, array, value) -> ConfigError:
    with pytest.raises(ConfigError) as e:
        _load(dotted, array, value)
    err = e.value
    assert "\n" not in str(err) and err.key.startswith(dotted.rpartition(".")[0]), (dotted, value, str(err))
    assert err.key.split(".")[-1] == dotted.rpartition(".")[2] or err.key.endswith(dotted.rpartition(".")[2]), str(err)
    return err


# --- (a) the schema: every number-valued key has a finite range -------------------------
def test_every_number_valued_key_has_a_finite_range():
    missing = [d for d, k, _ in KEYS if k.range is None]
    assert not missing
    assert len(KEYS) >= 220  # 190 scalar numbers and ~30 lists of numbers when this was written
    for dotted, key, _ in KEYS:
        assert math.isfinite(key.range.lo) and math.isfinite(key.range.hi) and key.range.why, dotted
        assert key.default is None or key.range.complaint(key.default) is None, dotted  # defaults inside
    assert set(BOUNDS) == {d for d, *_ in KEYS}


# --- (b) every key at its bounds, past them, NaN and infinity ------------------------------
@pytest.mark.parametrize("dotted, key, array", KEYS, ids=[d for d, *_ in KEYS])
def test_each_key_at_its_bounds_is_read_and_past_them_is_one_line(dotted, key, array):
    inside, outside = _edges(key, dotted)
    for x in inside:
        try:
            _load(dotted, array, _placed(key, dotted, x))
        except ConfigError as exc:  # another rule of the key (max > min, a cross-key rule)
            assert "range [" not in exc.reason and "range (" not in exc.reason, (dotted, x, exc.reason)
    for x in outside:
        err = _refused(dotted, array, _placed(key, dotted, x))
        if isinstance(x, float) and math.isnan(x) and _is_int(key, dotted) and not array:
            continue  # NaN for an integer: a type error, one line too
        assert "range" in err.reason or "expected" in err.reason, (dotted, x, err.reason)


# --- (c) random values around every range (hypothesis) -------------------------------------
@settings(max_examples=600, deadline=None, suppress_health_check=[HealthCheck.too_slow],
          derandomize=True)
@given(st.sampled_from(KEYS), st.one_of(st.floats(allow_nan=True, allow_infinity=True),
                                       st.integers(-2 ** 63, 2 ** 63 - 1)))
def test_any_number_in_any_key_is_read_or_refused_in_one_line(item, x):
    dotted, key, array = item
    value = _placed(key, dotted, x)
    try:
        cfg = _load(dotted, array, value)
    except ConfigError as exc:
        assert "\n" not in str(exc)
        return
    # read: then every number in it lies in the key's range
    section, _, leaf = dotted.rpartition(".")
    got = cfg.arrays[section][0][leaf] if array else cfg[section][leaf]
    assert key.range.complaint(got) is None, (dotted, got)


# --- (d) every numeric command-line option ---------------------------------------------------
def _numeric_options():
    from simlidar_mi.cli import build_parser
    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    for name, p in sub.choices.items():
        for a in p._actions:
            if a.type in (int, float) and not a.choices:  # a list of choices is its own check
                yield name, a, None
            elif hasattr(a.type, "bounds"):
                yield name, a, a.type.bounds


OPTIONS = list(_numeric_options())


def test_every_numeric_option_has_a_checked_range():
    unchecked = [(c, a.option_strings) for c, a, b in OPTIONS if b is None]
    assert not unchecked
    assert len(OPTIONS) >= 19


@pytest.mark.parametrize("command, action, bounds", OPTIONS,
                         ids=[f"{c}{a.option_strings[0]}" for c, a, _ in OPTIONS])
def test_each_option_past_its_range_or_nan_is_one_line_exit_2(command, action, bounds, capsys):
    from simlidar_mi.cli import build_parser
    opt = action.option_strings[-1]
    needs = {"fisheye-photo": ["x.jpg", "--out", "o"], "photo-gap": ["x.jpg", "--method", "canopeo"],
             "derive": ["-n", "3"], "measure": [], "preview": ["s.toml"], "study": ["s.toml", "--out", "o"],
             "evaluate-als": ["s.toml", "--points", "p.las", "--out", "o"]}
    base = needs.get(command, ["s.toml", "--out", "o"])
    is_list = action.type.__name__ == "numbers"
    n = 3 if opt == "--circle" else 1
    above = bounds.hi if bounds.hi_open else (int(bounds.hi) + 1 if action.type.__name__ == "int" else
                                              float(np.nextafter(bounds.hi, math.inf)))
    below = bounds.lo if bounds.lo_open else (int(bounds.lo) - 1 if action.type.__name__ == "int" else
                                              float(np.nextafter(bounds.lo, -math.inf)))
    inside = bounds.hi if not bounds.hi_open else float(np.nextafter(bounds.hi, -math.inf))
    fmt = (lambda v: ",".join([repr(v)] * n)) if is_list else (
        lambda v: str(v) if isinstance(v, int) else str(int(v)) if action.type.__name__ == "int" and
        math.isfinite(v) else repr(v))
    args = build_parser().parse_args([command, *base, opt, fmt(inside)])  # the bound itself is read
    assert getattr(args, action.dest) is not None
    for v in (above, below, math.nan, math.inf, 1e9 if not bounds.holds(1e9) else -1e300):
        with pytest.raises(SystemExit) as e:
            build_parser().parse_args([command, *base, opt, fmt(v)])
        err = capsys.readouterr().err.strip().splitlines()
        assert e.value.code == 2 and len(err) == 1, err
        assert err[0].startswith(f"simlidar-mi {command}: error: argument ") and opt in err[0], err


# --- (e) the work each command estimates from the keys ----------------------------------------
GB = 1 << 30
#: (command, scene, overrides, the key named): the issue's list of unbounded runs, each key
#: inside its own range and the product past a 4 GiB budget or scan.max_rays.
WORK = [
    ("measure", "apple_orchard.toml", ["orchard.n_trees=10000"], "orchard.n_trees"),
    ("measure", "apple_orchard.toml", ["orchard.tree.iterations=10"], "orchard.tree.iterations"),
    ("gapfraction", "strawberry_plot.toml", ["strawberry.rows=100000"], "strawberry.rows"),
    ("gapfraction", "strawberry_plot.toml", ["strawberry.plants_per_row=100000"], "strawberry.plants_per_row"),
    ("gapfraction", "random_leaves_spherical.toml", ["gapfraction.replicates=10000"], "gapfraction.replicates"),
    ("gapfraction", "random_leaves_spherical.toml", ["gapfraction.resolution=16384"], "gapfraction.resolution"),
    ("gapfraction", "random_leaves_spherical.toml", ["gapfraction.spp=4096"], "gapfraction.spp"),
    ("gapfraction", "random_leaves_spherical.toml", ["random_leaves.n_leaves=1000000000"],
     "random_leaves.n_leaves"),
    ("synthetic-photo", "random_leaves_spherical.toml", ["photo_render.max_depth=64"], "photo_render.max_depth"),
    ("synthetic-photo", "random_leaves_spherical.toml", ["photo_render.spp=4096"], "photo_render.spp"),
    ("forest", "forest_airborne_echoes.toml", ["forest.domain_m=[0, 1e7, 0, 1e7]"], "forest.domain_m"),
    ("fisheye", "random_leaves_spherical.toml", ["fisheye.grid_n=[1000, 1000]"], "fisheye.grid_n"),
    ("fisheye", "random_leaves_spherical.toml", ["fisheye.resolution=16384"], "fisheye.resolution"),
    ("fisheye", "random_leaves_spherical.toml", ["fisheye.spp=4096"], "fisheye.spp"),
    ("evaluate-photo", "random_leaves_spherical.toml", ['lai_methods.sampler="rays"',
                                                        "lai_methods.rays_per_cell=10000000"],
     "lai_methods.rays_per_cell"),
]


@pytest.mark.parametrize("command, scene, overrides, key", WORK, ids=[w[3] for w in WORK])
def test_work_past_the_budget_names_the_key_that_sizes_it(command, scene, overrides, key):
    cfg = _load_file(scene, overrides)
    with pytest.raises(ConfigError) as e:
        check_work(cfg, command, memory=4 * GB)
    assert e.value.key == key and e.value.file == f"--set {next(o for o in overrides if o.startswith(key))}"
    assert "\n" not in str(e.value) and ("GB" in e.value.reason or "rays" in e.value.reason)


def _load_file(scene, overrides):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return load_scene(SCENES / scene, overrides)


@pytest.mark.parametrize("scene", sorted(p.name for p in SCENES.glob("*.toml")))
def test_the_included_scenes_fit_the_budget_of_a_4_gib_machine(scene):
    cfg = _load_file(scene, [])
    for command in COMMAND_WORK:
        check_work(cfg, command, memory=2 * GB)


def test_the_estimate_counts_what_is_generated():
    """The estimates' per-element counts against the generators: an apple tree's segments at 5
    and 6 generations, a strawberry plant's triangles per leaf (within the estimate's margin)."""
    from simlidar_mi.config import work
    from simlidar_mi.lidar import survey
    from simlidar_mi.truth.run import truth_geometry
    for it in (5, 6):
        g = survey.generate(_load_file("apple_orchard.toml", ["orchard.n_trees=1", f"orchard.tree.iterations={it}"]))
        est = work.SEGMENTS_AT_5 * work.GROWTH ** (it - 5)
        assert 0.8 * est <= len(g.branches) <= est, (it, len(g.branches), est)
    g, _ = truth_geometry(_load_file("strawberry_plot.toml", ["strawberry.rows=1", "strawberry.plants_per_row=2"]))
    s = _load_file("strawberry_plot.toml", [])["strawberry"]
    assert len(g.leaves) <= 2 * (s["leaves_per_plant_mean"] + 3 * s["leaves_per_plant_sd"]) * \
        work.TRIANGLES_PER_STRAWBERRY_LEAF


# --- (f) the issue's cases as real processes, memory and time bounded ------------------------
CLI_CASES = [(c, s, o, k) for c, s, o, k in WORK] + [
    ("measure", "apple_orchard.toml", ["orchard.n_trees=1000000000"], "orchard.n_trees"),
    ("gapfraction", "strawberry_plot.toml", ["strawberry.rows=1000000000"], "strawberry.rows"),
    ("gapfraction", "random_leaves_spherical.toml", ["random_leaves.n_leaves=1000000000000"],
     "random_leaves.n_leaves"),
    ("fisheye", "random_leaves_spherical.toml", ["fisheye.grid_n=[3000, 3000]"], "fisheye.grid_n"),
    ("fisheye", "random_leaves_spherical.toml", ["fisheye.n_sectors=1000000000"], "fisheye.n_sectors"),
    ("measure", "apple_orchard.toml", ["scene.facets=1000000"], "scene.facets"),
    ("scan", "forest_airborne_echoes.toml", ["sensor.beam_samples=4096"], "sensor.beam_samples"),
]
LIMIT_AS = 3 * GB


def _limit():
    import resource
    resource.setrlimit(resource.RLIMIT_AS, (LIMIT_AS, LIMIT_AS))


def test_the_issues_cases_end_in_one_line_exit_2_within_a_memory_limit(tmp_path):
    """Each case of the issue's list as ``simlidar-mi`` itself under a 3 GiB address-space
    limit: one line naming the key, exit 2, nothing written (the timeout only stops a hang)."""
    from pathlib import Path
    program = Path(sys.executable).parent / "simlidar-mi"
    running = []
    for i, case in enumerate(CLI_CASES):
        command, scene, overrides, key = case
        out = [] if command == "measure" else ["--out", str(tmp_path / f"o{i}")]
        sets = [a for o in overrides for a in ("--set", o)]
        running.append((case, subprocess.Popen([str(program), command, str(SCENES / scene), *out, *sets],
                                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                               preexec_fn=_limit)))
        if len(running) == 2 or i == len(CLI_CASES) - 1:  # two at a time: a 2-core machine
            for case, p in running:
                _, err = p.communicate(timeout=300)
                lines = err.strip().splitlines()
                assert p.returncode == 2 and len(lines) == 1, (case, err[-2000:])
                assert f"key '{case[3]}'" in lines[0], (case, lines)
            running = []
    assert not any(tmp_path.iterdir())
