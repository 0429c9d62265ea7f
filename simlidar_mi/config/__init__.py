"""Scene files (TOML) → validated, typed settings.

A scene file is a TOML document whose sections are listed in
:data:`simlidar_mi.config.keys.SECTIONS`; every
key has a type, a default and a check, and anything else is refused with the file,
the dotted key and the value.  ``--set section.key=value`` overrides are parsed as
TOML values and validated the same way.

Example (``scenes/apple_orchard.toml``)::

    [scene]
    seed = 2013
    representation = "mesh"
    facets = 8

    [orchard]
    n_trees = 4
    [orchard.tree]
    iterations = 5
    stochastic = true

    [scan]
    x0_m = 1.0
    z0_m = 1.0
"""
from __future__ import annotations

import copy
import hashlib
import json
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .checks import decode_toml, parse_toml, tomllib  # noqa: F401  (tomllib: tomli on Python 3.10, for callers)
from .keys import ARRAY_SECTIONS, FLOAT, PRIMITIVE_NEEDS, SECTIONS, Key
from ..errors import ConfigError, SimlidarWarning
from .presets import apply_preset


@dataclass
class SceneConfig:
    """A validated scene file: ``sections[name][key]`` with defaults filled in."""

    path: Path | None
    sections: dict[str, dict[str, Any]]
    arrays: dict[str, list[dict[str, Any]]]
    present: set[str] = field(default_factory=set)
    sha256: str = ""  # what the scene says, execution knobs left out (_scene_digest)
    overridden: dict[str, str] = field(default_factory=dict)  # dotted key → "--set key=value"
    given: set[str] = field(default_factory=set)  # dotted keys the file or an override set (not defaults)
    from_preset: dict[str, str] = field(default_factory=dict)  # dotted key → the sensor preset that gave it

    @property
    def source(self) -> str:
        return str(self.path) if self.path else "<scene>"

    def __getitem__(self, section: str) -> dict[str, Any]:
        return self.sections[section]

    @property
    def declared(self) -> set[str]:
        """The sections that make the scene what it is: :attr:`present` less the tables that
        hold execution knobs alone (its identity: ``sha256``, the study's row keys)."""
        return _declared(self.present, self.given)

    def has(self, section: str) -> bool:
        """True when the file itself contains ``section`` (not only its defaults)."""
        return section in self.present

    @property
    def seed(self) -> int:
        return int(self.sections["scene"]["seed"])

    def gave(self, key: str) -> bool:
        """True when the scene file or a ``--set`` gave ``key`` ("section.key"), not its default."""
        return key in self.given

    def source_of(self, key: str | None) -> str:
        """Where ``key``'s value came from: its ``--set`` argument, the sensor preset that
        filled it, else the scene file."""
        key = key or ""
        return self.overridden.get(key) or self.from_preset.get(key) or self.source

    def relabel(self, exc: ConfigError) -> ConfigError:
        """``exc`` blaming the ``--set`` argument or sensor preset that gave its key, if one did."""
        where = self.overridden.get(exc.key) or self.from_preset.get(exc.key)
        if where and exc.file in (None, self.source):
            return ConfigError(exc.reason, file=where, key=exc.key, value=exc.value)
        return exc


def _check_value(spec: Key, value: Any, src: str, dotted: str) -> Any:
    if isinstance(value, bool) and bool not in spec.types:
        raise ConfigError(f"expected {_typename(spec.types)}, got a boolean", file=src, key=dotted, value=value)
    if not isinstance(value, spec.types):
        raise ConfigError(f"expected {_typename(spec.types)}, got {type(value).__name__}",
                          file=src, key=dotted, value=value)
    if spec.types == FLOAT:
        value = float(value)
    if spec.range is not None:
        problem = spec.range.complaint(value)
        if problem:
            raise ConfigError(problem, file=src, key=dotted, value=value)
    if spec.check is not None:
        problem = spec.check(value)
        if problem:
            raise ConfigError(problem, file=src, key=dotted, value=value)
    return value


def _typename(types: tuple) -> str:
    names = {int: "an integer", float: "a number", bool: "true/false", str: "a string", list: "a list"}
    if types == FLOAT:
        return "a number"
    return " or ".join(names.get(t, t.__name__) for t in types)


def _flatten(data: dict) -> dict[str, Any]:
    """{'orchard': {'tree': {...}, 'n_trees': 4}} → {'orchard': {'n_trees': 4}, 'orchard.tree': {...}}."""
    out: dict[str, Any] = {}
    for name, value in data.items():
        if not isinstance(value, dict):
            out[name] = value
            continue
        own = {}
        for key, inner in value.items():
            if isinstance(inner, dict) and f"{name}.{key}" in SECTIONS:
                out[f"{name}.{key}"] = inner
            else:
                own[key] = inner
        out[name] = own
    return out


class Override(str):
    """A ``section.key=value`` override that stands for a command-line option: its errors name
    ``label`` (what the user typed, ``--voxel 1e-06``) instead of ``--set section.key=value``."""

    def __new__(cls, item: str, label: str):
        obj = super().__new__(cls, item)
        obj.label = label
        return obj

    def __reduce__(self):
        return (Override, (str(self), self.label))


def parse_override(item: str) -> tuple[str, Any]:
    """'scan.dtheta_deg=0.5' → ('scan.dtheta_deg', 0.5); values are TOML, bare words strings."""
    if "=" not in item:
        raise ConfigError("an override must look like section.key=value", key="--set", value=item)
    if "\n" in item or "\r" in item:  # TOML ends the value there and reads the rest as more lines
        raise ConfigError("an override is one line: it holds a line break, and what follows it would be "
                          "dropped; give each key its own --set", key="--set", value=item)
    key, raw = item.split("=", 1)
    key, raw = key.strip(), raw.strip()
    try:
        value = parse_toml(f"v = {raw}", _label(item), key=key, value=raw)["v"]
    except ConfigError as exc:
        if not exc.reason.startswith("not valid TOML"):
            raise  # nested too deep
        value = raw
    return key, value


def _label(item: str) -> str:
    """How errors name an override: its option, ``--set key=value`` (a long one shortened)."""
    return getattr(item, "label", None) or f"--set {item if len(item) <= 100 else item[:80] + '…'}"


def load_scene(path: str | Path | None = None, overrides: list[str] | tuple = (),
               text: str | None = None) -> SceneConfig:
    """Read, validate and fill in a scene file.

    Parameters
    ----------
    path : the TOML file (or None with ``text``).
    overrides : ``section.key=value`` strings applied after reading.
    text : TOML text instead of a file (notebooks, tests).
    """
    src = str(path) if path is not None else "<scene>"
    if text is None:
        try:
            raw_bytes = Path(path).read_bytes()
        except OSError as exc:
            raise ConfigError(f"cannot read scene file: {exc.strerror or exc}", file=src) from exc
        text = decode_toml(raw_bytes, src)
    data = parse_toml(text, src)

    arrays_raw = {name: data.pop(name) for name in list(data) if name in ARRAY_SECTIONS}
    flat = _flatten(data)
    overridden: dict[str, str] = {}  # errors in an override name the --set argument
    for item in overrides:
        key, value = parse_override(item)
        section, _, leaf = key.rpartition(".")
        label = _label(item)
        if section not in SECTIONS:
            raise ConfigError(f"unknown section '{section}'; valid: {', '.join(SECTIONS)}",
                              file=label, key=key, value=value)
        flat.setdefault(section, {})[leaf] = value
        overridden[f"{section}.{leaf}"] = label
    # [sensor] preset: fills the sensor/platform/scan keys neither the file nor --set gave
    flat, from_preset, skipped = apply_preset(
        flat, src, origin=overridden, base_dir=Path(path).parent if path is not None else Path.cwd(),
        sections=SECTIONS, check=_check_value)
    if skipped:
        warnings.warn(SimlidarWarning(
            f"{src}: [platform] kind {flat['platform']['kind']!r} differs from the kind of sensor preset "
            f"{flat['sensor']['preset']!r}; its {', '.join(skipped)} were not applied"), stacklevel=2)
    origin = {**from_preset, **overridden}  # where each key came from, when not the scene file

    sections: dict[str, dict[str, Any]] = {}
    present: set[str] = set()
    given = {f"{name}.{key}" for name, table in flat.items() if isinstance(table, dict) for key in table}
    for name, table in flat.items():
        if name not in SECTIONS:
            raise ConfigError(f"unknown section or key; valid sections: {', '.join(SECTIONS)}",
                              file=src, key=name, value=table if not isinstance(table, dict) else None)
        if not isinstance(table, dict):
            raise ConfigError("expected a table", file=src, key=name, value=table)
        present.add(name)
    for name, spec in SECTIONS.items():
        table = flat.get(name, {})
        values = {}
        for key, value in table.items():
            where = origin.get(f"{name}.{key}", src)
            if key not in spec:
                raise ConfigError(f"unknown key in [{name}]; valid: {', '.join(spec)}",
                                  file=where, key=f"{name}.{key}", value=value)
            values[key] = _check_value(spec[key], value, where, f"{name}.{key}")
        for key, ks in spec.items():
            values.setdefault(key, copy.deepcopy(ks.default))
        sections[name] = values

    sensor = sections["sensor"]
    if sensor["noise_model"] == "snr" and sensor["range_noise_per_m"] > 0:
        raise ConfigError("applies to noise_model = \"range\" only; the \"snr\" law's σ grows with range "
                          "through the echo energy (set sensor.noise_model = \"range\" for the old law)",
                          file=overridden.get("sensor.range_noise_per_m", src), key="sensor.range_noise_per_m",
                          value=sensor["range_noise_per_m"])
    if sensor["range_max_m"] is not None and not sensor["range_max_m"] > sensor["range_min_m"]:
        raise ConfigError(f"must be greater than sensor.range_min_m ({sensor['range_min_m']} m)",
                          file=overridden.get("sensor.range_max_m", src), key="sensor.range_max_m",
                          value=sensor["range_max_m"])

    arrays: dict[str, list[dict[str, Any]]] = {name: [] for name in ARRAY_SECTIONS}
    arrays_given: dict[str, list[list[str]]] = {}  # the keys each array table gave, for the digest
    for name, items in arrays_raw.items():
        if not isinstance(items, list):
            raise ConfigError(f"[[{name}]] must be an array of tables", file=src, key=name, value=items)
        spec = ARRAY_SECTIONS[name]
        for j, item in enumerate(items):
            values = {}
            for key, value in item.items():
                dotted = f"{name}[{j}].{key}"
                if key not in spec:
                    raise ConfigError(f"unknown key; valid: {', '.join(spec)}", file=src, key=dotted, value=value)
                values[key] = _check_value(spec[key], value, src, dotted)
            arrays_given.setdefault(name, []).append(sorted(values))
            for key, ks in spec.items():
                values.setdefault(key, ks.default)
            arrays[name].append(values)
        present.add(name)
    for j, prim in enumerate(arrays["primitive"]):
        if prim["type"] is None:
            raise ConfigError("missing; valid: cylinder, box, obj, ply", file=src, key=f"primitive[{j}].type")
        for need in PRIMITIVE_NEEDS[prim["type"]]:
            if prim[need] is None:
                raise ConfigError(f"a {prim['type']} primitive needs '{need}'", file=src,
                                  key=f"primitive[{j}].{need}")
    digest = _scene_digest(sections, given, present, arrays, arrays_given)  # paths as written
    for j, prim in enumerate(arrays["primitive"]):
        kind = prim["type"]
        if kind in ("obj", "ply") and not prim["path"].lower().endswith(f".{kind}"):
            what = "a Wavefront OBJ mesh" if kind == "obj" else "a PLY mesh"
            raise ConfigError(f"an {kind} primitive's file name must end in .{kind} ({what})",
                              file=src, key=f"primitive[{j}].path", value=prim["path"])
        if kind in ("obj", "ply") and path is not None:
            prim["path"] = str((Path(path).parent / prim["path"]).resolve())
        mesh_only = [k for k in ("labels", "label_property") if prim[k] is not None]
        if kind not in ("obj", "ply") and mesh_only:
            raise ConfigError(f"only mesh primitives (obj, ply) take '{mesh_only[0]}'", file=src,
                              key=f"primitive[{j}].{mesh_only[0]}", value=prim[mesh_only[0]])
        if prim["labels"] is not None:
            ints = all(isinstance(x, int) for xs in prim["labels"].values() for x in xs)
            if ints != (kind == "ply"):
                raise ConfigError("an obj mesh's labels are name patterns (strings), a ply mesh's are "
                                  "values of label_property (integers)", file=src,
                                  key=f"primitive[{j}].labels", value=prim["labels"])
            if kind == "ply" and prim["label_property"] is None:
                raise ConfigError("a ply mesh's labels need label_property (the face property to read)",
                                  file=src, key=f"primitive[{j}].label_property")
    return SceneConfig(Path(path) if path else None, sections, arrays, present, digest,
                       overridden, given, from_preset)


def _is_knob(dotted: str) -> bool:
    section, _, leaf = dotted.rpartition(".")
    return SECTIONS[section][leaf].knob


def _declared(present: set[str], given: set[str]) -> set[str]:
    """The sections a scene declares, less those that hold execution knobs alone (a [scan]
    table, or a --set, giving only chunk_beams declares nothing about the scene)."""
    knobs_only = {d.rpartition(".")[0] for d in given if _is_knob(d)}
    return present - (knobs_only - {d.rpartition(".")[0] for d in given if not _is_knob(d)})


def _scene_digest(sections: dict, given: set[str], present: set[str], arrays: dict,
                  arrays_given: dict) -> str:
    """SHA-256 of what a scene says: the sections it declares and the values of the keys its
    file, ``--set`` overrides and sensor preset give, as validated (``5e-1`` and ``0.5``
    agree; comments and key order do not count), without the execution knobs
    (:attr:`Key.knob`: chunk sizes and size limits, on which no result depends)."""
    said = {}
    for dotted in given:
        section, _, leaf = dotted.rpartition(".")
        if not _is_knob(dotted):
            said[dotted] = sections[section][leaf]
    present = _declared(present, given)
    tables = {name: [{k: item[k] for k in keys} for item, keys in zip(arrays[name], arrays_given[name])]
              for name in arrays_given}
    text = json.dumps({"sections": sorted(present), "keys": said, "arrays": tables},
                      sort_keys=True, default=str, allow_nan=True)
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def sensor_preset(ref: str | Path, base_dir: str | Path | None = None):
    """A built-in sensor preset (``simlidar-mi sensors`` lists them) or a user preset .toml
    (relative to ``base_dir``, default the working folder), checked against this schema."""
    from .presets import resolve
    return resolve(str(ref) if isinstance(ref, Path) else ref, base_dir=Path(base_dir) if base_dir is not None else Path.cwd(),
                   sections=SECTIONS, check=_check_value, key="preset")
