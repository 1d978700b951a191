"""Reader and writer plugins. The reader table below is the one place formats are chosen.

:func:`open_log` picks a reader by ``--format``, else by content (each entry's ``sniff`` looks
at the first decompressed bytes), else by file suffix.
"""

from __future__ import annotations

import functools
import importlib
import warnings
from collections.abc import Callable, Iterator
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from dynslam_cli.errors import InputError, SeveralTopicsError
from dynslam_formats.base import ROS_ONLY_OPTIONS, LogReader, ReaderOptions, ReadStats
from dynslam_formats.guard import guarded
from dynslam_formats.source import Source

__all__ = ["READERS", "LogReader", "ReadStats", "ReaderEntry", "ReaderOptions", "Source",
           "all_readers", "describe_log", "open_log"]


@dataclass(frozen=True)
class ReaderEntry:
    """One row of the reader table."""

    name: str
    description: str
    suffixes: tuple[str, ...]
    sniff: Callable[[bytes], bool]
    factory: Callable[[Source, ReaderOptions], LogReader]
    folder_marker: str | None = None
    """A file whose presence in a folder makes the folder a log of this format."""


def _lazy(module: str, name: str) -> Callable[..., Any]:
    """A function that imports ``module`` on first call and calls its ``name``, so the
    table costs nothing until a format is used (and ``--help`` stays fast)."""

    def call(*args: Any) -> Any:
        return getattr(importlib.import_module(module), name)(*args)

    return call


READERS: tuple[ReaderEntry, ...] = (
    ReaderEntry("carmen", "Carmen / Radish / Freiburg log (FLASER, ROBOTLASER, RAWLASER...)",
                (".log", ".clf", ".gfs.log", ".gfs"), _lazy("dynslam_formats.carmen", "sniff"),
                _lazy("dynslam_formats.carmen", "CarmenReader")),
    ReaderEntry("player", "Player writelog text log (file versions 0.0, 0.2, 0.3)",
                (".playerlog",), _lazy("dynslam_formats.player", "sniff"),
                _lazy("dynslam_formats.player", "PlayerReader")),
    ReaderEntry("ros", "ROS1 .bag, ROS2 bag folder or .db3 (rosbags)",
                (".bag", ".db3"), _lazy("dynslam_formats.ros", "sniff"),
                _lazy("dynslam_formats.ros", "RosbagsReader"), folder_marker="metadata.yaml"),
    ReaderEntry("mcap", "MCAP file: ros2 profile via rosbags, others (ROS1 in MCAP) via mcap",
                (".mcap",), _lazy("dynslam_formats.mcap_plain", "sniff"),
                _lazy("dynslam_formats.mcap_plain", "McapReader")),
)


PLUGIN_GROUP = "dynslam.readers"


@functools.cache
def all_readers() -> tuple[ReaderEntry, ...]:
    """The built-in table, then readers other installed packages register under the
    ``dynslam.readers`` entry-point group (each entry point names a :class:`ReaderEntry`)."""
    from importlib.metadata import entry_points  # 25 ms: only when plugins are consulted

    plugins = []
    for ep in sorted(entry_points(group=PLUGIN_GROUP), key=lambda e: e.name):
        try:
            entry = ep.load()
        except Exception as e:  # a broken plugin must not break the built-in formats
            warnings.warn(f"dynslam reader plugin {ep.name!r} failed to load: {e}",
                          stacklevel=2)
            continue
        if isinstance(entry, ReaderEntry):
            plugins.append(entry)
        else:
            warnings.warn(f"dynslam reader plugin {ep.name!r} is not a ReaderEntry",
                          stacklevel=2)
    return READERS + tuple(plugins)


def _in_order() -> Iterator[ReaderEntry]:
    """:func:`all_readers` in order, loading the plugins only once the table is exhausted."""
    yield from READERS
    yield from all_readers()[len(READERS):]


def reader_names() -> list[str]:
    return [entry.name for entry in all_readers()]


def detect_format(source: Source) -> ReaderEntry:
    """The table entry whose sniffer accepts the content, else whose suffix matches."""
    if source.is_dir:
        for entry in _in_order():
            if entry.folder_marker and (Path(source.path) / entry.folder_marker).exists():
                return entry
        raise InputError(source.name, "a folder, but not a ROS2 bag (no metadata.yaml)")
    for entry in _in_order():
        if source.head and entry.sniff(source.head):
            return entry
    for entry in _in_order():
        if source.plain_path.endswith(entry.suffixes):
            return entry
    if not source.head:
        raise InputError(source.name, "empty log: no records at all")
    raise InputError(source.name, "cannot tell the log format from its content or name; "
                     f"name it with --format ({', '.join(reader_names())})")


def open_log(path: str, options: ReaderOptions, format_name: str | None = None
             ) -> tuple[Source, ReaderEntry, LogReader]:
    """Open ``path`` (``-`` for standard input) and build its reader."""
    source = Source(path)
    try:
        if format_name is None:
            entry = detect_format(source)
        else:
            entry = next((e for e in all_readers() if e.name == format_name), None)  # type: ignore[assignment]
            if entry is None:
                raise InputError(source.name, f"unknown format {format_name!r}; known: "
                                 f"{', '.join(reader_names())}")
        return source, entry, guarded(entry.factory(source, options), options, source.name)
    except BaseException:
        source.close()
        raise


def describe_log(path: str, options: ReaderOptions, format_name: str | None = None
                 ) -> dict[str, object]:
    """What a log holds, read through its reader (so it works for every format, plugins
    included): records or topics with counts, scans, beams, field of view, max range,
    duration, whether it carries odometry, and the laser's mount on the robot (x, y
    metres, heading degrees; each one the log states, up to MAX_MOUNTS). A bag with
    several LaserScan (or Odometry) topics and no option choosing one is described topic
    by topic, under ``topics``, with the option ``process`` needs: the same rule as
    processing, never a silent pick."""
    try:
        return _describe(path, options, format_name)
    except SeveralTopicsError as e:
        field = next(f for f, option in ROS_ONLY_OPTIONS if option == e.option)
        each = {t: describe_log(path, replace(options, **{field: t}), format_name)
                for t in sorted(e.counts)}
        shared = ("path", "format", "records")
        return {**{k: next(iter(each.values()))[k] for k in shared}, "choose_with": e.option,
                "topics": {t: {k: v for k, v in d.items() if k not in shared}
                           for t, d in each.items()}}


MAX_MOUNTS = 4  # dynslam info lists this many of a log's laser mounts


def _describe(path: str, options: ReaderOptions, format_name: str | None
              ) -> dict[str, object]:
    import math

    source, entry, reader = open_log(path, options, format_name)
    n, beams, fovs, max_ranges, odometry, mounts = 0, set(), set(), set(), False, set()
    first = last = math.nan
    try:
        for scan in reader.scans():
            if n == 0:
                first = scan.stamp
            last = scan.stamp
            n += 1
            beams.add(len(scan.ranges))
            if len(scan.angles) > 1:
                fovs.add(round(math.degrees(abs(scan.angles[-1] - scan.angles[0])), 2))
            max_ranges.add(round(scan.max_range, 3))
            odometry = odometry or scan.has_odometry
            if len(mounts) <= MAX_MOUNTS:
                laser = scan.laser
                mounts.add((round(laser.x, 4) + 0.0, round(laser.y, 4) + 0.0,  # (no -0.0)
                            round(math.degrees(laser.theta), 2) + 0.0))
    finally:
        source.close()
    topics = getattr(reader, "topics", None)
    return {"path": source.name, "format": entry.name,
            **({"scan_topic": topics[0], "odom_topic": topics[1]} if topics else {}),
            "records": reader.stats.to_dict()["records"], "scans": n,
            "beams": sorted(beams), "fov_deg": sorted(fovs), "max_range_m": sorted(max_ranges),
            "duration_s": round(last - first, 3) if n else 0.0, "odometry": odometry,
            "laser_mount": ([list(m) for m in sorted(mounts)] if len(mounts) <= MAX_MOUNTS
                            else f"more than {MAX_MOUNTS} (a moving mount)"),
            "skipped": dict(reader.stats.skipped), "warnings": dict(reader.stats.warnings)}
