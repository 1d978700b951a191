"""Every algorithm parameter, with its unit, in one frozen dataclass tree: :class:`Config`,
whose sections (dynslam_cli.sections) each part of the program takes on its own.

A TOML file overrides any of them section by section, e.g.::

    [map]
    resolution_m = 0.1

    [laser]
    clear_cap_m = 15.0

Unknown sections or keys, and values of the wrong type, are errors (:class:`ConfigError`).
The effective configuration is written to ``summary.json`` beside the outputs.
"""

from __future__ import annotations

import ast
import dataclasses
import inspect
import itertools
import json
import math
import tomllib
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from dynslam_cli.errors import ConfigError
from dynslam_cli.mapping.grid import LOGODDS_STEP, MAX_LOGODDS
from dynslam_cli.sections import (
    ChangeConfig,
    CornerConfig,
    DynamicConfig,
    EkfConfig,
    LaserConfig,
    LoopConfig,
    MapConfig,
    MatchConfig,
    PriorConfig,
    RecordConfig,
    require,
)


@dataclass(frozen=True)
class Config:
    """All parameters of one run."""

    map: MapConfig = field(default_factory=MapConfig)
    laser: LaserConfig = field(default_factory=LaserConfig)
    dynamic: DynamicConfig = field(default_factory=DynamicConfig)
    corners: CornerConfig = field(default_factory=CornerConfig)
    ekf: EkfConfig = field(default_factory=EkfConfig)
    match: MatchConfig = field(default_factory=MatchConfig)
    loop: LoopConfig = field(default_factory=LoopConfig)
    changes: ChangeConfig = field(default_factory=ChangeConfig)
    record: RecordConfig = field(default_factory=RecordConfig)
    prior: PriorConfig = field(default_factory=PriorConfig)

    def validate(self) -> Config:
        """Check value ranges (each section its own, then that the inverse models fit the
        grids' storage); returns self so calls chain."""
        for section in (self.map, self.laser, self.dynamic, self.ekf, self.corners,
                        self.match, self.loop, self.changes, self.record, self.prior):
            section.check()
        m, d = self.map, self.dynamic
        require([(_storable(values), f"{name}: {_STORABLE}") for name, values in (
            ("map", (m.p_hit, m.p_miss, m.p_clamp_min, m.p_clamp_max)),
            ("dynamic", (d.p_high, d.p_low, d.p_clamp_min, d.p_clamp_max)))])
        return self

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


_STORABLE = (f"the grids store log-odds as int16 steps of {LOGODDS_STEP:g}: the high and "
              f"low values must be at least one step from 0 in log-odds, the clamps within "
              f"±{MAX_LOGODDS:.1f} (p at least 1.3e-14 from 0 and 1)")


def _storable(probabilities: tuple[float, float, float, float]) -> bool:
    """Whether an inverse model (high, low, clamp min, clamp max; in (0, 1)) fits the
    grid's int16 log-odds: each value moves a cell, each clamp can be stored."""
    if not all(0 < p < 1 for p in probabilities):
        return True  # (the range checks say so)
    high, low, lo, hi = (math.log(p / (1 - p)) for p in probabilities)
    return (min(abs(high), abs(low)) >= LOGODDS_STEP
            and max(abs(lo), abs(hi)) <= MAX_LOGODDS)


def _coerce(value: Any, annotation: Any, where: str) -> Any:
    """Check a TOML value against a field's type annotation (float accepts int)."""
    allowed = typing.get_args(annotation) if isinstance(annotation, types.UnionType) else (
        annotation,)
    for t in allowed:
        if t is type(None) and value is None:
            return None
        if t is float and isinstance(value, int | float) and not isinstance(value, bool):
            if not math.isfinite(value):
                break
            return float(value)
        if t in (int, str, bool) and type(value) is t:
            return value
    names = " or ".join(getattr(t, "__name__", str(t)) for t in allowed)
    raise ConfigError(f"{where}: expected {names}, got {value!r}")


_MOVED = {MatchConfig: {name: "[match.icp]" for name in (
    "iterations", "max_correspondence_m", "min_correspondence_m", "effective_pairs",
    "prior_as_pairs")}}
"""Keys that left a section, and the section that holds them now."""


def _build(cls: type, values: dict[str, Any], where: str) -> Any:
    hints = typing.get_type_hints(cls)
    known = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(values) - known)
    moved = _MOVED.get(cls, {})
    for name in unknown:
        if name in moved:
            raise ConfigError(f"{where}: {name} is in {moved[name]} now")
    if unknown:
        raise ConfigError(f"{where}: unknown key(s) {', '.join(unknown)}; known: "
                          f"{', '.join(sorted(known))}")
    kwargs = {}
    for name, value in values.items():
        hint = hints[name]
        if dataclasses.is_dataclass(hint):
            if not isinstance(value, dict):
                raise ConfigError(f"{where}[{name}] must be a table")
            kwargs[name] = _build(hint, value, f"{where}[{name}]")
        else:
            kwargs[name] = _coerce(value, hint, f"{where}: {name}")
    return cls(**kwargs)


def load_config(path: Path | None = None, overrides: dict[str, dict[str, Any]] | None = None
                ) -> Config:
    """Defaults, then the TOML file at ``path``, then ``overrides`` ({section: {key: value}})."""
    values: dict[str, dict[str, Any]] = {}
    where = "config"
    if path is not None:
        where = str(path)
        try:
            with open(path, "rb") as f:
                values = tomllib.load(f)
        except OSError as e:
            raise ConfigError(f"{path}: cannot read: {e.strerror}") from None
        except tomllib.TOMLDecodeError as e:
            raise ConfigError(f"{path}: not valid TOML: {e}") from None
    for section, items in (overrides or {}).items():
        values.setdefault(section, {}).update(items)
    return _build(Config, values, where).validate()


def _field_docs(cls: type) -> dict[str, str]:
    """The docstring under each field of a dataclass (read from its source)."""
    docs: dict[str, str] = {}
    body = ast.parse(inspect.getsource(cls)).body[0].body  # type: ignore[attr-defined]
    for node, after in itertools.pairwise(body):
        if (isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name)
                and isinstance(after, ast.Expr) and isinstance(after.value, ast.Constant)
                and isinstance(after.value.value, str)):
            docs[node.target.id] = " ".join(after.value.value.split())
    return docs


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return json.dumps(value)
    return repr(value)


def _comment(text: str, width: int = 92) -> list[str]:
    lines, line = [], "#"
    for word in text.split():
        if len(line) + 1 + len(word) > width:
            lines.append(line)
            line = "#"
        line += " " + word
    return [*lines, line] if line != "#" else lines


def _class_doc(cls: type) -> str:
    doc = inspect.getdoc(cls) or ""
    return "" if doc.startswith(cls.__name__ + "(") else doc.split("\n\n")[0]  # not dataclass's


def _table_toml(name: str, table: Any) -> list[str]:
    """One TOML table (and its nested tables after it), each key under its docstring."""
    out = ["", *_comment(_class_doc(type(table))), f"[{name}]"]
    docs = _field_docs(type(table))
    nested = []
    for f in dataclasses.fields(table):
        value = getattr(table, f.name)
        if dataclasses.is_dataclass(value):
            nested.append((f"{name}.{f.name}", value, docs.get(f.name, "")))
            continue
        out += _comment(docs.get(f.name, ""))
        out.append(f"# {f.name} =    (unset by default; give a value to use it)"
                   if value is None else f"{f.name} = {_toml_value(value)}")
    for sub, value, doc in nested:
        lines = _table_toml(sub, value)
        out += [lines[0], *_comment(doc), *lines[1:]]
    return out


def to_toml(config: Config | None = None) -> str:
    """Every parameter as TOML, each under its meaning and unit (the field's docstring); a
    parameter that is unset by default (None) is written commented out. ``--config``
    accepts the result unchanged."""
    config = config or Config()
    out = ["# dynslam configuration: every parameter with its default, unit and meaning.",
           "# Keep what you change (dynslam process LOG --config FILE.toml); unknown keys",
           "# are errors. The effective values of a run are in its summary.json."]
    for section in dataclasses.fields(config):
        out += _table_toml(section.name, getattr(config, section.name))
    return "\n".join(out) + "\n"
