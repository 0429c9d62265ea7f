"""Bad input refused before any work: scene text that would become a path, sizes bounded from
the keys before anything is allocated, nesting too deep for the parser, execution knobs kept
out of the scene's identity, and errors naming the option the user typed."""
from __future__ import annotations

import os
import tracemalloc
from types import SimpleNamespace

import pytest

from simlidar_mi.cli import main
from simlidar_mi.config import load_scene
from simlidar_mi.errors import ConfigError
from simlidar_mi.lidar import survey
from tests.conftest import SCENES

CYLINDER = SCENES / "calibration_cylinder.toml"
VINEYARD = SCENES / "vineyard_vsp.toml"

FOREST = """
[scene]
seed = 1
[forest]
domain_m = [0.0, 10.0, 0.0, 10.0]
export = "prototypes"
[[species]]
name = "{name}"
preset = "small-tree"
bumps = [{{ C_per_m2 = 0.02, x0_m = 5.0, y0_m = 5.0, h_m2 = 50.0, l_m2 = 50.0 }}]
"""


def _write(path, text):
    path.write_text(text)
    return path


def _refused(call, *args) -> tuple[ConfigError, int]:
    """The ConfigError ``call(*args)`` raises and the peak of Python and numpy allocations
    (tracemalloc) until then, in bytes."""
    tracemalloc.start()
    try:
        with pytest.raises(ConfigError) as e:
            call(*args)
        return e.value, tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


# --- scene text that becomes a file name ------------------------------------------------

@pytest.mark.parametrize("name", ["../../../../elsewhere/evil", "/tmp/evil", "a/b", ".hidden", "..",
                                  "x" * 65, "white space", ""])
def test_species_names_that_are_not_plain_file_names_are_refused(tmp_path, name):
    from simlidar_mi.forest.run import run_forest
    scene = _write(tmp_path / "forest.toml", FOREST.format(name=name))
    with pytest.raises(ConfigError) as e:
        load_scene(scene)
    assert (e.value.file, e.value.key, e.value.value) == (str(scene), "species[0].name", name)
    with pytest.raises(ConfigError):
        run_forest(scene, tmp_path / "out")
    assert not (tmp_path / "out").exists() and not (tmp_path / "elsewhere").exists()
    assert not any(p.suffix == ".ply" for p in tmp_path.rglob("*"))


def test_plain_species_names_pass_and_the_mesh_writer_checks_them_too(tmp_path):
    from simlidar_mi.forest.outputs import _write_prototype_meshes
    for ok in ("elm", "Quercus_robur-2", "tree.v1"):
        assert load_scene(_write(tmp_path / "f.toml", FOREST.format(name=ok))).arrays["species"][0]["name"] == ok
    forest = SimpleNamespace(species_names=("elm", "../evil"), prototypes=[], prototype_species=[])
    with pytest.raises(ConfigError) as e:  # the Python API: a Forest built without a scene file
        _write_prototype_meshes(forest, tmp_path / "protos", "ply", 6)
    assert e.value.key == "species.name" and e.value.value == "../evil"
    assert not (tmp_path / "protos").exists()


def test_a_preset_file_must_be_a_regular_toml_file_of_bounded_size(tmp_path):
    from simlidar_mi.config.presets import MAX_PRESET_BYTES
    (tmp_path / "folder.toml").mkdir()
    os.mkfifo(tmp_path / "pipe.toml")  # reading it would block for ever
    with open(tmp_path / "big.toml", "wb") as fh:  # sparse: no disk used
        fh.truncate(MAX_PRESET_BYTES + 1)
    (tmp_path / "notes.txt").write_text('[sensor]\ndivergence_mrad = 1.0\n')
    cases = {"/etc/passwd": "must be a .toml file", "./notes.txt": "must be a .toml file",
             "folder.toml": "is not a regular file", "pipe.toml": "is not a regular file",
             "big.toml": f"holds {MAX_PRESET_BYTES + 1} bytes", "none.toml": "no sensor preset file"}
    for ref, words in cases.items():
        scene = _write(tmp_path / "scene.toml", f'[sensor]\npreset = "{ref}"\n')
        with pytest.raises(ConfigError) as e:
            load_scene(scene)
        assert (e.value.file, e.value.key, e.value.value) == (str(scene), "sensor.preset", ref), ref
        assert words in e.value.reason, ref


# --- sizes bounded from the keys --------------------------------------------------------

@pytest.mark.parametrize("value, words", [(1_000_000_000, "≤ 4096"), (100_000, "≤ 4096"),
                                          (-1, "≥ 0")])
def test_beam_samples_are_bounded_when_the_scene_is_read(value, words):
    with pytest.raises(ConfigError) as e:
        load_scene(CYLINDER, [f"sensor.beam_samples={value}"])
    assert (e.value.key, e.value.value) == ("sensor.beam_samples", value) and words in e.value.reason
    assert e.value.file == f"--set sensor.beam_samples={value}"


def test_sub_rays_and_sub_beams_count_in_the_ray_budget(monkeypatch):
    # 90,000 beams × 9 dot-matrix sub-beams × 4096 sub-rays = 3.3e9 rays > the default 1e9
    cfg = load_scene(CYLINDER, ["sensor.divergence_mrad=2.0", "sensor.beam_samples=4096", "scan.footprint=2"])
    monkeypatch.setattr(survey, "scene_sensor", lambda *a: pytest.fail("not before the count"), raising=True)
    with pytest.raises(ConfigError) as e:
        survey.check_rays(cfg, [SimpleNamespace(n_beams=90_000)], None)
    assert (e.value.key, e.value.value) == ("sensor.beam_samples", 4096)
    assert "90,000 beams × 9 sub-beams × 4096 sub-rays = 3.32e+09 rays exceed scan.max_rays" in e.value.reason
    survey.check_rays(load_scene(CYLINDER, ["sensor.divergence_mrad=2.0", "sensor.beam_samples=2048"]),
                      [SimpleNamespace(n_beams=90_000)], None)  # 1.8e8: within
    # a platform's beams are counted from the keys, before the scene is generated
    monkeypatch.setattr(survey, "generate", lambda cfg: pytest.fail("generated before the count"))
    cfg = load_scene(CYLINDER, ['platform.kind="static"', "platform.position_m=[0, 0, 1]",
                                "platform.elevation_deg=[-30, 60, 0.05]", "platform.azimuth_deg=[0, 360, 0.05]",
                                "sensor.divergence_mrad=2.0", "sensor.beam_samples=1024"])
    with pytest.raises(ConfigError) as e:  # 7200 × 1801 beams × 1024
        survey._plan(cfg)
    assert e.value.key == "sensor.beam_samples" and "12,967,200 beams" in e.value.reason


@pytest.mark.parametrize("value", [16, 1_000_000])
def test_max_returns_beyond_las_are_refused_when_read(value):
    with pytest.raises(ConfigError) as e:
        load_scene(CYLINDER, [f"sensor.max_returns={value}"])
    assert (e.value.key, e.value.value) == ("sensor.max_returns", value) and "≤ 15" in e.value.reason
    assert load_scene(CYLINDER, ["sensor.max_returns=15"])["sensor"]["max_returns"] == 15


def test_divergence_beyond_a_laser_beam_is_refused():
    with pytest.raises(ConfigError) as e:
        load_scene(CYLINDER, ["sensor.divergence_mrad=100000.0"])  # 100 rad
    assert (e.value.key, e.value.value) == ("sensor.divergence_mrad", 100000.0) and "≤ 100" in e.value.reason
    assert load_scene(CYLINDER, ["sensor.divergence_mrad=100.0"])["sensor"]["divergence_mrad"] == 100.0


@pytest.mark.parametrize("override, key", [  # each key within its own range, the product not
    ("vineyard.vines_per_row=100000", "vineyard.vines_per_row"),
    ("vineyard.canopy.shoots_per_m=1000 vineyard.canopy.leaves_per_shoot=1000", "vineyard.canopy.shoots_per_m"),
    ("vineyard.canopy.leaves_per_shoot=1000 vineyard.vines_per_row=1000", "vineyard.vines_per_row"),
    ("vineyard.post_spacing_m=0.0001", "vineyard.post_spacing_m"),
])
def test_vineyard_sizes_are_refused_before_generating(monkeypatch, override, key):
    from simlidar_mi.plants import vineyard
    monkeypatch.setattr(vineyard, "vine", lambda *a: pytest.fail("a vine was generated"))
    monkeypatch.setattr(vineyard, "trellis", lambda *a: pytest.fail("a trellis was generated"))
    items = override.split()
    err, peak = _refused(survey.generate, load_scene(VINEYARD, items))
    assert err.key == key and err.file == f"--set {next(i for i in items if i.startswith(key))}"
    assert peak < 100e6


def test_the_vineyard_count_is_what_is_generated():
    from simlidar_mi.plants.vineyard import VineyardParams, vineyard
    p = VineyardParams(n_rows=2, vines_per_row=3, clusters=True)
    v = vineyard(p, seed=3)
    n = p.n_elements()
    assert n["trellis"] + n["wood"] == len(v.branches) and n["leaf_triangles"] == len(v.leaves)
    assert n["clusters"] == len(v.clusters) > 0
    with pytest.raises(ConfigError) as e:
        vineyard(p, max_elements=sum(n.values()) - 1)
    assert e.value.key.startswith("vineyard.")


@pytest.mark.parametrize("overrides, key, value", [
    (['platform.kind="path"', "platform.waypoints_m=[[0, -2, 1], [0, 2, 1]]", "platform.step_m=1e-9"],
     "platform.step_m", 1e-9),
    (['platform.kind="rotating"', "platform.position_m=[0, 0, 1.5]", "platform.duration_s=86400"],
     "platform.duration_s", 86400),
    (['platform.kind="rotating"', "platform.position_m=[0, 0, 1.5]", "platform.duration_s=3e4"],
     "platform.duration_s", 3e4),
    (['platform.kind="rosette"', "platform.position_m=[0, 0, 1.5]", "platform.duration_s=86400"],
     "platform.duration_s", 86400),
    (['platform.kind="rotating"', "platform.waypoints_m=[[0, -2, 1], [0, 2, 1]]", "platform.speed_m_s=1e-9"],
     "platform.speed_m_s", 1e-9),
    (['platform.kind="static"', "platform.position_m=[0, 0, 1]", "platform.elevation_deg=[-30, 60, 1e-9]"],
     "platform.elevation_deg", [-30, 60, 1e-9]),
    (['platform.kind="airborne"', "platform.start_xy_m=[0, 0]", "platform.end_xy_m=[100, 0]",
      "platform.speed_m_s=1e-9"], "platform.speed_m_s", 1e-9),
])
def test_platform_beam_counts_come_from_the_keys_before_any_array(monkeypatch, overrides, key, value):
    monkeypatch.setattr(survey, "generate", lambda cfg: pytest.fail("generated before the count"))
    err, peak = _refused(survey._plan, load_scene(CYLINDER, overrides))
    assert (err.key, err.value) == (key, value) and "exceed scan.max_beams" in err.reason
    assert err.file.startswith(f"--set {key}=") and peak < 100e6


def test_a_huge_platform_scan_is_one_line_and_writes_nothing(tmp_path, capsys):
    rc = main(["scan", str(CYLINDER), "--out", str(tmp_path / "o"), "--set", 'platform.kind="rotating"',
               "--set", "platform.position_m=[0, 0, 1.5]", "--set", "platform.duration_s=86400"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and not (tmp_path / "o").exists()
    assert err[0].startswith("simlidar-mi scan: error: --set platform.duration_s=86400, key 'platform.duration_s'")


# --- nesting too deep for the parser ------------------------------------------------------

def test_deeply_nested_arrays_are_one_line_in_a_scene_a_preset_and_a_set(tmp_path, capsys):
    deep = "[" * 100_000 + "]" * 100_000
    scene = _write(tmp_path / "deep.toml", f"[scene]\norigin_m = {deep}\n")
    preset = _write(tmp_path / "deep_preset.toml", f"[sensor]\ndivergence_mrad = {deep}\n")
    with_preset = _write(tmp_path / "uses.toml", '[sensor]\npreset = "deep_preset.toml"\n')
    for args, where in (([str(scene)], str(scene)), ([str(with_preset)], str(preset)),
                        ([str(CYLINDER), "--set", f"scan.x0_m={deep}"], "--set scan.x0_m=[[[[")):
        assert main(["measure", *args]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith(f"simlidar-mi measure: error: {where}"), err
        assert "nested more than 32 deep" in err[0] and len(err[0]) < 400
    # 33 levels parse but are refused as well, before any code walks them
    with pytest.raises(ConfigError, match="nested more than 32 deep"):
        load_scene(text=f"[scene]\norigin_m = {'[' * 32 + ']' * 32}\n")


# --- execution knobs ---------------------------------------------------------------------

def test_execution_knobs_change_neither_the_scene_hash_nor_the_study_key(tmp_path):
    from simlidar_mi.lidar.study import _key, scene_table
    base = load_scene(CYLINDER)
    knobs = ["scan.chunk_beams=1000", "scan.max_beams=5000000", "scan.max_rays=123456789"]
    edited = _write(tmp_path / "knobs.toml", CYLINDER.read_text().replace("[scan]", "[scan]\nchunk_beams = 7"))
    for cfg in (load_scene(CYLINDER, knobs), load_scene(edited)):
        assert cfg.sha256 == base.sha256
        assert _key(scene_table(cfg), version="v") == _key(scene_table(base), version="v")
    other = load_scene(CYLINDER, ["scan.dtheta_deg=0.5"])
    assert other.sha256 != base.sha256
    assert _key(scene_table(other), version="v") != _key(scene_table(base), version="v")
    forest = _write(tmp_path / "f.toml", FOREST.format(name="elm"))  # no [scan] table of its own
    with_knobs = load_scene(forest, ["forest.max_trees=7", "scan.chunk_beams=9"])
    assert with_knobs.sha256 == load_scene(forest).sha256
    assert _key(scene_table(with_knobs), version="v") == _key(scene_table(load_scene(forest)), version="v")
    assert load_scene(VINEYARD, ["vineyard.max_elements=99"]).sha256 == load_scene(VINEYARD).sha256


# --- errors name the option typed --------------------------------------------------------

def test_truth_errors_name_the_option_or_key_the_user_gave(tmp_path, capsys):
    scene = SCENES / "apple_orchard.toml"
    assert main(["truth", str(scene), "--out", str(tmp_path / "t"), "--voxel", "1e-6"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("simlidar-mi truth: error: --voxel 1e-06, key 'truth.voxel_m', "
                                               "value 1e-06: a 1e-06 m grid over this scene has"), err
    assert main(["truth", str(scene), "--out", str(tmp_path / "t"), "--set", "truth.margin_m=1e4"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[0].startswith("simlidar-mi truth: error: --set truth.margin_m=1e4, key 'truth.margin_m', "
                             "value 10000.0:") and "with this margin on every side" in err[0], err
    with pytest.raises(ConfigError) as e:  # so large that the count is infinite: still one error
        from simlidar_mi.truth.run import run_truth
        run_truth(scene, None, ["truth.margin_m=1e308"])
    assert e.value.key == "truth.margin_m"
    assert not (tmp_path / "t").exists()


@pytest.mark.parametrize("args, option", [(["--voxel", "1e-6"], "--voxel"), (["--voxel", "nan"], "--voxel"),
                                          (["--min-beams", "nan"], "--min-beams"),
                                          (["--min-beams", "-5"], "--min-beams"),
                                          (["--row-spacing", "-1"], "--row-spacing"),
                                          (["--row-spacing", "nan"], "--row-spacing")])
def test_evaluate_checks_its_options_before_the_scan(tmp_path, capsys, monkeypatch, args, option):
    monkeypatch.setattr(survey, "run_scan", lambda *a, **k: pytest.fail("scanned before the options"))
    try:
        rc = main(["evaluate", str(SCENES / "apple_orchard.toml"), "--out", str(tmp_path / "e"), *args])
    except SystemExit as exc:  # outside the option's range: refused while the line is parsed
        rc = exc.code
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and err[0].startswith(
        (f"simlidar-mi evaluate: error: key '{option}', ", f"simlidar-mi evaluate: error: argument {option}: ")), err
    assert not (tmp_path / "e").exists()
