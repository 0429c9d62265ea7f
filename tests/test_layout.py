"""The package layout: rooms by workflow over a shared base, imports pointing down only.

Every import is read from the source, as a reader sees it: module level, inside functions,
and under ``if TYPE_CHECKING:`` alike (an annotation that names a higher room is a dependency too).
"""
from __future__ import annotations

import ast
import doctest
import importlib
from pathlib import Path

import pytest

import simlidar_mi

REPO = Path(__file__).resolve().parents[1]
PKG = "simlidar_mi"

# Room -> rank. A module may import its own room and rooms of a lower rank only.
BASE = {"errors", "_version", "_runtime", "config", "geometry"}
RANK = {"base": 0, "io": 1, "lsystem": 1, "plants": 2, "scene": 3, "forest": 4,
        "lidar": 5, "canopy": 5, "truth": 6, "plugins": 6, "cli": 7, "api": 8}
MAX_LINES = 650  # "past ~600 lines, look for the seam"


def _modules() -> dict[str, Path]:
    mods = {}
    for path in sorted((REPO / PKG).rglob("*.py")):
        parts = list(path.relative_to(REPO).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts.pop()
        mods[".".join(parts)] = path
    for path in sorted((REPO / "plugins").glob("*.py")):
        name = path.stem
        mods[f"{PKG}.plugins" + ("" if name == "__init__" else f".{name}")] = path
    return mods


MODULES = _modules()


def room(module: str) -> str:
    parts = module.split(".")
    if len(parts) == 1:
        return "api"  # simlidar_mi/__init__.py re-exports the public API
    head = parts[1]
    if head in BASE:
        return "base"
    if head == "cli":
        return "cli"
    assert head in RANK, f"{module}: not in a known room; add it to the layout"
    return head


def _imports(module: str, path: Path) -> set[str]:
    """Modules of this package that ``module`` imports, at any depth of its code."""
    tree = ast.parse(path.read_text(), str(path))
    package = module if path.name == "__init__.py" else module.rsplit(".", 1)[0]
    found: set[str] = set()

    def visit(node: ast.AST) -> None:
        if isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.split(".")[0] == PKG:
                    found.add(_existing(alias.name))
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            if target.split(".")[0] == PKG:
                for alias in node.names:  # "from pkg import submodule" imports the submodule
                    sub = f"{target}.{alias.name}"
                    found.add(sub if sub in MODULES else _existing(target))
        for child in ast.iter_child_nodes(node):
            visit(child)

    visit(tree)
    found.discard(module)
    return found


def _existing(name: str) -> str:
    while name not in MODULES and "." in name:
        name = name.rsplit(".", 1)[0]
    assert name in MODULES, name
    return name


GRAPH = {m: _imports(m, p) for m, p in MODULES.items()}


def test_every_module_is_in_a_room():
    assert {room(m) for m in MODULES} <= set(RANK)


def test_imports_point_down_only():
    bad = []
    for mod, targets in GRAPH.items():
        r = room(mod)
        for t in targets:
            rt = room(t)
            if rt != r and RANK[rt] >= RANK[r]:
                bad.append(f"{mod} ({r}) imports {t} ({rt})")
    assert not bad, "\n".join(sorted(bad))


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index, low, stack, on, out, counter = {}, {}, [], set(), [], [0]

    def strong(v: str) -> None:
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                strong(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in graph:
        if v not in index:
            strong(v)
    return out


def test_no_import_cycles():
    assert _cycles(GRAPH) == []


def test_imports_under_type_checking_and_in_functions_count(tmp_path):
    # the checker reads what a reader reads: an annotation-only import is still a dependency
    src = tmp_path / "m.py"
    src.write_text("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from .lidar.scan import ScanResult\n"
                   "def f():\n    from .canopy import photo\n")
    assert _imports(f"{PKG}.m", src) == {f"{PKG}.lidar.scan", f"{PKG}.canopy.photo"}


def test_package_root_holds_few_modules():
    # the root shows the design: rooms are packages; shared helpers live in config/ and _runtime/
    root = sorted(p.name for p in (REPO / PKG).glob("*.py"))
    assert len(root) <= 8, root


def test_cycle_finder_finds_a_cycle():
    # the checker itself must be able to fail
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert _cycles({"a": {"b"}, "b": set()}) == []


def test_files_stay_small_and_say_what_they_hold():
    long, silent = [], []
    for mod, path in MODULES.items():
        text = path.read_text()
        if text.count("\n") > MAX_LINES:
            long.append(f"{path.relative_to(REPO)}: {text.count(chr(10))} lines")
        if not ast.get_docstring(ast.parse(text)):
            silent.append(str(path.relative_to(REPO)))
    assert not long, long
    assert not silent, silent


@pytest.mark.parametrize("name", sorted(simlidar_mi._API))
def test_public_api_names_resolve(name):
    assert getattr(simlidar_mi, name) is getattr(
        importlib.import_module(f"{PKG}.{simlidar_mi._API[name]}"), name)
    assert name in dir(simlidar_mi)


def test_unknown_attribute_is_an_attribute_error():
    with pytest.raises(AttributeError, match="no attribute 'nope'"):
        simlidar_mi.nope  # noqa: B018


def test_package_docstring_example_runs(monkeypatch):
    monkeypatch.chdir(REPO)
    result = doctest.testmod(simlidar_mi, verbose=False)
    assert result.attempted >= 5 and result.failed == 0


def test_every_package_ships_in_the_wheel():
    # pyproject lists packages by hand (plugins/ is mapped in): a new room must be listed too
    from simlidar_mi.config import tomllib  # tomli on Python 3.10
    listed = set(tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    found = {".".join(p.parent.relative_to(REPO).parts) for p in (REPO / PKG).rglob("__init__.py")}
    assert found | {f"{PKG}.plugins"} == listed
