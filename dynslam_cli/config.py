"""Every algorithm parameter, with its unit, in one frozen dataclass tree.

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
from dynslam_cli.localization.corners import CornerConfig
from dynslam_cli.localization.cornerslam import EkfConfig
from dynslam_cli.localization.loops import LoopConfig
from dynslam_cli.localization.scanmatch import MatchConfig
from dynslam_cli.mapping.changes import ChangeConfig
from dynslam_cli.mapping.grid import LOGODDS_STEP, MAX_LOGODDS
from dynslam_cli.types import Scan


@dataclass(frozen=True)
class MapConfig:
    """Occupancy grids: geometry and the inverse sensor model of an ordinary grid."""

    resolution_m: float = 0.05
    """Cell edge length (metres)."""
    p_hit: float = 0.85
    """Inverse sensor model value for a cell where a beam ended (probability)."""
    p_miss: float = 0.35
    """Inverse sensor model value for a cell a beam passed through (probability)."""
    p_clamp_min: float = 0.02
    """The lowest probability a cell can hold: log-odds are clamped to [logit(p_clamp_min),
    logit(p_clamp_max)] so maps stay revisable."""
    p_clamp_max: float = 0.98
    """The highest probability a cell can hold."""
    free_threshold: float = 0.1
    """A cell with p below this is Free (paper Sec. 3.1: 0.1)."""
    occupied_threshold: float = 0.9
    """A cell with p above this is Occupied (paper Sec. 3.1: 0.9)."""
    grow_margin_m: float = 10.0
    """When the robot leaves the grid, it grows by at least this much on that side (metres)."""
    max_extent_m: float = 2000.0
    """The map may span at most this much in x and in y (metres); a run whose map would grow
    beyond stops with an error (an odometry jump, a unit error)."""


@dataclass(frozen=True)
class LaserConfig:
    """How readings are interpreted."""

    min_range_m: float = 0.02
    """Readings at or below this are invalid (SICK error codes are often 0) and dropped."""
    max_range_m: float | None = None
    """Override the log's max range (metres); readings at or above it are 'no return'."""
    clear_cap_m: float = 10.0
    """A no-return beam clears free space up to this distance (metres) and marks no hit."""
    fov_deg: float | None = None
    """Field of view for logs whose records carry no beam angles (old FLASER), overriding
    CARMEN's rule (degrees). The first beam is at -fov/2, beams evenly spaced."""

    def limit(self, scan: Scan) -> Scan:
        """The scan with ``max_range_m`` as its max range where set, so every consumer
        (scan matching, corners, loop closure, the maps) sees the same no-return rule."""
        if self.max_range_m is None or scan.max_range == self.max_range_m:
            return scan
        return dataclasses.replace(scan, max_range=self.max_range_m)


@dataclass(frozen=True)
class DynamicConfig:
    """The dynamic map D (paper Sec. 3.2) and the neighbourhood rule (Sec. 5).

    S uses the ``[map]`` values: ``p_hit`` is Table 1's *high*, ``p_miss`` its *low*.
    """

    enabled: bool = True
    """False: one ordinary occupancy grid, D stays empty (``--no-dynamic``, paper Fig. 3b)."""
    p_high: float = 0.97
    """Table 2's *high*: a hit where S was Free (probability); two in a row make a cell
    Occupied in D from Free."""
    p_low: float = 0.0001
    """Table 2's *low*. Very low so one free observation clears D: D keeps no history."""
    p_clamp_min: float = 0.05
    """The lowest probability a cell of D can hold (its log-odds clamped, as S's)."""
    p_clamp_max: float = 0.99
    """The highest probability a cell of D can hold."""
    neighbourhood_m: float = 0.1
    """An end point is compared with S^{t-1} over a square window of this half-width
    (metres), so small pose or rounding errors do not turn walls dynamic (Sec. 5)."""


@dataclass(frozen=True)
class RecordConfig:
    """A recording of the run for Foxglove and RViz (``--record``; see
    dynslam_formats.recording): an MCAP file in the output folder or at a path."""

    file: str | None = None
    """The recording, ending in .mcap (``--record``): a bare file name is written in the
    output folder, a path (``~/runs/today.mcap``) there, atomically; unset: no recording."""
    period_s: float = 5.0
    """The maps, paths and landmarks are sent at most once every this many seconds of log
    time, when they changed, and once at the end (``--record-period``)."""


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

    def validate(self) -> Config:
        """Check value ranges; returns self so calls chain."""
        m = self.map
        checks = [
            (0.005 <= m.resolution_m <= 10, "map.resolution_m must be in [0.005, 10] m"),
            (m.max_extent_m > 0, "map.max_extent_m must be > 0"),
            (0.5 < m.p_hit < 1, "map.p_hit must be in (0.5, 1)"),
            (0 < m.p_miss < 0.5, "map.p_miss must be in (0, 0.5)"),
            (0 < m.p_clamp_min < 0.5 < m.p_clamp_max < 1,
             "map clamp must be 0 < p_clamp_min < 0.5 < p_clamp_max < 1"),
            (0 < m.free_threshold < 0.5 < m.occupied_threshold < 1,
             "map thresholds must be 0 < free_threshold < 0.5 < occupied_threshold < 1"),
            (m.grow_margin_m > 0, "map.grow_margin_m must be > 0"),
            (self.laser.clear_cap_m > 0, "laser.clear_cap_m must be > 0"),
            (self.laser.min_range_m >= 0, "laser.min_range_m must be >= 0"),
            (self.laser.max_range_m is None or self.laser.max_range_m > 0,
             "laser.max_range_m must be > 0"),
            (self.laser.fov_deg is None or 0 < self.laser.fov_deg <= 360,
             "laser.fov_deg must be in (0, 360]"),
        ]
        d = self.dynamic
        checks += [
            (0.5 < d.p_high < 1, "dynamic.p_high must be in (0.5, 1)"),
            (0 < d.p_low < 0.5, "dynamic.p_low must be in (0, 0.5)"),
            (0 < d.p_clamp_min < 0.5 < d.p_clamp_max < 1,
             "dynamic clamp must be 0 < p_clamp_min < 0.5 < p_clamp_max < 1"),
            (0 <= d.neighbourhood_m <= 1.0, "dynamic.neighbourhood_m must be in [0, 1] m"),
        ]
        e, c = self.ekf, self.corners
        checks += [
            (e.localization in ("ekf", "odometry"), "ekf.localization must be ekf or odometry"),
            (e.gate_chi2 > 0 and e.search_radius_m > 0, "ekf gate values must be > 0"),
            (e.confirm_observations >= 1, "ekf.confirm_observations must be >= 1"),
            (e.max_landmarks >= 1, "ekf.max_landmarks must be >= 1"),
            (c.min_points >= 3 and c.min_length_m > 0, "corners: min_points >= 3, length > 0"),
            (0 < c.min_angle_deg < 90, "corners.min_angle_deg must be in (0, 90)"),
        ]
        mc = self.match.correlative
        checks += [
            (self.match.method in ("icp", "correlative"),
             "match.method must be icp or correlative"),
            (0.005 <= mc.resolution_m <= 0.5 and mc.field_sigma_m > 0,
             "match.correlative: resolution_m must be in [0.005, 0.5] m, field_sigma_m > 0"),
            (0 < mc.outlier_share < 1, "match.correlative.outlier_share must be in (0, 1)"),
            (mc.effective_points > 0 and mc.window_sigmas > 0,
             "match.correlative: effective_points and window_sigmas must be > 0"),
            (0 < mc.min_window_m <= mc.max_window_m <= 5
             and 0 < mc.min_window_deg <= mc.max_window_deg <= 180,
             "match.correlative: 0 < min_window <= max_window (at most 5 m and 180 deg)"),
        ]
        lp = self.loop
        checks += [
            (lp.node_distance_m > 0 and lp.node_angle_deg > 0,
             "loop.node_distance_m and node_angle_deg must be > 0"),
            (lp.pending_closures >= 1, "loop.pending_closures must be >= 1"),
            (lp.online_nodes >= 2, "loop.online_nodes must be >= 2"),
            (lp.online_flops > 0, "loop.online_flops must be > 0"),
        ]
        ch = self.changes
        checks += [
            (min(ch.blob_gap_m, ch.track_gate_m, ch.merge_distance_m) > 0,
             "changes: blob_gap_m, track_gate_m and merge_distance_m must be > 0"),
            (min(ch.track_gap_s, ch.still_s, ch.join_gap_s, ch.walker_speed_m_s) >= 0
             and ch.moving_speed_m_s > 0,
             "changes: track_gap_s, still_s, join_gap_s and walker_speed_m_s must be >= 0, "
             "moving_speed_m_s > 0"),
            (ch.min_scans >= 1 and ch.min_area_m2 >= 0 and ch.max_object_m2 > 0,
             "changes: min_scans must be >= 1, min_area_m2 >= 0, max_object_m2 > 0"),
        ]
        r = self.record
        checks += [
            (r.period_s > 0, "record.period_s must be > 0"),
            (r.file is None or (r.file.endswith(".mcap") and len(Path(r.file).name) > 5),
             f"record.file must be a file name or path ending in .mcap (a bare name is written "
             f"in the output folder), not {r.file!r}"),
        ]
        checks += [(_storable(values), f"{name}: {_STORABLE}") for name, values in (
            ("map", (m.p_hit, m.p_miss, m.p_clamp_min, m.p_clamp_max)),
            ("dynamic", (d.p_high, d.p_low, d.p_clamp_min, d.p_clamp_max)))]
        for ok, message in checks:
            if not ok:
                raise ConfigError(message)
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


def _build(cls: type, values: dict[str, Any], where: str) -> Any:
    hints = typing.get_type_hints(cls)
    known = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(values) - known)
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
