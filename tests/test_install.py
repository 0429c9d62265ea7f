"""The package as a user installs it: the sdist and wheel `python -m build` makes from a clone,
the wheel installed (not editable) into a fresh virtual environment scanning from a folder outside
the repository with its own Mitsuba plugins, the README's pip route, and CITATION.cff.

Installing Mitsuba, Dr.Jit, NumPy... from PyPI into each fresh environment would take minutes, so
the fresh environment gets them from this interpreter's site-packages through a path line in a
``.pth`` file. A path line does not run the ``.pth`` files of the folder it names (among them the
editable install's), and the environment's own site-packages comes first on ``sys.path``:
``simlidar_mi`` is imported from the wheel, which each test checks by its ``__file__``.
Nothing is downloaded: the build runs without isolation and pip with ``--no-index``.
"""
from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
import sysconfig
import tarfile
import zipfile
from pathlib import Path

import pytest

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib

from tests.conftest import REPO, SCENES

BOUND_S = 600  # stops a hung build or install; no assertion depends on time
SCENE = "calibration_cylinder.toml"
# what a source tree holds that is not source: never copied into the scratch clone
NOT_SOURCE = {".git", ".venv", "build", "dist", "out", "_build", "__pycache__", ".pytest_cache",
              ".hypothesis", "photo_masks"}


def _run(args, **kw) -> subprocess.CompletedProcess:
    proc = subprocess.run(args, capture_output=True, text=True, timeout=BOUND_S, **kw)
    assert proc.returncode == 0, f"{args}\nstdout: {proc.stdout[-2000:]}\nstderr: {proc.stderr[-4000:]}"
    return proc


def _copy_clone(dst: Path) -> Path:
    """The source tree as a clone has it (no .venv, builds, outputs or caches)."""
    def ignore(folder, names):
        rel = Path(folder).relative_to(REPO)
        return [n for n in names if n in NOT_SOURCE or n.endswith((".egg-info", ".pyc"))
                or (rel == Path("bench") and n == "out")]
    shutil.copytree(REPO, dst, ignore=ignore, symlinks=True)
    return dst


def _source_files(root: Path) -> list[str]:
    """The package's Python files as they sit in a wheel (plugins/ under simlidar_mi/)."""
    files = [p.relative_to(root).as_posix() for p in (root / "simlidar_mi").rglob("*.py")]
    files += [f"simlidar_mi/plugins/{p.name}" for p in (root / "plugins").glob("*.py")]
    return sorted(f for f in files if "__pycache__" not in f)


@pytest.fixture(scope="module")
def dists(tmp_path_factory) -> dict:
    """`python -m build` of a scratch clone: the sdist, then the wheel built from the sdist."""
    tmp = tmp_path_factory.mktemp("dists")
    clone = _copy_clone(tmp / "clone")
    _run([sys.executable, "-m", "build", "--no-isolation", "--outdir", str(tmp / "dist"), str(clone)])
    (sdist,) = (tmp / "dist").glob("simlidar_mi-*.tar.gz")
    (wheel,) = (tmp / "dist").glob("simlidar_mi-*-py3-none-any.whl")
    return {"clone": clone, "sdist": sdist, "wheel": wheel}


def _fresh_venv(path: Path) -> Path:
    """A new virtual environment (no pip, no packages) whose dependencies are this interpreter's,
    by a path line; returns its python."""
    _run([sys.executable, "-m", "venv", "--without-pip", str(path)])
    py = path / "bin" / "python"
    site = _run([str(py), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"]).stdout.strip()
    ours = {sysconfig.get_paths()["purelib"], sysconfig.get_paths()["platlib"]}
    (Path(site) / "_simlidar_test_deps.pth").write_text("".join(f"{p}\n" for p in sorted(ours)))
    return py


def _env(venv: Path | None = None) -> dict:
    """The environment of a user's shell: no PYTHONPATH, and the venv's bin/ first on PATH."""
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME", "VIRTUAL_ENV")}
    if venv is not None:
        env.update(VIRTUAL_ENV=str(venv), PATH=f"{venv / 'bin'}{os.pathsep}{env['PATH']}")
    return env


WHERE = ("import json, sys, simlidar_mi; from simlidar_mi._runtime.mitsuba import mitsuba; mitsuba();"
         "print(json.dumps({'package': simlidar_mi.__file__, 'plugins': {n: m.__file__ for n, m in"
         " sys.modules.items() if n.startswith('simlidar_mi.plugins.')}}))")


def _assert_installed_in(py: Path, venv: Path, cwd: Path) -> None:
    """simlidar_mi and each Mitsuba plugin it registers are imported from the environment."""
    where = json.loads(_run([str(py), "-c", WHERE], cwd=cwd, env=_env(venv)).stdout)
    site = venv.resolve()
    assert Path(where["package"]).resolve().is_relative_to(site), where["package"]
    assert {n.rsplit(".", 1)[1] for n in where["plugins"]} >= {
        "tractor_lidar", "range_integrator", "coverage_integrator", "fisheye_camera"}
    for name, file in where["plugins"].items():
        assert Path(file).resolve().is_relative_to(site / "lib"), (name, file)


@pytest.fixture(scope="module")
def source_scan(tmp_path_factory) -> Path:
    """The calibration scan run by the source tree's package (this interpreter's)."""
    run = tmp_path_factory.mktemp("source_scan")
    shutil.copy(SCENES / SCENE, run / SCENE)
    _run([sys.executable, "-m", "simlidar_mi.cli", "scan", SCENE, "--out", "out"], cwd=run)
    return run / "out"


def test_sdist_holds_what_a_build_needs(dists):
    """The sdist holds the package, its plugins, the metadata files and what the tests and README
    use; the wheel above was built from it (build makes the sdist first, then the wheel from it)."""
    with tarfile.open(dists["sdist"]) as tar:
        names = {n.split("/", 1)[1] for n in tar.getnames() if "/" in n}
    clone = dists["clone"]
    need = ["pyproject.toml", "README.md", "LICENSE", "CHANGELOG.md", "CITATION.cff", "MANIFEST.in",
            "Makefile", "tests/conftest.py", "docs/conf.py"]
    need += [p.relative_to(clone).as_posix() for p in (clone / "plugins").glob("*.py")]
    need += [p.relative_to(clone).as_posix() for p in (clone / "simlidar_mi").rglob("*.py")]
    need += [p.relative_to(clone).as_posix() for p in (clone / "scenes").glob("*.*")]
    assert sorted(set(need) - names) == []
    assert not [n for n in names if "__pycache__" in n or n.endswith(".pyc") or "_build/" in n]


def test_wheel_ships_the_package_its_plugins_and_licence(dists):
    with zipfile.ZipFile(dists["wheel"]) as whl:
        names = set(whl.namelist())
        info = next(n.split("/")[0] for n in names if n.endswith(".dist-info/METADATA"))
        meta = whl.read(f"{info}/METADATA").decode()
        entry = whl.read(f"{info}/entry_points.txt").decode()
    assert sorted(set(_source_files(dists["clone"])) - names) == []
    assert not [n for n in names if n.startswith(("plugins/", "tests/", "scenes/"))]
    assert f"{info}/licenses/LICENSE" in names
    assert re.search(r"^License-Expression: MIT$", meta, re.M)
    assert "simlidar-mi = simlidar_mi.cli:main" in entry


def test_wheel_scans_outside_the_repository(dists, source_scan, tmp_path):
    """The wheel, installed (not editable) into a fresh environment, scans from a folder outside
    the repository with the plugins it ships, giving the source tree's bytes."""
    venv = tmp_path / "venv"
    py = _fresh_venv(venv)
    _run([str(py), "-m", "pip", "install", "--no-deps", "--no-index", "--ignore-installed",
          str(dists["wheel"])], env=_env(venv))
    run = tmp_path / "elsewhere"
    run.mkdir()
    shutil.copy(SCENES / SCENE, run / SCENE)
    _assert_installed_in(py, venv, run)
    proc = _run([str(venv / "bin" / "simlidar-mi"), "scan", SCENE, "--out", "out"], cwd=run,
                env=_env(venv))
    assert "A_IM = " in proc.stdout
    for name in ("scan.exr", "points.las"):  # same scene and seed, same bytes
        assert (run / "out" / name).read_bytes() == (source_scan / name).read_bytes(), name
    # the sensor presets are code, shipped in the wheel
    sensors = _run([str(venv / "bin" / "simlidar-mi"), "sensors"], cwd=run, env=_env(venv)).stdout
    assert sensors == _run([sys.executable, "-m", "simlidar_mi.cli", "sensors"], cwd=run).stdout


def _readme_pip_block() -> str:
    text = (REPO / "README.md").read_text()
    section = text[text.index("## Installing with pip"):]
    return re.search(r"```sh\n(.*?)```", section, re.S).group(1)


def test_readme_pip_route_runs(dists, source_scan, tmp_path):
    """The README's pip block, run line by line in a scratch clone, offline: `python3 -m venv`
    makes the environment as above, `pip` adds --no-index --no-deps --no-build-isolation."""
    block = _readme_pip_block()
    assert re.search(r"^pip install \.", block, re.M), block
    clone = _copy_clone(tmp_path / "clone")
    venv_py = f"{Path(sys.executable).parent}/python"  # its venv module makes a venv of the base
    deps = "\\n".join(sorted({sysconfig.get_paths()["purelib"], sysconfig.get_paths()["platlib"]}))
    prelude = f'''
python3() {{
  if [ "$1 $2" = "-m venv" ]; then
    "{venv_py}" -m venv --without-pip "$3" || return
    site=$("$3/bin/python" -c "import sysconfig; print(sysconfig.get_paths()['purelib'])")
    printf '{deps}\\n' > "$site/_simlidar_test_deps.pth"
  else command python3 "$@"; fi
}}
pip() {{ python -m pip "$@" --no-index --no-deps --no-build-isolation --ignore-installed; }}
'''
    env = _env()
    env["HOME"] = str(tmp_path / "home")
    (tmp_path / "home").mkdir()
    _run(["bash", "-c", f"set -e\n{prelude}\n{block}"], cwd=clone, env=env)
    made = re.search(r"^python3 -m venv (\S+)", block, re.M).group(1)
    venv = Path(made.replace("~", env["HOME"], 1))
    _assert_installed_in(venv / "bin" / "python", venv, tmp_path)
    scan = re.search(r"^simlidar-mi scan \S+ --out (\S+)", block, re.M)
    out = clone / scan.group(1)
    # scan.exr's header names its output folder (another here); the points are the same bytes
    assert (out / "points.las").read_bytes() == (source_scan / "points.las").read_bytes()
    assert (out / "scan.exr").stat().st_size > 0


def test_citation_file_is_valid_cff():
    """CITATION.cff holds what the Citation File Format 1.2.0 requires, and agrees with the
    package: its version, its licence, and the seed papers of the references page."""
    import yaml
    import simlidar_mi
    cff = yaml.safe_load((REPO / "CITATION.cff").read_text())
    assert cff["cff-version"] == "1.2.0"
    for key in ("message", "title", "authors"):
        assert cff.get(key), key
    assert all(a.get("name") or a.get("family-names") for a in cff["authors"])
    project = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]
    assert cff["version"] == simlidar_mi.__version__
    assert cff["license"] == project["license"]
    assert cff["type"] == "software"
    assert re.fullmatch(r"\d{4}-\d{2}-\d{2}", str(cff["date-released"]))
    refs = " ".join((REPO / "docs" / "references.md").read_text().split())  # lines joined
    titles = [r["title"] for r in cff["references"]]
    assert len(titles) == 3
    for ref in cff["references"]:
        assert ref["title"] in refs, ref["title"]
        assert ref["type"] in ("article", "conference-paper")
        assert all(a.get("family-names") for a in ref["authors"])
        if "doi" in ref:
            assert f"doi:{ref['doi']}" in refs or ref["doi"] in refs, ref["doi"]
