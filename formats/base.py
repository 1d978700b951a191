"""What every reader shares: the options a user gives, the reader interface and its counted
skips and warnings. Opening an input is dynslam_formats.source; the guard every scan passes,
dynslam_formats.guard."""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import ClassVar, Protocol

from dynslam_cli.errors import printable
from dynslam_cli.types import Scan


@dataclass(frozen=True)
class ReaderOptions:
    """Reader choices a user can make on the command line."""

    laser: str = "front"
    """Which laser: Carmen ``front``/``rear``/``3``/``4``; Player a device index."""
    topic: str | None = None
    """ROS: the LaserScan topic (needed when a bag has several)."""
    odom_topic: str | None = None
    """ROS: the nav_msgs/Odometry topic (needed when a bag has several)."""
    fov_deg: float | None = None
    """Field of view for records that carry no beam angles (old Carmen FLASER)."""
    beam_step_deg: float | None = None
    """The angle between two beams (degrees) instead of the log's; the first beam stays."""
    scan_latency_s: float = 0.0
    """How much older a scan's content is than its stamp (and its odometry pose): its
    odometry is taken this much earlier, between the scan's and the one before's."""
    max_range_m: float | None = None
    """The laser's max range instead of the log's (metres): readings at or beyond it are
    'no return'."""
    interlace_s: float | None = None
    """A laser that sweeps its beams in two interlaced passes: the time between them (its
    odd beams turned by the robot's turn in that time); None: estimated from the log."""
    stopped_clock_period_s: float = 1.0
    """Where the log's stamps carry no time, its scans are timed by their order this many
    seconds apart."""
    mount_x_m: float | None = None
    """The laser's mount on the robot instead of the log's: its x (metres, forward) ..."""
    mount_y_m: float | None = None
    """... its y (metres, left) ..."""
    mount_deg: float | None = None
    """... and its heading (degrees); each one set replaces that coordinate alone."""
    start_s: float | None = None
    """Part of a log: leave out scans earlier than this, in seconds after the first scan."""
    end_s: float | None = None
    """... and stop after this many seconds after the first scan."""
    max_scans: int | None = None
    """... and after this many scans."""


ROS_ONLY_OPTIONS = (("topic", "--topic"), ("odom_topic", "--odom-topic"))


def warn_ros_only_options(options: ReaderOptions, stats: ReadStats, log_kind: str) -> None:
    """A counted warning for each ROS-only option given for a log of another kind, which
    ignores it: as readers count what does not apply to them (record types, interfaces)
    rather than fail, and as a batch's ``--topic`` may suit its bags but not its text logs."""
    for name, option in ROS_ONLY_OPTIONS:
        if getattr(options, name) is not None:
            stats.warn(f"{option} applies to ROS logs only: ignored for a {log_kind}")


@dataclass
class ReadStats:
    """Counts of what a reader saw, skipped and warned about, for summary.json and stderr."""

    records: Counter[str] = field(default_factory=Counter)
    skipped: Counter[str] = field(default_factory=Counter)
    warnings: Counter[str] = field(default_factory=Counter)
    first_line: dict[str, int] = field(default_factory=dict)
    scans: int = 0

    def skip(self, reason: str, line: int = 0) -> None:
        """A record was dropped for ``reason`` (counted, reported once with its first line)."""
        self.skipped[reason] += 1
        self.first_line.setdefault(reason, line)

    def warn(self, reason: str, line: int = 0, count: int = 1) -> None:
        """Something odd that did not drop a record (counted, reported once)."""
        self.warnings[reason] += count
        self.first_line.setdefault(reason, line)

    def to_dict(self) -> dict[str, object]:
        return {
            "records": dict(sorted(self.records.items())),
            "scans": self.scans,
            "skipped": dict(sorted(self.skipped.items())),
            "warnings": dict(sorted(self.warnings.items())),
            "first_line": dict(sorted(self.first_line.items())),
        }


@dataclass
class RecordWalk:
    """How far reading a container's records one after another got (a bag whose index, an
    MCAP file whose summary, cannot be used): messages read, the byte where reading stopped,
    and why when that was before the end of its data (None: it read to the end)."""

    messages: int = 0
    stop: int = 0
    damage: str | None = None

    def report(self, stats: ReadStats, size: int) -> None:
        """The damage, if any, as a counted warning saying where it starts."""
        if self.damage is not None:
            stats.warn(f"unreadable from byte {self.stop} of {size} ({printable(self.damage)})"
                       f": the {self.messages} messages before it were read")


class LogReader(Protocol):
    """The interface every reader plugin implements.

    A reader is built from a :class:`Source` and :class:`ReaderOptions`, yields :class:`Scan`
    records in time order from :meth:`scans` (streaming: memory must not grow with the log),
    and counts what it skipped in ``stats``. Bad input raises :class:`InputError`.
    """

    format_name: ClassVar[str]
    stats: ReadStats

    def scans(self) -> Iterator[Scan]: ...
