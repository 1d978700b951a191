"""Reader and writer plugins. The reader table below is the one place formats are chosen.

:func:`open_log` picks a reader by ``--format``, else by content (each entry's ``sniff`` looks
at the first decompressed bytes), else by file suffix.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from dynslam_cli.errors import InputError
from formats.base import LogReader, ReaderOptions, ReadStats, Source

__all__ = ["READERS", "LogReader", "ReadStats", "ReaderEntry", "ReaderOptions", "Source",
           "open_log"]


@dataclass(frozen=True)
class ReaderEntry:
    """One row of the reader table."""

    name: str
    description: str
    suffixes: tuple[str, ...]
    sniff: Callable[[bytes], bool]
    factory: Callable[[Source, ReaderOptions], LogReader]


def _carmen(source: Source, options: ReaderOptions) -> LogReader:
    from formats.carmen import CarmenReader

    return CarmenReader(source, options)


def _carmen_sniff(head: bytes) -> bool:
    from formats.carmen import sniff

    return sniff(head)


def _player(source: Source, options: ReaderOptions) -> LogReader:
    from formats.player import PlayerReader

    return PlayerReader(source, options)


def _player_sniff(head: bytes) -> bool:
    from formats.player import sniff

    return sniff(head)


def _ros(source: Source, options: ReaderOptions) -> LogReader:
    from formats.ros import RosbagsReader

    return RosbagsReader(source, options)


def _ros_sniff(head: bytes) -> bool:
    from formats.ros import sniff

    return sniff(head)


READERS: tuple[ReaderEntry, ...] = (
    ReaderEntry("carmen", "Carmen / Radish / Freiburg log (FLASER, ROBOTLASER, RAWLASER...)",
                (".log", ".clf", ".gfs.log", ".gfs"), _carmen_sniff, _carmen),
    ReaderEntry("player", "Player writelog text log (file versions 0.0, 0.2, 0.3)",
                (".playerlog",), _player_sniff, _player),
    ReaderEntry("ros", "ROS1 .bag, ROS2 bag folder / .db3 / .mcap (rosbags)",
                (".bag", ".db3", ".mcap"), _ros_sniff, _ros),
)


def reader_names() -> list[str]:
    return [entry.name for entry in READERS]


def detect_format(source: Source) -> ReaderEntry:
    """The table entry whose sniffer accepts the content, else whose suffix matches."""
    for entry in READERS:
        if source.head and entry.sniff(source.head):
            return entry
    stem = source.path[:-3] if source.path.endswith(".gz") else source.path
    for entry in READERS:
        if any(stem.endswith(s) for s in entry.suffixes):
            return entry
    if not source.head and not source.is_dir:
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
            entry = next((e for e in READERS if e.name == format_name), None)  # type: ignore[assignment]
            if entry is None:
                raise InputError(source.name, f"unknown format {format_name!r}; known: "
                                 f"{', '.join(reader_names())}")
        return source, entry, entry.factory(source, options)
    except BaseException:
        source.close()
        raise
