"""The documentation (docs/) builds without a warning, its generated references hold everything the
code holds, the scene-file schema describes every key, and every code block of its pages runs."""
from __future__ import annotations

import argparse
import html
import os
import re
import subprocess
import sys
from pathlib import Path

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib

import pytest

from tests.conftest import REPO, SHARED

DOCS = REPO / "docs"
sys.path.insert(0, str(DOCS / "_ext"))
import simlidar_ref  # noqa: E402  (docs/_ext: the generator of the references)

PAGES = sorted(p for p in DOCS.rglob("*.md") if "_build" not in p.parts)
BOUND_S = 600  # stops a hung build or command; no assertion depends on time
# Shell lines known to take minutes (2 shared cores), with the bound that stops them if hung. A
# page holding one is run twice: without those blocks (quick), and whole, marked `slow` (deselect
# with -m "not slow"; run by default).
SLOW_S = {"simlidar-mi study ": 3600, "simlidar-mi synthetic-photo ": 2400,
          "scenes/forest_4species.toml": 900, "scenes/forest_airborne.toml": 900}


def slow_bound_s(code: str) -> int | None:
    """The bound of the slowest known-slow line in ``code``, or None when it holds none."""
    bounds = [s for key, s in SLOW_S.items() if re.search(re.escape(key.rstrip()) + r"(\s|$)", code)]
    return max(bounds) if bounds else None


# --- (a) the build ------------------------------------------------------------------------
@pytest.fixture(scope="module")
def built(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("docs_html")
    proc = _build(DOCS, out)
    assert proc.returncode == 0, f"sphinx-build -W failed:\n{proc.stderr[-5000:]}"
    assert "WARNING" not in proc.stderr, proc.stderr[-5000:]
    return out


def _build(src: Path, out: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "sphinx", "-b", "html", "-W", "--keep-going", "-E",
                           "-q", "-d", str(out / ".doctrees"), str(src), str(out)],
                          capture_output=True, text=True, timeout=BOUND_S)


def test_a_broken_link_fails_the_build(tmp_path):
    """-W works: a page linking to a page that does not exist fails the build, naming it."""
    import shutil
    src = tmp_path / "docs"
    shutil.copytree(DOCS, src, ignore=shutil.ignore_patterns("_build"))
    with open(src / "getting-started.md", "a") as f:
        f.write("\nSee {doc}`no-such-page`.\n")
    proc = _build(src, tmp_path / "html")
    assert proc.returncode != 0
    assert "no-such-page" in proc.stderr


def _text(page: Path) -> str:
    return html.unescape(page.read_text())


def _section_text(page: str, ident: str) -> str:
    """The text (tags removed: a literal's words are split into spans) from a section's id on."""
    return html.unescape(re.sub(r"<[^>]+>", "", page[page.index(f'id="{ident}"'):]))


def test_docs_build_without_warnings(built):
    for page in PAGES:
        rel = page.relative_to(DOCS).with_suffix(".html")
        assert (built / rel).stat().st_size > 0, rel


def test_scene_key_reference_lists_every_key(built):
    """One table per section and one row per key of the schema, with its default and range."""
    from simlidar_mi.config.keys import ARRAY_SECTIONS, SECTIONS
    page = _text(built / "reference" / "scene-keys.html")
    rows = simlidar_ref.key_rows()
    assert len(rows) == sum(len(k) for k in (*SECTIONS.values(), *ARRAY_SECTIONS.values()))
    n_tables = page.count("<table")
    assert n_tables == len(SECTIONS) + len(ARRAY_SECTIONS)
    assert page.count("<tr") - n_tables == len(rows)  # one header row per table
    for section in (*SECTIONS, *ARRAY_SECTIONS):
        assert f'id="keys-{section.replace(".", "-").replace("_", "-")}"' in page, section
    # one key read through, every column: [sensor] max_returns
    row = next(r for r in rows if (r.section, r.name) == ("sensor", "max_returns"))
    assert (row.type, row.unit, row.default) == ("integer", "", "1")
    assert row.range == "[1, 15] (LAS 1.4 holds return numbers 1-15)"
    assert row.range in page and row.doc in page
    speed = next(r for r in rows if (r.section, r.name) == ("platform", "speed_m_s"))
    assert (speed.type, speed.unit, speed.default) == ("number", "m/s", "—")


def test_cli_reference_lists_every_command_and_option(built):
    from simlidar_mi.cli import COMMANDS, build_parser
    page = (built / "reference" / "cli.html").read_text()
    subs = simlidar_ref.subcommands(build_parser())
    assert list(subs) == [name for name, *_ in COMMANDS]
    for name, sub in subs.items():
        assert f'id="cli-{name}"' in page, name
        section = _section_text(page, f"cli-{name}")
        for action in sub._actions:
            if isinstance(action, argparse._HelpAction):  # -h, --help: in the usage line
                continue
            for opt in action.option_strings:
                assert opt in section, (name, opt)
            if action.help:
                assert action.help in section, (name, action.dest)  # shown as written, not as markup


def test_api_reference_documents_every_exported_name(built):
    import simlidar_mi
    page = (built / "reference" / "api.html").read_text()
    missing = [n for n in simlidar_mi.__all__ if n != "__version__" and f'id="simlidar_mi.{n}"' not in page]
    assert not missing


def test_sensor_reference_shows_every_preset_value_and_source(built):
    from simlidar_mi.config import presets as sp
    page = (built / "reference" / "sensors.html").read_text()
    for p in sp.BUILTIN.values():
        assert f'id="preset-{p.name}"' in page
        section = _section_text(page, f"preset-{p.name}")
        for dotted, v in p.values().items():
            assert dotted in section and sp._fmt(v.value) in section, (p.name, dotted)
            assert p.sources.get(v.source, v.source) in section, (p.name, dotted)


# --- (b) the schema describes every key ---------------------------------------------------
def test_every_scene_key_has_a_description_unit_and_range():
    assert simlidar_ref.problems() == []


def test_schema_check_finds_what_a_key_lacks(monkeypatch):
    """The check above can fail: an undocumented key, a quantity without a unit, a check whose
    range cannot be read are each reported."""
    from simlidar_mi.config import keys as ck
    odd = lambda v: None if v != 3 else "is three"  # noqa: E731 - no 'must' complaint
    n = 2
    closes_over = lambda v: None if v != n else "must not be two"  # noqa: E731
    monkeypatch.setitem(ck.SECTIONS, "extra", {
        "height": ck.Key(ck.FLOAT, 1.0, ck.positive, "a height with no unit in its name"),
        "count": ck.Key(ck.INT, 1, ck.at_least(1)),
        "odd": ck.Key(ck.INT, 1, odd, "a check without words"),
        "closure": ck.Key(ck.INT, 1, closes_over, "a check closing over an unknown value"),
    })
    found = simlidar_ref.problems()
    no_range = ("a number-valued key with no range: add it to simlidar_mi/config/bounds.py BOUNDS")
    assert found == [
        "[extra] height: a number with no unit: end its name with the unit (_m, _deg, ...) or, if "
        "it has none, add it to NO_UNIT",
        f"[extra] height: {no_range}",
        "[extra] count: no description (Key's doc)",
        f"[extra] count: {no_range}",
        "[extra] odd: check test_schema_check_finds_what_a_key_lacks.<locals>.<lambda> has no "
        "docstring and no 'must ...' text",
        f"[extra] odd: {no_range}",
        "[extra] closure: check test_schema_check_finds_what_a_key_lacks.<locals>.<lambda> closes "
        "over ['n']",
        f"[extra] closure: {no_range}"]


@pytest.mark.parametrize(("check", "text"), [
    ("positive", "> 0"), ("nonneg", "≥ 0"), ("unit_interval", "in [0, 1]"),
    ("at_least(3)", "≥ 3"), ("within(0, 100, 'why')", "[0, 100] (why)"),
    ("one_of('a', 'b')", 'one of "a", "b"'), ("vec2", "a list of two numbers [x, y] in metres"),
])
def test_allowed_range_is_read_from_the_check(check, text):
    from simlidar_mi.config import keys as ck
    assert simlidar_ref.key_range(eval(check, vars(ck))) == text


def test_unit_is_read_from_the_key_name():
    assert [simlidar_ref.unit("s", k) for k in ("speed_m_s", "background_per_m2", "leaves_per_m",
            "leaf_area_m2", "divergence_mrad", "fov_deg", "rotation_hz", "block_period_us",
            "pulse_length_ns", "wavelength_nm", "x0_m", "duration_s", "n_trees")] == [
        "m/s", "m⁻²", "m⁻¹", "m²", "mrad", "°", "Hz", "µs", "ns", "nm", "m", "s", ""]


# --- (c) every code block of every page runs ----------------------------------------------
def _sybil():
    from sybil import Sybil
    from sybil.parsers.myst import CodeBlockParser, PythonCodeBlockParser, SkipParser

    class ShellBlock(CodeBlockParser):
        """A ```sh block, run by bash in the page's scratch clone, after the page's earlier blocks
        (their exported environment carries over, as in one terminal)."""

        language = "sh"

        def evaluate(self, example):
            ns = example.namespace
            if "../shared/" in example.parsed and not SHARED.is_dir():
                return None  # the real test photos beside the clone: absent on this machine
            env_file = ns["_env_file"]
            script = (f'set -e\nsource "{env_file}"\n{SHELL_PRELUDE}\n{example.parsed}\n'
                      f'export -p > "{env_file}"\n')
            proc = subprocess.run(["bash", "-c", script], cwd=ns["_clone"], env=ns["_env"],
                                  capture_output=True, text=True,
                                  timeout=slow_bound_s(example.parsed) or BOUND_S)
            if proc.returncode != 0 or "Traceback" in proc.stderr:
                return (f"exit {proc.returncode}\nstdout: {proc.stdout[-2000:]}\n"
                        f"stderr: {proc.stderr[-3000:]}")
            return None

    class TomlBlock(CodeBlockParser):
        """A ```toml block: valid TOML; one whose first line names a file (``# sensors/x.toml``)
        is written there in the page's scratch clone, for the blocks after it to use."""

        language = "toml"

        def evaluate(self, example):
            tomllib.loads(example.parsed)
            m = re.match(r"#\s*(\S+\.toml)\s*$", example.parsed.splitlines()[0])
            if m:
                clone = example.namespace["_clone"]
                path = clone / m.group(1)
                # scenes/ and examples/ are links to the repository: never write through them
                assert path.resolve().is_relative_to(clone.resolve()), \
                    f"{m.group(1)}: a page writes only into its scratch clone"
                path.parent.mkdir(parents=True, exist_ok=True)
                path.write_text(example.parsed)
            return None

    return Sybil(parsers=[PythonCodeBlockParser(), ShellBlock(), TomlBlock(), SkipParser()])


# `make` lines install and run for minutes: they run as a dry run (`make -n`) of this repository's
# Makefile, which checks that each target exists and its recipe expands.
SHELL_PRELUDE = f'make() {{ command make -n -C "{REPO}" "$@" >/dev/null; }}'


def _clone(tmp_path: Path) -> tuple[Path, dict]:
    """A scratch clone as `make` leaves it: scenes/ and examples/ linked, and a .venv whose bin/
    holds `simlidar-mi`, `python` and `activate` for this interpreter. `simlidar-mi` is not on
    PATH until a block activates .venv or calls .venv/bin/simlidar-mi, as for a new user."""
    clone = tmp_path / "clone"
    bin_ = clone / ".venv" / "bin"
    bin_.mkdir(parents=True)
    for name in ("scenes", "examples"):
        (clone / name).symlink_to(REPO / name)
    if SHARED.is_dir():  # the shared data folder beside the clone, as ../shared
        (tmp_path / "shared").symlink_to(SHARED)
    shims = {"simlidar-mi": f'exec "{sys.executable}" -m simlidar_mi.cli "$@"',
             "python": f'exec "{sys.executable}" "$@"'}
    for name, body in shims.items():
        (bin_ / name).write_text(f"#!/bin/sh\n{body}\n")
        (bin_ / name).chmod(0o755)
    (bin_ / "activate").write_text(f'export VIRTUAL_ENV="{clone / ".venv"}"\n'
                                   'export PATH="$VIRTUAL_ENV/bin:$PATH"\n')
    path = [d for d in os.environ["PATH"].split(os.pathsep) if d and not (Path(d) / "simlidar-mi").exists()]
    return clone, dict(os.environ, PATH=os.pathsep.join(path))


def _fences(text: str) -> list[tuple[str, int, int]]:
    """Each fenced block of a page: its language (a MyST directive's is '{name}') and its first
    and last line (1-based)."""
    blocks, inside = [], None
    for i, line in enumerate(text.splitlines(), 1):
        m = re.match(r"^(`{3,})(.*)$", line.strip())
        if not m:
            continue
        if inside is None:
            inside = (m.group(1), m.group(2).strip().split(" ")[0], i)
        elif m.group(1) == inside[0] and not m.group(2).strip():
            blocks.append((inside[1], inside[2], i))
            inside = None
    return blocks


RUN = ("python", "sh", "toml")  # the languages _sybil() runs


def _page_params():
    for page in PAGES:
        name = str(page.relative_to(DOCS))
        if any(slow_bound_s(code) for lang, code in _blocks(page) if lang == "sh"):
            yield pytest.param(page, False, id=f"{name}-quick")
            yield pytest.param(page, True, id=f"{name}-whole", marks=pytest.mark.slow)
        else:
            yield pytest.param(page, True, id=name)


def _blocks(page: Path) -> list[tuple[str, str]]:
    lines = page.read_text().splitlines()
    return [(lang, "\n".join(lines[first:last - 1])) for lang, first, last in _fences(page.read_text())]


def test_slow_lines_are_recognised():
    """The quick run leaves out exactly the known-slow lines (so it can tell them apart)."""
    assert slow_bound_s("simlidar-mi study scenes/apple_orchard.toml --out out/study") == 3600
    assert slow_bound_s("simlidar-mi forest scenes/forest_4species.toml --out x") == 900
    assert slow_bound_s("simlidar-mi scan scenes/forest_airborne_echoes.toml --out x") is None
    assert slow_bound_s("simlidar-mi scan scenes/calibration_cylinder.toml --out x") is None
    assert any(p.id.endswith("-whole") for p in _page_params())


@pytest.mark.parametrize(("page", "whole"), list(_page_params()))
def test_page_code_blocks_run(page, whole, tmp_path, monkeypatch):
    blocks = _fences(page.read_text())
    unknown = [b for b in blocks if not b[0].startswith("{") and b[0] not in RUN]
    assert not unknown, f"{page.name}: blocks {unknown} have no runner here (add one, or use {RUN})"
    document = _sybil().parse(page)
    examples = list(document.examples())
    for lang, first, last in blocks:  # every python/sh block is run (a doctest block: each example)
        assert lang.startswith("{") or any(first <= e.line <= last for e in examples), (page.name, first)
    clone, env = _clone(tmp_path)
    env_file = tmp_path / "env.sh"
    env_file.write_text("")
    document.namespace.update(_clone=clone, _env=env, _env_file=env_file)
    monkeypatch.chdir(clone)  # Python blocks read scenes/ and write out/ where the shell ones do
    for example in examples:
        if not whole and isinstance(example.parsed, str) and slow_bound_s(example.parsed) \
                and not example.document.evaluators:  # (a block a `skip` holds back: to it)
            continue  # the quick run: the page's `-whole` run (marked slow) runs it
        example.evaluate()


def test_shell_blocks_fail_where_a_new_user_would(tmp_path):
    """The runner is strict: a bare `simlidar-mi` before .venv is activated fails, as it does in a
    new shell after `make demo`; a make target that does not exist fails."""
    clone, env = _clone(tmp_path)
    for line, ok in (("simlidar-mi --version", False), (".venv/bin/simlidar-mi --version", True),
                     ("source .venv/bin/activate && simlidar-mi --version", True),
                     ("make demo", True), ("make no-such-target", False)):
        proc = subprocess.run(["bash", "-c", f"set -e\n{SHELL_PRELUDE}\n{line}"], cwd=clone, env=env,
                              capture_output=True, text=True, timeout=BOUND_S)
        assert (proc.returncode == 0) is ok, (line, proc.stderr)


# --- (d) the faults page names tests that exist ------------------------------------------
FAULTS = DOCS / "guide" / "faults.md"


def _faults_table(text: str) -> list[tuple[str, str, str]]:
    rows = []
    for line in text.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split(" | ")]
        if len(cells) == 3 and cells[2].startswith("tests/"):
            rows.append((cells[0], cells[1], cells[2]))
    return rows


def _missing_tests(rows: list[tuple[str, str, str]]) -> list[str]:
    import ast
    missing = []
    for _case, _seen, ref in rows:
        path, name = ref.split("::")
        file = REPO / path
        tree = ast.parse(file.read_text()) if file.is_file() else ast.Module(body=[], type_ignores=[])
        names = {n.name for n in ast.walk(tree) if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef))}
        if name.split("[")[0] not in names:
            missing.append(ref)
    return missing


def test_faults_table_names_tests_that_exist():
    """Every row of the "Faults and bad input" page is backed by a real test."""
    rows = _faults_table(FAULTS.read_text())
    assert len(rows) >= 30
    assert _missing_tests(rows) == []


def test_faults_check_finds_a_missing_test():
    rows = [("a case", "a line", "tests/test_docs.py::test_no_such_test"),
            ("a case", "a line", "tests/no_such_file.py::test_x"),
            ("a case", "a line", "tests/test_docs.py::test_faults_table_names_tests_that_exist")]
    assert _missing_tests(rows) == ["tests/test_docs.py::test_no_such_test", "tests/no_such_file.py::test_x"]


# --- (e) every command has its Python function on the commands page ---------------------
COMMANDS_PAGE = DOCS / "reference" / "commands.md"
# calls a command's source and its example share without being its entry point
NOT_AN_ENTRY = {*dir(__builtins__ if isinstance(__builtins__, dict) else vars(__builtins__)),
                *dir(dict), "load_scene", "bounds_m", "format_measures", "paper_grid"}


def _command_sections(text: str) -> dict[str, str]:
    """Each ``(api-NAME)=`` section of the commands page: its text up to the next one."""
    parts = re.split(r"^\(api-([a-z0-9-]+)\)=$", text, flags=re.M)
    return dict(zip(parts[1::2], parts[2::2]))


def test_every_command_has_a_python_entry_with_an_example():
    """One section a command, holding a runnable python block that calls the function the command
    itself calls (read from the command's source), and that function's documentation."""
    import inspect

    from simlidar_mi.cli import COMMANDS
    sections = _command_sections(COMMANDS_PAGE.read_text())
    assert [n for n, *_ in COMMANDS if n not in sections] == []
    for name, _help, _args, run in COMMANDS:
        body = sections[name]
        code = "\n".join(c for lang, c in _blocks_of(body) if lang == "python")
        assert code, f"{name}: no python example"
        called = [f for f in re.findall(r"\b([a-z_][a-z0-9_]*)\(", inspect.getsource(run))
                  if re.search(rf"\b{f}\(", code) and f not in NOT_AN_ENTRY]
        assert called, f"{name}: the example calls none of the functions the command calls"
        assert any(f"{f}`" in body or f".. autofunction:: " in body and f"{f}\n" in body for f in called), \
            (name, called)


def _blocks_of(text: str) -> list[tuple[str, str]]:
    lines = text.splitlines()
    return [(lang, "\n".join(lines[first:last - 1])) for lang, first, last in _fences(text)]


# --- (f) links into the benchmarks page name a section that exists -----------------------
def benchmark_anchors(text: str) -> set[str]:
    """The heading ids MyST gives BENCHMARKS.md (included by docs/benchmarks.md): GitHub-style
    slugs of its headings to conf.py's ``myst_heading_anchors`` level, the ids GitHub gives too."""
    import importlib.util
    spec = importlib.util.spec_from_file_location("docs_conf", DOCS / "conf.py")
    conf = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(conf)
    from markdown_it import MarkdownIt
    from mdit_py_plugins.anchors import anchors_plugin
    from myst_parser.slugs import github_slugify
    md = MarkdownIt("commonmark").use(anchors_plugin, min_level=1, max_level=conf.myst_heading_anchors,
                                      slug_func=github_slugify)
    return {t.attrs["id"] for t in md.parse(text) if t.type == "heading_open" and "id" in t.attrs}


def benchmark_links(pages: dict[str, str]) -> list[tuple[str, str, str]]:
    """(page, link text, anchor or '') of every link into the benchmarks page."""
    return [(name, " ".join(m.group(1).split()), m.group(3) or "")
            for name, text in pages.items()
            for m in re.finditer(r"\[([^\]]*)\]\(([^)#]*(?:benchmarks|BENCHMARKS)\.md)(?:#([^)]*))?\)", text)]


def bad_benchmark_links(pages: dict[str, str], anchors: set[str]) -> list[str]:
    return [f"{page}: [{text}] -> {anchor or 'the top of the page'}" for page, text, anchor in benchmark_links(pages)
            if anchor not in anchors and not (page == "README.md" and not anchor)]


def test_every_benchmarks_link_names_an_existing_section():
    """A "benchmarks: X" link lands on its section (MyST heading anchors), not the top of a
    2,000-line page; only the README's links to the whole file (BENCHMARKS.md) have none."""
    pages = {str(p.relative_to(DOCS)): p.read_text() for p in PAGES}
    pages["README.md"] = (REPO / "README.md").read_text()
    assert len(benchmark_links(pages)) >= 36
    assert bad_benchmark_links(pages, benchmark_anchors((REPO / "BENCHMARKS.md").read_text())) == []


def test_benchmark_link_check_finds_a_bad_anchor():
    anchors = benchmark_anchors("# Top\n## 10c. Canopy ground truth\n### The §5 study: 96 orchards\n")
    assert anchors == {"top", "10c-canopy-ground-truth", "the-5-study-96-orchards"}
    pages = {"guide/x.md": "see [benchmarks: truth](../benchmarks.md#10c-canopy-ground-truth) and "
                           "[benchmarks: study](../benchmarks.md) and [b](../benchmarks.md#no-such)"}
    assert bad_benchmark_links(pages, anchors) == ["guide/x.md: [benchmarks: study] -> the top of the page",
                                                   "guide/x.md: [b] -> no-such"]


def test_long_commands_wrap_in_the_built_pages(built):
    """A shell block's long command wraps (pre-wrap) rather than running off behind a scroll bar."""
    css = (built / "_static" / "simlidar.css").read_text()
    rule = css[css.index("div.highlight-sh pre"):]
    assert "white-space: pre-wrap" in rule[:rule.index("}")]
    page = (built / "guide" / "hemispherical.html").read_text()
    assert "_static/simlidar.css" in page and 'class="highlight-sh' in page
