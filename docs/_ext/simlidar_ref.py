"""References generated from the code at build time: the scene-file keys and the sensor presets.

The scene-file schema (:data:`simlidar_mi.config.keys.SECTIONS` and ``ARRAY_SECTIONS``) is the one
source of the key reference: each :class:`~simlidar_mi.config.keys_base.Key` gives the type, the
default and the one-line meaning; the unit is read from the key's name (the project names every
quantity with its unit: ``_m``, ``_deg``, ``_hz`` ...); the allowed range is the key's
``Key.range`` (:mod:`simlidar_mi.config.bounds`, the interval checked at load) and what its check
adds, read from the check's own complaint, the text a user sees when a value is refused. :func:`problems` lists what the schema
lacks (``tests/test_docs.py`` fails on any).

Directives (usable from MyST pages as ```` ```{scene-keys} ````):

- ``scene-keys``: one section per ``[section]`` / ``[[array]]`` table with a table of its keys;
- ``sensor-presets``: a summary table, then every preset's values with their sources;
- ``cli-commands``: every command of :func:`simlidar_mi.cli.build_parser` with its usage and a
  table of its arguments. Help texts are plain text (they are written for a terminal), so they
  are shown as text, never parsed as markup (``estimates/*.nc`` stays as it is).
"""
from __future__ import annotations

import argparse
import math
import re
import types
from dataclasses import dataclass

from docutils import nodes
from docutils.parsers.rst import Directive

# name suffix -> unit, longest first (``speed_m_s`` is m/s, not s)
UNIT_SUFFIXES = (
    ("_m_s", "m/s"), ("_per_m2", "m⁻²"), ("_per_m", "m⁻¹"), ("_m2", "m²"), ("_mrad", "mrad"),
    ("_deg", "°"), ("_hz", "Hz"), ("_us", "µs"), ("_ns", "ns"), ("_nm", "nm"), ("_gb", "GB"), ("_m", "m"), ("_s", "s"),
)

#: Number-valued keys whose name carries no unit because the quantity has none, and what stands
#: in the unit column instead ("1": a ratio, share or reflectance; "count"; "—": no quantity).
NO_UNIT = {
    **{f"materials.{k}": "1" for k in ("wood", "leaf", "ground")},
    "primitive.reflectance": "1",
    "photo_render.leaf_rgb": "1", "photo_render.soil_rgb": "1",
    "photo_render.sun_irradiance": "relative", "photo_render.sky_radiance": "relative",
    "photo_render.exposure": "1",
    "orchard.leaves.defoliation": "1", "orchard.leaves.outer_weight": "1",
    "orchard.leaves.width_ratio_mean": "1", "orchard.leaves.width_ratio_sd": "1",
    "forest.crown_factor": "1", "forest.scale_range": "1", "forest.max_candidate_factor": "1",
    **{f"species.{k}_tree_cv": "1" for k in ("leaf_length", "n_daughters", "leaves_per_branch")},
    "lai_methods.pai_sat": "1", "lai_methods.wood_to_total": "1",
    "gapfraction.window_fraction": "1", "gapfraction.mask_threshold": "1",
    "sensor.detection_threshold": "1", "sensor.noise_ref_snr": "1", "sensor.threshold_snr": "1",
    "strawberry.leaves_per_plant_mean": "count", "strawberry.leaves_per_plant_sd": "count",
    "strawberry.extraction_fractions": "1", "strawberry.extraction_counts": "count",
    **{f"strawberry.leaf.{k}": "1" for k in (
        "b_over_a_mean", "b_over_a_sd", "c_over_b_mean", "c_over_b_sd", "p_over_a_mean",
        "p_over_a_sd", "lateral_area_ratio", "lateral_b_over_a_factor", "lateral_c_over_b_factor")},
    "vineyard.canopy.petiole_length_ratio": "1",
    "platform.scan_legs": "count", "platform.kind": "—",
    "fisheye.coeffs": "1", "fisheye.grid_n": "count",
    "gapfraction.cameras": "—", "species.bumps": "—", "orchard.leaves.angle_distribution": "°, 1",
}

_TYPE_NAMES = {int: "integer", float: "number", bool: "boolean", str: "string", list: "array",
               dict: "table"}


def unit(section: str, name: str) -> str:
    """The key's unit from its name's suffix, else its :data:`NO_UNIT` entry, else ``""``."""
    for suffix, u in UNIT_SUFFIXES:
        if name.endswith(suffix):
            return u
    return NO_UNIT.get(f"{section}.{name}", "")


def needs_unit(key) -> bool:
    """Floats and arrays hold quantities; integers are counts, strings and booleans have none."""
    return float in key.types or list in key.types


def type_name(key) -> str:
    ts = [t for t in key.types if not (t is int and float in key.types)]  # int is accepted for float
    return " or ".join(_TYPE_NAMES.get(t, t.__name__) for t in ts)


def toml_value(v) -> str:
    """A default as it would be written in the scene file (TOML)."""
    if v is None:
        return "—"
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return f'"{v}"'
    if isinstance(v, float):
        return repr(v) if math.isfinite(v) else str(v)
    if isinstance(v, list):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    return str(v)


#: Functions that make checks, whose bounds :func:`key_range` reads from the made check's closure.
FACTORIES = ("at_least", "within", "one_of", "_angle")


class UndescribedCheck(Exception):
    """A key's check whose allowed range cannot be read from the code (see :func:`key_range`)."""


def _complaints(code: types.CodeType) -> list[str]:
    """Whole complaint strings (``"must ..."``) of a check's code, nested code included.

    An f-string's pieces end or start with a space (``"must be one of "``): not whole, left out."""
    out = []
    for c in code.co_consts:
        if isinstance(c, types.CodeType):
            out += _complaints(c)
        elif isinstance(c, str) and c.startswith("must ") and c == c.rstrip():
            out.append(c)
    return out


def key_range(check) -> str:
    """The values a check allows, from the check itself.

    A check made by a factory (``at_least(n)``, ``within(lo, hi)``, ``one_of(...)``) is read from
    the values it closes over; any other check from its docstring or else its complaint strings
    ("must be > 0" -> "> 0"). Raises :class:`UndescribedCheck` when neither is there."""
    if check is None:
        return ""
    cells = dict(zip(check.__code__.co_freevars, (c.cell_contents for c in check.__closure__ or ())))
    if cells and check.__qualname__.split(".<locals>")[0] not in FACTORIES:
        raise UndescribedCheck(f"check {check.__qualname__} closes over {sorted(cells)}")
    if "choices" in cells:
        return "one of " + ", ".join(toml_value(c) for c in cells["choices"])
    if "n" in cells:
        return f"≥ {cells['n']}"
    if {"lo", "hi"} <= set(cells):
        why = cells.get("why")
        return f"[{cells['lo']:g}, {cells['hi']:g}]" + (f" ({why})" if why else "")
    if cells:
        raise UndescribedCheck(f"check {check.__qualname__} closes over {sorted(cells)}")
    if check.__doc__:
        return check.__doc__.strip().splitlines()[0]
    found = _complaints(check.__code__)
    if not found:
        raise UndescribedCheck(f"check {check.__qualname__} has no docstring and no 'must ...' text")
    return "; ".join(_plain(s) for s in found)


def _plain(complaint: str) -> str:
    """'must be > 0' -> '> 0', 'must lie in [0, 1]' -> 'in [0, 1]', 'must not be 0' -> 'not 0'."""
    s = re.sub(r"^must (not be|not) ", "not ", complaint)
    s = re.sub(r"^must (be |lie |hold )?", "", s)
    return {"a finite number": "finite", "finite numbers": "finite"}.get(s, s)


@dataclass(frozen=True)
class KeyRow:
    section: str
    name: str
    array: bool  # a key of an [[array]] table
    type: str
    unit: str
    default: str
    range: str
    doc: str
    knob: bool


def key_rows() -> list[KeyRow]:
    """Every scene-file key, section by section, in the schema's order."""
    from simlidar_mi.config.keys import ARRAY_SECTIONS, SECTIONS
    rows = []
    for tables, array in ((SECTIONS, False), (ARRAY_SECTIONS, True)):
        for section, keys in tables.items():
            for name, key in keys.items():
                try:
                    rng = range_text(key)
                except UndescribedCheck as exc:
                    rng = f"?? {exc}"
                rows.append(KeyRow(section, name, array, type_name(key), unit(section, name),
                                   toml_value(key.default), rng, key.doc, key.knob))
    return rows


def problems() -> list[str]:
    """What the schema lacks for its reference: keys without a description, quantities without a
    unit, checks whose range cannot be read. Empty when the reference is complete."""
    from simlidar_mi.config.keys import ARRAY_SECTIONS, SECTIONS
    out = []
    for tables in (SECTIONS, ARRAY_SECTIONS):
        for section, keys in tables.items():
            for name, key in keys.items():
                where = f"[{section}] {name}"
                if not key.doc.strip():
                    out.append(f"{where}: no description (Key's doc)")
                if needs_unit(key) and not unit(section, name):
                    out.append(f"{where}: a {type_name(key)} with no unit: end its name with the unit "
                               "(_m, _deg, ...) or, if it has none, add it to NO_UNIT")
                try:
                    key_range(key.check)
                except UndescribedCheck as exc:
                    out.append(f"{where}: {exc}")
                if _numeric(section, name, key) and key.range is None:
                    out.append(f"{where}: a number-valued key with no range: add it to "
                               "simlidar_mi/config/bounds.py BOUNDS")
    return out


def _numeric(section: str, name: str, key) -> bool:
    from simlidar_mi.config.bounds import NOT_NUMERIC, numeric
    return f"{section}.{name}" not in NOT_NUMERIC and numeric(key.types, key.default)


#: Checks that say no more than a key's range (its sign, its finiteness, its interval): a key
#: with a range shows the range alone.
_RANGE_ONLY = ("positive", "nonneg", "unit_interval", "_finite", "at_least", "within", "_angle",
               "_below_one", "_opening")


def range_text(key) -> str:
    """What the reference shows as a key's allowed values: its range (``Key.range``, each
    element's for a list) and what its check adds to it, else the check alone."""
    if key.range is None:
        return key_range(key.check)
    rng = key.range.text()
    if list in key.types and not any(t in key.types for t in (int, float)):
        rng = "each " + rng
    if key.check is None or key.check.__qualname__.split(".<locals>")[0] in _RANGE_ONLY:
        return rng
    return f"{rng}; {key_range(key.check)}"


# --- docutils tables ----------------------------------------------------------------------
def _cell(content) -> nodes.entry:
    entry = nodes.entry()
    if isinstance(content, nodes.Node):
        entry += content
    else:
        entry += nodes.paragraph(text=str(content))
    return entry


def table(header: list[str], rows: list[list], widths: list[int] | None = None) -> nodes.table:
    tab = nodes.table(classes=["simlidar-ref"])
    group = nodes.tgroup(cols=len(header))
    tab += group
    for w in widths or [1] * len(header):
        group += nodes.colspec(colwidth=w)
    head = nodes.thead()
    group += head
    r = nodes.row()
    for h in header:
        r += _cell(h)
    head += r
    body = nodes.tbody()
    group += body
    for row in rows:
        r = nodes.row()
        for c in row:
            r += _cell(c)
        body += r
    return tab


def _literal(text: str) -> nodes.paragraph:
    p = nodes.paragraph()
    p += nodes.literal(text=text)
    return p


def _section(document, title: str, ident: str) -> nodes.section:
    sec = nodes.section(ids=[nodes.make_id(ident)], names=[nodes.fully_normalize_name(ident)])
    sec += nodes.title(text=title)
    document.note_explicit_target(sec, sec)  # a label: {ref}`keys-sensor` links to it
    return sec


class SceneKeys(Directive):
    """One section per scene-file table, each with a table of its keys."""

    has_content = False

    def run(self):
        doc = self.state.document
        out = []
        by_section: dict[tuple[str, bool], list[KeyRow]] = {}
        for row in key_rows():
            by_section.setdefault((row.section, row.array), []).append(row)
        for (section, array), rows in by_section.items():
            title = f"[[{section}]]" if array else f"[{section}]"
            sec = _section(doc, title, f"keys-{section}")
            body = [[_literal(r.name), r.type, r.unit,
                     "—" if r.default == "—" else _literal(r.default), r.range, r.doc + (" (execution setting: no result depends on it)" if r.knob else "")]
                    for r in rows]
            sec += table(["key", "type", "unit", "default", "allowed", "meaning"], body,
                         [14, 7, 5, 10, 16, 40])
            out.append(sec)
        return out


class SensorPresets(Directive):
    """A summary of the built-in sensors, then each one's values with their sources."""

    has_content = False

    def run(self):
        from simlidar_mi.config import presets as sp
        doc = self.state.document
        summary = []
        for p in sp.BUILTIN.values():
            v = p.sensor.get("divergence_mrad")
            summary.append([_literal(p.name), p.title, p.kind or "—",
                            "—" if v is None else sp._fmt(v.value)])
        out = [table(["preset", "sensor", "platform kind", "divergence (mrad)"], summary, [12, 30, 8, 8])]
        for p in sp.BUILTIN.values():
            sec = _section(doc, p.name, f"preset-{p.name}")
            sec += nodes.paragraph(text=p.title + (f". {p.note}." if p.note else "."))
            rows = []
            for dotted, v in p.values().items():
                source = p.sources.get(v.source, v.source)
                rows.append([_literal(dotted), _literal(sp._fmt(v.value)),
                             f"{source}" + (f" ({sp.UNCHECKED})" if not v.checked else ""), v.note])
            sec += table(["key", "value", "source", "note"], rows, [14, 12, 30, 30])
            out.append(sec)
        return out


def _usage(parser: argparse.ArgumentParser) -> str:
    fmt = argparse.HelpFormatter(parser.prog, width=88)  # fixed width: the page is the same anywhere
    fmt.add_usage(parser.usage, parser._actions, parser._mutually_exclusive_groups)
    return fmt.format_help().strip()


def _argument_rows(parser: argparse.ArgumentParser) -> list[list]:
    rows = []
    for a in parser._actions:
        if isinstance(a, (argparse._HelpAction, argparse._SubParsersAction)):
            continue
        name = ", ".join(a.option_strings) if a.option_strings else (a.metavar or a.dest)
        if a.option_strings and a.nargs != 0:
            name += " " + (a.metavar or a.dest.upper())
        value = " | ".join(map(str, a.choices)) if a.choices else ""
        quiet = (None, False, [], argparse.SUPPRESS)
        default = "" if a.required or any(a.default is q or a.default == q and type(a.default) is type(q)
                                          for q in quiet) else str(a.default)
        help_ = (a.help or "") + (" (required)" if a.required and a.option_strings else "")
        if "%(" in help_:  # argparse's own placeholders, as --help expands them
            help_ = help_ % {"default": a.default}
        rows.append([_literal(name), value, default, help_])
    return rows


def subcommands(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    """The parser's sub-commands by name, in the order they were added."""
    for a in parser._actions:
        if isinstance(a, argparse._SubParsersAction):
            return dict(a.choices)
    return {}


class CliCommands(Directive):
    """The command line from its parser: the program's options, then one section per command."""

    has_content = False

    def run(self):
        from simlidar_mi.cli import build_parser
        doc = self.state.document
        parser = build_parser()
        out = [nodes.literal_block(text=_usage(parser)),
               table(["argument", "choices", "default", "meaning"], _argument_rows(parser), [16, 10, 8, 40])]
        for name, sub in subcommands(parser).items():
            sec = _section(doc, f"simlidar-mi {name}", f"cli-{name}")
            sec += nodes.paragraph(text=sub.description or "")
            sec += nodes.literal_block(text=_usage(sub))
            sec += table(["argument", "choices", "default", "meaning"], _argument_rows(sub), [16, 10, 8, 40])
            out.append(sec)
        return out


def setup(app):
    app.add_directive("cli-commands", CliCommands)
    app.add_directive("scene-keys", SceneKeys)
    app.add_directive("sensor-presets", SensorPresets)
    return {"parallel_read_safe": True, "parallel_write_safe": True}
