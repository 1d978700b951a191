"""What every reader shares: opening a source, the reader interface, counted skips."""

from __future__ import annotations

import bz2
import dataclasses
import io
import lzma
import math
import os
import stat
import struct
import sys
import zlib
from collections import Counter, deque
from collections.abc import Callable, Iterator
from contextlib import contextmanager, suppress
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO, ClassVar, Protocol

import numpy as np

from dynslam_cli.errors import InputError, printable
from dynslam_cli.geometry import interpolate, wrap_angle
from dynslam_cli.types import Pose2D, Scan

SNIFF_BYTES = 65536
BINARY_SNIFF_BYTES = 8000  # a NUL byte among the first this many: binary (as git and grep)


@dataclass(frozen=True)
class Compression:
    """A compression a text log may come in, read by Python's standard library."""

    name: str
    suffix: str
    magic: bytes
    decompressor: Callable[[], Any]
    """A new incremental decompressor (``decompress(data, max_length)``), for the head."""
    opener: Callable[[BinaryIO], BinaryIO]
    """The decompressed stream of a binary file object."""
    damaged: tuple[type[Exception], ...]
    """What its decompressor or stream raises on damaged or truncated data (gzip's stream
    raises nothing: it ends where the damage starts and says where,
    :class:`GzipUntilDamaged`)."""


COMPRESSIONS = (
    Compression("gzip", ".gz", b"\x1f\x8b", lambda: zlib.decompressobj(GZIP_WBITS),
                lambda raw: io.BufferedReader(GzipUntilDamaged(raw), GZIP_PIECE),  # type: ignore[return-value]
                (zlib.error,)),
    Compression("bzip2", ".bz2", b"BZh", bz2.BZ2Decompressor,
                lambda raw: bz2.BZ2File(raw),  # type: ignore[return-value]
                (EOFError, OSError)),  # ("Invalid data stream" is an OSError)
    Compression("xz", ".xz", b"\xfd7zXZ\x00", lzma.LZMADecompressor,
                lambda raw: lzma.LZMAFile(raw),  # type: ignore[return-value]  # noqa: SIM115
                (EOFError, lzma.LZMAError)),
)
COMPRESSED_SUFFIXES = tuple(c.suffix for c in COMPRESSIONS)


def compression_of(head: bytes, path: str) -> Compression | None:
    """The compression whose magic bytes start ``head``, else whose suffix ends ``path``."""
    return (next((c for c in COMPRESSIONS if head.startswith(c.magic)), None)
            or next((c for c in COMPRESSIONS if path.endswith(c.suffix)), None))


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


GZIP_WBITS = zlib.MAX_WBITS | 16  # a gzip header and trailer around the deflate stream
GZIP_PIECE = 16384  # compressed bytes fed at a time: the damage is found within this many


class GzipUntilDamaged(io.RawIOBase):
    """A gzip file's decompressed bytes up to where its compressed data ends early (a log cut
    off while written: a robot that crashed) or stops being readable (a bad copy). There the
    stream ends as if the file did, and :attr:`damage` says where and why. Members written
    one after another read as one stream, and zero bytes after a member are padding, as
    ``gzip.GzipFile`` reads them; anything else after a member is damage."""

    def __init__(self, raw: BinaryIO) -> None:
        super().__init__()
        self._raw = raw
        self._member = zlib.decompressobj(GZIP_WBITS)
        self._pending = b""
        self._offset = 0  # compressed bytes read so far
        self._ended = False
        self.damage: str | None = None

    def readable(self) -> bool:
        return True

    def readinto(self, buffer: bytearray | memoryview) -> int:  # type: ignore[override]
        while not self._pending and not self._ended:
            self._pending = self._inflate_more()
        n = min(len(buffer), len(self._pending))
        buffer[:n] = self._pending[:n]
        self._pending = self._pending[n:]
        return n

    def _inflate_more(self) -> bytes:
        """The next decompressed bytes (maybe none yet); at the end, or at damage, none and
        ``_ended`` set."""
        member = self._member
        if member.eof:  # a member ended: zero padding, then maybe a next member
            data = member.unused_data.lstrip(b"\0")
            while not data and (piece := self._read()):
                data = piece.lstrip(b"\0")
            if not data:
                self._ended = True
                return b""
            member = self._member = zlib.decompressobj(GZIP_WBITS)
        else:
            data = member.unconsumed_tail or self._read()
            if not data:
                self._ended = True
                self.damage = (f"compressed data ends at byte {self._offset} before its "
                               "end-of-stream marker (cut off while written?): read up to there")
                return b""
        try:
            return member.decompress(data, GZIP_PIECE * 4)
        except zlib.error as e:
            self._ended = True  # (data is a tail of what was read: it starts here)
            self.damage = (f"compressed data damaged between bytes {self._offset - len(data)} "
                           f"and {self._offset} ({e}): read up to there")
            return b""

    def _read(self) -> bytes:
        piece = self._raw.read(GZIP_PIECE)
        self._offset += len(piece)
        return piece


class Source:
    """An input: a path (gzip, bzip2 or xz by magic bytes or suffix: :data:`COMPRESSIONS`)
    or ``-`` for standard input.

    ``head`` holds the first (decompressed) bytes for format sniffing; :meth:`open` returns a
    binary stream positioned at the start. :meth:`progress` reports compressed bytes consumed.
    """

    def __init__(self, path: str) -> None:
        self.path = path
        self.name = "<stdin>" if path == "-" else path
        self._opened: BinaryIO | None = None  # the decompressed stream, once opened
        if path == "-":
            stdin = sys.stdin.buffer
            self._raw: BinaryIO = io.BufferedReader(getattr(stdin, "raw", stdin), 1 << 20)
            self.size = 0
        else:
            p = Path(path)
            try:  # stat first: a folder is a bag; a missing or unreadable path says why
                if stat.S_ISDIR(p.stat().st_mode):
                    self._raw = None  # type: ignore[assignment]
                    self.size = 0
                    self.compression: Compression | None = None
                    self.head = b""
                    return
                self._raw = open(p, "rb")  # noqa: SIM115 - closed by close()
                self.size = os.fstat(self._raw.fileno()).st_size
            except OSError as e:
                raise InputError(self.name, f"cannot open: {e.strerror}") from None
        self.compression = compression_of(self._raw.peek(SNIFF_BYTES), path)
        self.head = self._peek_head()

    @property
    def is_dir(self) -> bool:
        return self._raw is None

    @property
    def plain_path(self) -> str:
        """The path without its compression's suffix (``run.log.bz2``: ``run.log``)."""
        c = self.compression
        return self.path.removesuffix(c.suffix) if c is not None else self.path

    def _peek_head(self) -> bytes:
        data = self._raw.peek(SNIFF_BYTES)
        c = self.compression
        if c is None:
            return data[:SNIFF_BYTES]
        decompressor = c.decompressor()
        try:
            head = decompressor.decompress(data, SNIFF_BYTES)
        except c.damaged:
            raise InputError(self.name, f"not a valid {c.name} file") from None
        if not head and data and len(data) == self.size and not decompressor.eof:
            raise InputError(self.name, f"{c.name} data damaged or cut short before its "
                             "first readable bytes")
        return head

    def open(self) -> BinaryIO:
        """The (decompressed) byte stream. A gzip stream ends where its compressed data
        stops being readable; :attr:`damage` then says where and why."""
        c = self.compression
        if c is None:
            return self._raw
        self._opened = c.opener(self._raw)
        return self._opened

    @property
    def damage(self) -> str | None:
        """Where and why a gzip source's compressed data stopped being readable (None: it
        did not, or the source is not gzip)."""
        return getattr(getattr(self._opened, "raw", None), "damage", None)

    def progress(self) -> tuple[int, int]:
        """(bytes consumed, total bytes) of the file on disk; total 0 when unknown."""
        if self.size == 0 or self._raw is None:
            return 0, 0
        try:
            return self._raw.tell(), self.size
        except (OSError, ValueError):
            return 0, self.size

    def close(self) -> None:
        if self._raw is not None and self.path != "-":
            self._raw.close()


def read_text_lines(path: Path | str) -> list[str]:
    """All lines of a small text file (TUM, relations); unreadable or binary is an error."""
    try:
        return Path(path).read_text(encoding="utf-8").splitlines()
    except OSError as e:
        raise InputError(str(path), f"cannot read: {e.strerror}") from None
    except UnicodeDecodeError:
        raise InputError(str(path), "not a text file") from None


def text_lines(source: Source, stats: ReadStats | None = None
               ) -> Iterator[tuple[int, str, bool]]:
    """(line number, line without its end, whether the line was terminated) for a text log.

    Decoding errors are replaced, never fatal. A compressed stream cut short or damaged ends
    the lines where it stops being readable (gzip's: the line it stops in comes
    unterminated; bzip2's and xz's: the lines their decoder had given): a counted warning in
    ``stats`` saying where, or an :class:`InputError` without ``stats``. Binary data (a NUL
    byte in the first ``BINARY_SNIFF_BYTES``: an image, a program, a bag read with
    ``--format carmen``) and a line longer than ``MAX_LINE_CHARS`` (``/dev/zero``) are an
    :class:`InputError`.
    """
    if b"\0" in source.head[:BINARY_SNIFF_BYTES]:
        raise InputError(source.name, "not a text log: binary data (NUL bytes) near the start")
    damaged = source.compression.damaged if source.compression is not None else ()
    stream = io.TextIOWrapper(source.open(), encoding="utf-8", errors="replace", newline=None)
    lineno, terminated = 0, True
    try:
        while line := stream.readline(MAX_LINE_CHARS + 1):
            lineno += 1
            terminated = line.endswith("\n")
            if terminated:
                yield lineno, line[:-1], True
            elif len(line) > MAX_LINE_CHARS:
                raise InputError(source.name, f"a line longer than {MAX_LINE_CHARS} characters: "
                                 "not a text log?", lineno)
            else:
                yield lineno, line, False
        if source.damage is not None:
            where = lineno + terminated  # the line the damage cuts short, or the next
            if stats is None:
                raise InputError(source.name, source.damage, where)
            stats.warn(source.damage, where)
    except damaged as e:  # bzip2, xz: the lines before it were read
        message = f"compressed data is damaged or truncated ({e}): read up to there"
        if stats is None:
            raise InputError(source.name, message, lineno + 1) from None
        stats.warn(message, lineno + 1)
    finally:  # the source owns the file (and closes it): let go of it, leave it open
        with suppress(ValueError):  # (already closed by the source)
            stream.detach()


_OURS = (str(Path(__file__).resolve().parent), str(Path(__file__).resolve().parent.parent /
                                                  "dynslam_cli"))


def _raised_by_library(e: BaseException) -> bool:
    """Whether the innermost frame of ``e``'s traceback is outside dynslam (a container
    library's own error on damaged data, not a bug of ours)."""
    tb = e.__traceback__
    if tb is None:
        return False
    while tb.tb_next is not None:
        tb = tb.tb_next
    return not tb.tb_frame.f_code.co_filename.startswith(_OURS)


@contextmanager
def container_errors(name: str, what: str) -> Iterator[None]:
    """The one place a container library's exceptions (rosbags, mcap, zstd, sqlite, struct,
    ...) on damaged data become a one-line :class:`InputError` naming the file; its message
    is cut to its first line (some quote a whole message definition)."""
    try:
        yield
    except InputError:
        raise
    except Exception as e:
        if not (isinstance(e, UnicodeDecodeError | struct.error | EOFError)
                or _raised_by_library(e)):
            raise
        raise InputError(name, f"cannot read this {what}: {first_line(e)}") from None


def first_line(e: BaseException) -> str:
    """An exception's message cut to its first line (some quote a whole message definition),
    or its type's name when it has none (an ``AssertionError``)."""
    lines = str(e).strip().splitlines()
    return lines[0] if lines else type(e).__name__


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


MAX_LINE_CHARS = 4_000_000  # a text log's line: 20000 beams with remissions fit 10 times
MAX_BEAMS = 20_000  # per scan; the finest 2D lidars give a few thousand
MAX_COORDINATE_M = 1e7  # an odometry or mounting pose farther out than this is garbage
MAX_RANGE_M = 1000.0  # a max range above this is capped: readings beyond are no-returns
FULL_TURN = 2 * math.pi * 1.01  # a sweep spans at most one turn (plus rounding)


def _finite_pose(pose: Pose2D) -> bool:
    return (math.isfinite(pose.theta) and abs(pose.x) <= MAX_COORDINATE_M
            and abs(pose.y) <= MAX_COORDINATE_M)  # (NaN fails the comparisons)


def scan_problem(scan: Scan) -> str | None:
    """Why a scan cannot be used (None: it can). Cheap: a few vector checks per scan."""
    n = len(scan.ranges)
    if not math.isfinite(scan.stamp):
        return "time stamp is not a finite number"
    if not (_finite_pose(scan.odom) and _finite_pose(scan.laser)):
        return f"pose is not finite or beyond ±{MAX_COORDINATE_M:g} m"
    if n == 0 or n != len(scan.angles):
        return "no beams, or beam angles and ranges differ in count"
    if n > MAX_BEAMS:
        return f"more than {MAX_BEAMS} beams in one scan"
    if not (scan.max_range > 0 and math.isfinite(scan.max_range)):
        return "max range is not a positive number"
    if not np.isfinite(scan.angles).all():
        return "beam angles are not finite (angle_min / increment)"
    span = float(scan.angles.max() - scan.angles.min())
    if (n > 1 and span <= 0) or span > FULL_TURN:
        return "beam angles do not make a sweep (increment zero, or more than one turn)"
    return None


def beam_geometry(angles: np.ndarray) -> tuple[float, float]:
    """(start, step) of evenly spaced beam angles, each at float32 precision: the
    ``angle_min`` and ``angle_increment`` of a ``sensor_msgs/LaserScan``."""
    n = len(angles)
    step = (float(angles[-1]) - float(angles[0])) / (n - 1) if n > 1 else 0.0
    return float(np.float32(angles[0])), float(np.float32(step))


def _single_heading(pose: Pose2D) -> Pose2D:
    theta = pose.theta if -math.pi <= pose.theta <= math.pi else wrap_angle(pose.theta)
    heading = float(np.float32(theta))  # (of an unwrapped heading, float32 would be coarse)
    return pose if heading == pose.theta else Pose2D(pose.x, pose.y, heading)


class SinglePrecision:
    """Scans as a ``sensor_msgs/LaserScan`` holds them: float32 ranges and max range, beam
    angles ``start + i·step`` with float32 start and step (:func:`beam_geometry`); and the
    headings of the odometry and the mount at float32 (2.4e-7 rad at most), as a heading
    read back from a quaternion differs from the one written in float64's last bits, and a
    run follows such bits. Text logs (ranges in mm or cm, headings in 1e-6 rad) and bags
    (float32 ranges) lose nothing real by it, and a scan written to a recording
    (``--record``) reads back bit for bit: a run on the recording is the same run. Equal
    geometries share one read-only angle array."""

    def __init__(self) -> None:
        self._key: tuple[int, float, float] | None = None
        self._angles = np.zeros(0)

    def __call__(self, scan: Scan) -> Scan:
        n = len(scan.angles)
        key = (n, *beam_geometry(scan.angles))
        if key != self._key:
            self._key = key
            self._angles = key[1] + key[2] * np.arange(n, dtype=np.float64)
            self._angles.flags.writeable = False
        with np.errstate(over="ignore"):  # beyond float32: +inf, no return (as it was)
            ranges = scan.ranges.astype(np.float32).astype(np.float64)
        return dataclasses.replace(
            scan, ranges=ranges,
            angles=self._angles, max_range=float(np.float32(scan.max_range)),
            odom=_single_heading(scan.odom), laser=_single_heading(scan.laser))


# A mount that moves less than this (metres, radians) from the one held has not moved: a
# Carmen log's mount is the difference of two poses printed to six decimals (fr079: 1.2e-6 m
# apart from scan to scan; MIT CSAIL 5e-13 m), far below a laser's millimetres.
MOUNT_TOLERANCE_M, MOUNT_TOLERANCE_RAD = 1e-5, 1e-5


def same_mount(a: Pose2D, b: Pose2D) -> bool:
    """Whether two laser mounts are one within ``MOUNT_TOLERANCE_M`` / ``_RAD``."""
    return (abs(a.x - b.x) <= MOUNT_TOLERANCE_M and abs(a.y - b.y) <= MOUNT_TOLERANCE_M
            and abs(math.remainder(a.theta - b.theta, math.tau)) <= MOUNT_TOLERANCE_RAD)


class SteadyMount:
    """Scans with the laser mount held: a mount that is the held one within the tolerance
    (:func:`same_mount`) becomes it exactly, any other is held from then on. The run then
    sees one mount where the log has one, and a recording sends it once, on ``/tf_static``
    (only a mount that really moves goes on ``/tf``), and still plays back into the same
    run."""

    def __init__(self) -> None:
        self._mount: Pose2D | None = None

    def __call__(self, scan: Scan) -> Scan:
        held = self._mount
        if held is not None and scan.laser != held and same_mount(held, scan.laser):
            return dataclasses.replace(scan, laser=held)
        self._mount = scan.laser
        return scan


class ReaderFilter:
    """A reader seen through a filter of its scans: same format name, stats and extras."""

    def __init__(self, reader: LogReader) -> None:
        self.reader = reader
        self.format_name = reader.format_name
        self.stats = reader.stats

    def __getattr__(self, name: str) -> object:  # a reader's own extras (ROS: topics)
        return getattr(self.reader, name)


NO_VALID_READING = ("no valid reading (every range NaN, negative, or outside the laser's "
                    "range_min..range_max)")


class ScanGuard(ReaderFilter):
    """A reader's scans as the core may use them, whatever the input: finite time stamp,
    finite and bounded poses, finite beam angles making at most one turn, at most
    ``MAX_BEAMS`` beams, a positive finite max range (capped at ``MAX_RANGE_M``), negative
    readings marked invalid, at LaserScan precision (:class:`SinglePrecision`), the laser
    mount held steady (:class:`SteadyMount`). Any other scan, and one without a single valid
    reading, is a counted, reported skip.
    A time stamp that does not increase is a counted warning and the scan is kept in file
    order: real logs have a few (Radish intel and infinite-corridor), and the corrected
    Radish logs stamp every scan alike."""

    def __init__(self, reader: LogReader, name: str) -> None:
        super().__init__(reader)
        self.name = name

    def scans(self) -> Iterator[Scan]:
        passed = skipped = 0
        last = -math.inf
        single, steady = SinglePrecision(), SteadyMount()
        for scan in self.reader.scans():
            problem = scan_problem(scan)
            if problem is None:
                negative = scan.ranges < 0  # invalid, as NaN is (-inf, the -1 of some drivers)
                if negative.any():
                    scan = dataclasses.replace(scan,
                                               ranges=np.where(negative, np.nan, scan.ranges))
                if np.isnan(scan.ranges).all():
                    problem = NO_VALID_READING
            if problem is not None:
                self.stats.skip(problem, scan.source_line)
                skipped += 1
                continue
            passed += 1
            if scan.stamp <= last:
                self.stats.warn("time stamp does not increase (scan kept in file order)",
                                scan.source_line)
            last = max(last, scan.stamp)
            if scan.max_range > MAX_RANGE_M:
                self.stats.warn(f"max range above {MAX_RANGE_M:g} m capped", scan.source_line)
                scan = dataclasses.replace(scan, max_range=MAX_RANGE_M)
            yield steady(single(scan))
        if skipped and not passed:
            raise InputError(self.name, f"no usable scans: all {skipped} were skipped ("
                             + "; ".join(sorted(self.stats.skipped)) + ")")


class LogWindow(ReaderFilter):
    """A reader's scans from ``start_s`` to ``end_s`` seconds after its first scan, at most
    ``max_scans`` of them; reading stops at the end of the window."""

    def __init__(self, reader: LogReader, options: ReaderOptions, name: str) -> None:
        super().__init__(reader)
        self.name = name
        self.start = options.start_s if options.start_s is not None else -math.inf
        self.end = options.end_s if options.end_s is not None else math.inf
        self.max_scans = options.max_scans

    def scans(self) -> Iterator[Scan]:
        """The window's scans; none (the window starts after the log ends, or falls between
        two scans) is an error that says the log's span."""
        first, n, t = None, 0, 0.0
        for scan in self.reader.scans():
            first = scan.stamp if first is None else first
            t = scan.stamp - first
            if t > self.end or (self.max_scans is not None and n >= self.max_scans):
                break
            if t >= self.start:
                n += 1
                yield scan
        if n == 0 and first is not None:
            window = (f"from {self.start:g} s" if self.end == math.inf
                      else f"from {max(self.start, 0.0):g} to {self.end:g} s")
            raise InputError(self.name, f"no scans {window} into the log (its scans span "
                             f"{'at least ' if t > self.end else ''}{t:.1f} s)")


def guarded(reader: LogReader, options: ReaderOptions, name: str) -> LogReader:
    """``reader`` behind the :class:`ScanGuard`, and in a :class:`LogWindow` when the options
    ask for part of the log: what every reader's scans go through (plugins' too)."""
    reader = ScanGuard(reader, name)
    if options.start_s is None and options.end_s is None and options.max_scans is None:
        return reader
    return LogWindow(reader, options, name)


class OdometryBuffer:
    """Pairs scans with odometry interpolated at their time stamps, for formats where the
    two come on separate records (Carmen RAWLASER/LASERn + ODOM, Player, ROS bags).

    A scan waits until an odometry record at or after its time arrives, then gets the pose
    interpolated between the two records around it; scans after the last record get the last
    pose (a counted warning). Memory holds only the scans between two odometry records.
    Odometry going backwards in time is dropped and counted (``backwards``)."""

    def __init__(self, stats: ReadStats) -> None:
        self.stats = stats
        self._odom: deque[tuple[float, Pose2D]] = deque(maxlen=2)
        self._waiting: deque[tuple[float, int, object]] = deque()
        self.backwards = 0
        self.first_backwards_line = 0
        self.records = 0

    def add_odometry(self, stamp: float, pose: Pose2D, line: int = 0
                     ) -> Iterator[tuple[object, Pose2D | None, int]]:
        if self._odom and stamp < self._odom[-1][0]:
            self.backwards += 1
            self.first_backwards_line = self.first_backwards_line or line
            return
        self.records += 1
        self._odom.append((stamp, pose))
        yield from self._flush(final=False)

    def add_scan(self, stamp: float, payload: object, line: int = 0
                 ) -> Iterator[tuple[object, Pose2D | None, int]]:
        self._waiting.append((stamp, line, payload))
        yield from self._flush(final=False)

    def finish(self) -> Iterator[tuple[object, Pose2D | None, int]]:
        """The scans still waiting; their pose is None if there was no odometry at all."""
        yield from self._flush(final=True)

    def _flush(self, final: bool) -> Iterator[tuple[object, Pose2D | None, int]]:
        while self._waiting:
            stamp, line, payload = self._waiting[0]
            if not self._odom:
                if not final:
                    return
                pose = None
            elif stamp > self._odom[-1][0] and not final:
                return
            else:
                pose = self._at(stamp, line)
            self._waiting.popleft()
            yield payload, pose, line

    def _at(self, stamp: float, line: int) -> Pose2D:
        (t0, p0), (t1, p1) = self._odom[0], self._odom[-1]
        if stamp >= t1:
            if stamp > t1:
                self.stats.warn("scan after the last odometry record: odometry held", line)
            return p1
        if stamp <= t0 or t1 == t0:
            if stamp < t0:
                self.stats.warn("scan older than the odometry before it: odometry held", line)
            return p0
        return interpolate(p0, p1, (stamp - t0) / (t1 - t0))
