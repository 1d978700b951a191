"""What every reader's scans go through (plugins' too): the guard (a scan is finite and
bounded, or a counted skip; float32 precision and a steady mount held) and the window of
the log asked for (``--start``, ``--end``, ``--max-scans``)."""

from __future__ import annotations

import dataclasses
import itertools
import math
from collections.abc import Callable, Iterator

import numpy as np

from dynslam_cli.errors import InputError
from dynslam_cli.geometry import interpolate, wrap_angle
from dynslam_cli.types import Pose2D, Scan
from dynslam_formats.base import LogReader, ReaderOptions, ReadStats
from dynslam_formats.tum import clock_stopped

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


class BeamStep(ReaderFilter):
    """A reader's scans with their beams ``step_deg`` apart from the first, for a log whose
    records state the laser's angular step wrong (``--beam-step``)."""

    def __init__(self, reader: LogReader, step_deg: float) -> None:
        super().__init__(reader)
        self.step = math.radians(step_deg)

    def scans(self) -> Iterator[Scan]:
        for scan in self.reader.scans():
            yield scan.respaced(self.step)


class LaserMount(ReaderFilter):
    """A reader's scans with the laser's mount the options give (``mount_x_m``, ``mount_y_m``,
    ``mount_deg``: each set one replaces that coordinate of the log's), for a log that
    states its mount wrong or not at all."""

    def __init__(self, reader: LogReader, options: ReaderOptions) -> None:
        super().__init__(reader)
        self.x, self.y = options.mount_x_m, options.mount_y_m
        self.theta = None if options.mount_deg is None else math.radians(options.mount_deg)
        self._stated: Pose2D | None = None  # the log's last mount ...
        self._mount = Pose2D()  # ... and what it becomes

    def scans(self) -> Iterator[Scan]:
        for scan in self.reader.scans():
            if scan.laser != self._stated:
                stated = self._stated = scan.laser
                self._mount = Pose2D(stated.x if self.x is None else self.x,
                                     stated.y if self.y is None else self.y,
                                     stated.theta if self.theta is None else self.theta)
            yield dataclasses.replace(scan, laser=self._mount)


class RangeLimit(ReaderFilter):
    """A reader's scans with ``max_range_m`` as their max range, so every consumer (scan
    matching, corners, loop closure, the maps, a prior's placement) sees the same
    no-return rule."""

    def __init__(self, reader: LogReader, max_range_m: float) -> None:
        super().__init__(reader)
        self.max_range_m = max_range_m

    def scans(self) -> Iterator[Scan]:
        for scan in self.reader.scans():
            yield (scan if scan.max_range == self.max_range_m
                   else dataclasses.replace(scan, max_range=self.max_range_m))


class ScanLatency(ReaderFilter):
    """A reader's scans with their odometry taken ``latency_s`` before their stamps, for a
    laser whose scans reach the log that much after they were seen (a SICK at 38.4 kbaud
    sends its 361 bytes in 94 ms): each scan's odometry pose interpolated between the
    scan before's and its own (the first scan's, and one stamped no later than the one
    before, as they are)."""

    def __init__(self, reader: LogReader, latency_s: float) -> None:
        super().__init__(reader)
        self.latency_s = latency_s

    def scans(self) -> Iterator[Scan]:
        before: Scan | None = None
        for scan in self.reader.scans():
            if (before is not None and scan.stamp > before.stamp and scan.has_odometry
                    and before.has_odometry):
                f = max(1.0 - self.latency_s / (scan.stamp - before.stamp), 0.0)
                yield dataclasses.replace(scan, odom=interpolate(before.odom, scan.odom, f))
            else:
                yield scan
            before = scan


def read_ahead(scans: Iterator[Scan], enough: Callable[[list[Scan]], bool]
               ) -> tuple[list[Scan], Exception | None]:
    """A log's first scans, read until ``enough`` says so of those read (or the log ends),
    and the error that ended the reading before, if one did (:func:`replayed` raises it
    after the scans before it, as reading without looking ahead would)."""
    probe: list[Scan] = []
    try:
        for scan in scans:
            probe.append(scan)
            if enough(probe):
                break
    except Exception as e:
        return probe, e
    return probe, None


def replayed(probe: list[Scan], error: Exception | None, scans: Iterator[Scan]
             ) -> Iterator[Scan]:
    """The scans read ahead (:func:`read_ahead`), then the error that ended them or the
    rest of the log."""
    yield from probe
    if error is not None:
        raise error
    yield from scans


MAX_TURN_RATE = 4.0  # rad/s: an odometry turning faster between two scans glitched
MIN_TURN_RATE = 0.1  # rad/s: the turns that tell the passes apart
RATE_GAP_S = 0.5  # scans farther apart tell too little of the turn during one sweep
INTERLACE_PROBE_TURNS = 200  # the delay is estimated from this many turning scans ...
INTERLACE_PROBE_SCANS = 5000  # ... among a log's first this many at most
INTERLACED_S = 0.003  # and taken where it is at least this long ...
INTERLACE_MIN_TURNS = 50  # ... from at least this many turning scans
INTERLACED = ("the laser sweeps its beams in two interlaced passes, {:.1f} ms apart: its odd "
              "beams are turned by the robot's turn in that time ([laser] interlace_s)")


def turn_rate(scan: Scan, before: Scan | None) -> float:
    """The odometry's turn rate (rad/s) from the scan before to ``scan``; 0 where either has
    no odometry, the clock does not run forward or leaps more than RATE_GAP_S (a log that
    keeps a scan every second or so: the mean turn between them is not the turn during
    the sweep), or the turn is faster than MAX_TURN_RATE (a glitch)."""
    if (before is None or not (scan.has_odometry and before.has_odometry)
            or not 0 < scan.stamp - before.stamp <= RATE_GAP_S):
        return 0.0
    rate = math.remainder(scan.odom.theta - before.odom.theta, math.tau) / (
        scan.stamp - before.stamp)
    return rate if abs(rate) <= MAX_TURN_RATE else 0.0


def evenly_spaced(angles: np.ndarray) -> bool:
    """Whether a scan's beams are all there, evenly spaced (a reader that dropped a beam
    leaves a gap, after which its odd beams are not the odd pass's)."""
    if len(angles) < 3:
        return False
    steps = np.diff(angles)
    return bool(steps.max() - steps.min() <= 0.25 * abs(float(np.median(steps))))


def odd_beam_delay(scans: list[Scan]) -> tuple[float, int]:
    """How much later than the even beams a laser's odd beams were seen (seconds), and from
    how many turning scans: each odd beam's range, less the mean of its two even
    neighbours', is its wall's slope times the angle the robot turned in that time (least
    squares over smooth stretches of wall; 0 for a laser that sweeps once)."""
    num = den = 0.0
    turning = 0
    for before, scan in itertools.pairwise(scans):
        rate = turn_rate(scan, before)
        n = len(scan.ranges) - 1 + len(scan.ranges) % 2  # (the last beam even)
        if abs(rate) < MIN_TURN_RATE or n < 5 or not evenly_spaced(scan.angles):
            continue
        turning += 1
        r, a = scan.ranges, scan.angles
        left, odd, right = r[0:n - 2:2], r[1:n - 1:2], r[2:n:2]
        with np.errstate(invalid="ignore"):  # (no returns: inf − inf, never ``ok``)
            slope = (right - left) / (a[2:n:2] - a[0:n - 2:2])
            off = odd - (left + right) / 2
            ok = ((np.maximum(np.maximum(left, right), odd) < scan.max_range)
                  & (np.abs(right - left) < 0.3) & (np.abs(off) < 0.1))
        x = slope[ok] * rate
        num += float(x @ off[ok])
        den += float(x @ x)
    return (num / den if den > 0 else 0.0), turning


class Interlaced(ReaderFilter):
    """A reader's scans with the beams of a laser that sweeps them in two interlaced passes
    (a SICK LMS at half a degree: the even beams in one turn of its mirror, the odd ones in
    the next) each turned by the robot's turn between the passes, ``delay_s`` at the
    odometry's turn rate from the scan before (:func:`turn_rate`): a turning robot
    otherwise sees every wall twice, the odd beams' copy turned by that much. ``delay_s``
    None: estimated from the log's first turning scans (:func:`odd_beam_delay`; said once
    where it is INTERLACED_S or more from INTERLACE_MIN_TURNS turning scans or more, else
    the scans pass as they are)."""

    def __init__(self, reader: LogReader, delay_s: float | None) -> None:
        super().__init__(reader)
        self.delay_s = delay_s

    def scans(self) -> Iterator[Scan]:
        scans = iter(self.reader.scans())
        probe: list[Scan] = []
        error: Exception | None = None
        delay = self.delay_s
        if delay is None:
            turning = 0

            def enough(probe: list[Scan]) -> bool:
                nonlocal turning
                turning += abs(turn_rate(probe[-1], probe[-2] if len(probe) > 1 else None)
                               ) >= MIN_TURN_RATE
                return turning == INTERLACE_PROBE_TURNS or len(probe) == INTERLACE_PROBE_SCANS

            probe, error = read_ahead(scans, enough)
            delay, turns = odd_beam_delay(probe)
            if abs(delay) < INTERLACED_S or turns < INTERLACE_MIN_TURNS:
                delay = 0.0
            else:
                self.stats.warn(INTERLACED.format(1000 * delay))
        if delay == 0.0:
            yield from replayed(probe, error, scans)
            return
        before: Scan | None = None
        for scan in replayed(probe, error, scans):
            yield self._deskewed(scan, turn_rate(scan, before) * delay)
            before = scan

    @staticmethod
    def _deskewed(scan: Scan, turn: float) -> Scan:
        """``scan`` with its odd beams turned by ``turn`` (radians; the beams keep their
        order, so a turn of more than a beam's spacing puts an odd beam past its even
        neighbour: each end point is where it was seen all the same). A scan a beam is
        missing from (:func:`evenly_spaced`) stays as it is."""
        if turn == 0.0 or not evenly_spaced(scan.angles):
            return scan
        angles = scan.angles.copy()
        angles[1::2] += turn
        return dataclasses.replace(scan, angles=angles)


CLOCK_PROBE_SCANS = 50  # a log's clock is judged on its first this many scans
STOPPED_CLOCK = ("time stamps carry no time (most scans repeat one): the scans are timed by "
                 "their order, {:g} s apart ([laser] stopped_clock_period_s)")


class ScanOrderClock(ReaderFilter):
    """A reader's scans timed by their order, ``period_s`` apart from 0, where the log's
    stamps carry no time (:func:`clock_stopped` over its first CLOCK_PROBE_SCANS scans:
    the corrected Radish freiburg-campus stamps every scan 0, infinite-corridor's clock
    sticks at 2³² after four scans), so what is ruled in seconds (change events,
    snapshots, a window of the log) has a time to go by; said once (STOPPED_CLOCK). A log
    whose clock runs passes as it is."""

    def __init__(self, reader: LogReader, period_s: float) -> None:
        super().__init__(reader)
        self.period_s = period_s

    def scans(self) -> Iterator[Scan]:
        scans = iter(self.reader.scans())
        probe, error = read_ahead(scans, lambda probe: len(probe) == CLOCK_PROBE_SCANS)
        stopped = clock_stopped(np.array([scan.stamp for scan in probe]))
        if stopped:
            self.stats.warn(STOPPED_CLOCK.format(self.period_s))
        for i, scan in enumerate(replayed(probe, error, scans)):
            yield dataclasses.replace(scan, stamp=i * self.period_s) if stopped else scan


def timed_by_order(stats: ReadStats) -> bool:
    """Whether a reader's scans were timed by their order (:class:`ScanOrderClock`)."""
    head = STOPPED_CLOCK.split("{")[0]
    return any(w.startswith(head) for w in stats.warnings)


def guarded(reader: LogReader, options: ReaderOptions, name: str) -> LogReader:
    """``reader`` behind the :class:`ScanGuard` (its beams first spread as ``beam_step_deg``
    says and its laser mounted as ``mount_*`` say, where set; then held to ``max_range_m``,
    its odometry made older by ``scan_latency_s`` and its odd beams turned by
    ``interlace_s``, where set), and in a :class:`LogWindow` when the options ask for part
    of the log: what every reader's scans go through (plugins' too)."""
    if options.beam_step_deg is not None:
        reader = BeamStep(reader, options.beam_step_deg)
    if any(v is not None for v in (options.mount_x_m, options.mount_y_m, options.mount_deg)):
        reader = LaserMount(reader, options)
    reader = ScanOrderClock(ScanGuard(reader, name), options.stopped_clock_period_s)
    if options.max_range_m is not None:
        reader = RangeLimit(reader, options.max_range_m)
    if options.scan_latency_s > 0:
        reader = ScanLatency(reader, options.scan_latency_s)
    if options.interlace_s is None or options.interlace_s > 0:
        reader = Interlaced(reader, options.interlace_s)
    if options.start_s is None and options.end_s is None and options.max_scans is None:
        return reader
    return LogWindow(reader, options, name)
