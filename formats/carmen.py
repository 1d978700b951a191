"""Carmen / Radish / Freiburg logs (CARMEN 0.7 writelog/readlog; GMapping's .gfs.log).

One record a line, fields separated by white space, ending with
``ipc_timestamp ipc_hostname logger_timestamp``; ``#`` starts a comment. The scan time is the
ipc_timestamp (third field from the end).

Which records make scans (``--laser``):

=========  ==========================================================
front      ``FLASER``, ``RAWLASER1``, ``ROBOTLASER1`` (the default)
rear       ``RLASER``, ``RAWLASER2``, ``ROBOTLASER2``
3, 4       ``LASER3``/``RAWLASER3``, ``LASER4``/``RAWLASER4``
=========  ==========================================================

If a log carries the same laser in two record kinds, the first kind seen is used and the
other counted as skipped ("duplicate laser record kind").

Odometry: ``FLASER``/``RLASER`` carry it (the *second* pose triple, the robot's pose, as
GMapping and the Freiburg metricEvaluator use; the first triple minus the second gives the
laser's mounting pose). ``ROBOTLASER`` likewise (robot pose; laser pose − robot pose).
``RAWLASER`` and ``LASER3/4`` carry none: the robot pose is interpolated from the ``ODOM``
records around the scan's time stamp (held after the last one).

Beam angles: ``RAWLASER``/``ROBOTLASER`` give start angle and resolution. Old ``FLASER``
lines carry none: CARMEN's readlog rule (start −90°; 180/181 beams → 1° steps, 360/361 →
0.5°, other n → 180°/(n−1)), unless ``PARAM laser_front_laser_fov`` / ``..._resolution``
(degrees; a fov of at most 2π that the beams span as radians is radians, said once) or the
``--flaser-fov`` option says otherwise. Max range for FLASER: 80 m (CARMEN) unless a
``PARAM ..._max_range`` gives one; readings beyond that PARAM contradict it, and then the
largest reading seen marks "no return" instead (said once).

Bad input, decided per case:

* **error** (exit 1, ``file:line: what``): a laser/odometry record with too few or too many
  fields for its beam count (e.g. a line that ends after its pose), a non-numeric field, a
  negative beam count; an empty log; a log with no records of the chosen laser.
* **counted skip** (warning, counted in summary.json): a damaged *last* line with no line end
  (a log cut off while being written); a scan whose pose is NaN/inf; a repeated laser kind.
* **counted warning, record kept**: NaN, negative or −inf ranges (the beam is dropped:
  invalid); +inf ranges (no return, REP 117); time stamps that do not increase (Radish logs
  have all-zero, negative and 6-digit stamps: scans stay in file order with the stamps as
  written); unknown record types and known ones dynslam does not use (counted by type);
  ``--topic`` / ``--odom-topic``, which apply to ROS logs only (ignored).
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from typing import ClassVar

import numpy as np

from dynslam_cli.errors import InputError
from dynslam_cli.geometry import compose, relative
from dynslam_cli.types import Pose2D, Scan
from dynslam_formats.base import ReaderOptions, ReadStats, warn_ros_only_options
from dynslam_formats.odometry import OdometryBuffer
from dynslam_formats.source import Source, text_lines

RECORD_NAMES = ("PARAM", "SYNC", "ODOM", "TRUEPOS", "FLASER", "RLASER", "LASER3", "LASER4",
                "RAWLASER1", "RAWLASER2", "RAWLASER3", "RAWLASER4", "ROBOTLASER1",
                "ROBOTLASER2", "NEFF", "WEIGHT")

LASERS = {
    "front": ("FLASER", "RAWLASER1", "ROBOTLASER1"),
    "rear": ("RLASER", "RAWLASER2", "ROBOTLASER2"),
    "3": ("LASER3", "RAWLASER3"),
    "4": ("LASER4", "RAWLASER4"),
}
PARAM_PREFIX = {"front": "front", "rear": "rear", "3": "laser3", "4": "laser4"}
POSED_KINDS = ("FLASER", "RLASER", "ROBOTLASER1", "ROBOTLASER2")
CARMEN_DEFAULT_MAX_RANGE = 80.0
NO_OFFSET = Pose2D()
TRAILER = 3  # ipc_timestamp ipc_hostname logger_timestamp


def sniff(head: bytes) -> bool:
    """True if the first record line starts with a Carmen record name."""
    for raw in head.splitlines()[:200]:
        tokens = raw.split()
        if not tokens or tokens[0].startswith(b"#"):
            continue
        return tokens[0].decode("ascii", "replace") in RECORD_NAMES
    return False


CONTRADICTED_MAX_RANGE = 1.05  # a reading this far beyond the PARAM max range contradicts it
NO_RETURN_SHARE = 0.99  # readings within 1% of the largest one are "no return"


def fov_radians(value: float, beams: int, resolution_deg: float | None) -> float:
    """A ``PARAM ..._fov`` in radians. CARMEN writes degrees, but some logs write radians
    (csail: ``laser_front_laser_fov 3.14159`` with 361 beams at 0.5°). A value of at most 2π
    is radians when the beams at the given resolution span it as radians (within one beam),
    or, with no resolution given, always: a laser scan spanning under 6.3° does not exist."""
    if value <= 2 * math.pi + 1e-6:
        if resolution_deg is None or resolution_deg <= 0:
            return value
        span = math.radians(resolution_deg) * max(beams - 1, 1)
        if abs(span - value) <= math.radians(resolution_deg):
            return value
    return math.radians(value)


def carmen_beam_angles(n: int) -> tuple[float, float]:
    """(start, step) in radians for an old FLASER line of n beams, by CARMEN's readlog rule."""
    if n in (180, 181):
        step = math.radians(1.0)
    elif n in (360, 361):
        step = math.radians(0.5)
    else:
        step = math.pi / max(n - 1, 1)
    return -math.pi / 2, step


class CarmenReader:
    """Streams :class:`Scan` records from a Carmen log (see the module docstring)."""

    format_name: ClassVar[str] = "carmen"

    def __init__(self, source: Source, options: ReaderOptions) -> None:
        if options.laser not in LASERS:
            raise InputError(source.name, f"unknown laser {options.laser!r} for a Carmen log; "
                             f"choose one of {', '.join(LASERS)}")
        self.source = source
        self.options = options
        self.stats = ReadStats()
        warn_ros_only_options(options, self.stats, "Carmen log")
        self._kinds = LASERS[options.laser]
        self._kind: str | None = None
        self._params: dict[str, str] = {}
        self._angles: dict[tuple[int, float, float], np.ndarray] = {}
        self._odometry_buffer = OdometryBuffer(self.stats)
        self._line = 0
        self._ceiling = 0.0  # largest reading where readings contradict the PARAM max range

    # -- the stream -----------------------------------------------------------------------
    def scans(self) -> Iterator[Scan]:
        name = self.source.name
        any_line = False
        for lineno, line, terminated in text_lines(self.source, self.stats):
            self._line = lineno
            tokens = line.split()
            if not tokens:
                continue
            any_line = True
            if tokens[0].startswith("#"):
                self.stats.records["#comment"] += 1
                continue
            kind = tokens[0]
            self.stats.records[kind] += 1
            try:
                yield from self._record(kind, tokens)
            except InputError:
                if terminated:
                    raise
                self.stats.skip("damaged last line (log cut off while written)", lineno)
        if not any_line:
            raise InputError(name, "empty log: no records at all")
        buffer = self._odometry_buffer
        yield from self._emit_ready(buffer.finish(report=self._kind not in POSED_KINDS))
        if self.stats.scans == 0:
            seen = ", ".join(f"{k}×{v}" for k, v in sorted(self.stats.records.items()))
            raise InputError(name, f"no {'/'.join(self._kinds)} records for laser "
                             f"'{self.options.laser}' (records found: {seen or 'none'})")

    def _record(self, kind: str, tokens: list[str]) -> Iterator[Scan]:
        if kind == "PARAM":
            if len(tokens) >= 3:
                self._params[tokens[1].replace("_", "").lower()] = tokens[2]
            return
        if kind == "ODOM":
            yield from self._odometry(tokens)
            return
        if kind not in self._kinds:
            if kind not in RECORD_NAMES:
                self.stats.warn(f"unknown record type {kind} (ignored)", self._line)
            return
        if self._kind is None:
            self._kind = kind
        elif kind != self._kind:
            self.stats.skip(f"duplicate laser record kind {kind} (using {self._kind})",
                            self._line)
            return
        if kind in ("FLASER", "RLASER"):
            yield from self._old_laser(tokens)
        elif kind.startswith("ROBOTLASER"):
            yield from self._robot_laser(tokens)
        elif kind.startswith("RAWLASER"):
            yield from self._raw_laser(tokens)
        else:
            yield from self._bare_laser(tokens)

    # -- field helpers --------------------------------------------------------------------
    def _fail(self, message: str) -> InputError:
        return InputError(self.source.name, message, self._line)

    def _numbers(self, tokens: list[str], start: int, stop: int) -> np.ndarray:
        try:
            return np.array(tokens[start:stop], dtype=np.float64)
        except ValueError:
            for i in range(start, stop):
                try:
                    float(tokens[i])
                except ValueError:
                    raise self._fail(f"{tokens[0]} field {i} ({tokens[i]!r}) is not a "
                                     "number") from None
            raise

    def _count(self, tokens: list[str], i: int) -> int:
        try:
            n = int(tokens[i])
        except (ValueError, IndexError):
            got = tokens[i] if i < len(tokens) else "nothing"
            raise self._fail(f"{tokens[0]} field {i} should be a beam count, got {got!r}"
                             ) from None
        if n < 0:
            raise self._fail(f"{tokens[0]} beam count {n} is negative")
        return n

    def _expect(self, tokens: list[str], expected: int, what: str) -> None:
        got = len(tokens)
        if got == expected:
            return
        hint = ""
        if got == expected - TRAILER:
            hint = " (the line ends after the pose: timestamp and host fields are missing)"
        raise self._fail(f"{tokens[0]} has {got - 1} fields, expected {expected - 1} "
                         f"for {what}{hint}")

    def _stamp(self, tokens: list[str]) -> float:
        return float(self._numbers(tokens, len(tokens) - TRAILER, len(tokens) - TRAILER + 1)[0])

    def _param_float(self, *names: str) -> float | None:
        laser = PARAM_PREFIX[self.options.laser]
        for pattern in names:
            value = self._params.get(pattern.format(laser=laser))
            if value is not None:
                try:
                    return float(value)
                except ValueError:
                    self.stats.warn(f"PARAM {pattern.format(laser=laser)} is not a number")
        return None

    def _beam_angles(self, n: int, start: float, step: float) -> np.ndarray:
        key = (n, start, step)
        angles = self._angles.get(key)
        if angles is None:
            angles = start + step * np.arange(n, dtype=np.float64)
            angles.flags.writeable = False
            self._angles[key] = angles
        return angles

    def _ranges(self, values: np.ndarray) -> np.ndarray:
        with np.errstate(invalid="ignore"):
            bad = np.isnan(values) | (values < 0)
        if bad.any():
            self.stats.warn("invalid ranges (NaN or negative): beam dropped", self._line,
                            int(bad.sum()))
            values = np.where(bad, np.nan, values)
        if np.isposinf(values).any():
            self.stats.warn("+inf ranges: no return", self._line, int(np.isposinf(values).sum()))
        return values

    def _poses(self, values: np.ndarray) -> tuple[Pose2D, Pose2D] | None:
        """(laser pose, robot pose) from six numbers; None (counted skip) if not finite."""
        if not np.isfinite(values).all():
            self.stats.skip("pose is NaN or infinite", self._line)
            return None
        v = [float(x) for x in values]
        return Pose2D(*v[:3]), Pose2D(*v[3:6])

    # -- records --------------------------------------------------------------------------
    def _old_laser(self, tokens: list[str]) -> Iterator[Scan]:
        n = self._count(tokens, 1)
        self._expect(tokens, n + 8 + TRAILER, f"{n} beams + laser pose + robot pose")
        values = self._numbers(tokens, 2, n + 8)
        poses = self._poses(values[n:n + 6])
        if poses is None:
            return
        laser_pose, robot = poses
        fov = self.options.fov_deg
        if fov is not None:
            start, step = -math.radians(fov) / 2, math.radians(fov) / max(n - 1, 1)
        else:
            start, step = carmen_beam_angles(n)
            p_fov = self._param_float("laser{laser}laserfov", "laser{laser}fov")
            p_res = self._param_float("laser{laser}laserresolution", "laser{laser}resolution")
            if p_res is not None and p_res > 0:
                step = math.radians(p_res)
            if p_fov is not None and p_fov > 0:
                fov = fov_radians(p_fov, n, p_res)
                if fov != math.radians(p_fov):
                    self.stats.warn(f"PARAM laser fov {p_fov:g} read as radians (the beams "
                                    "span it so)")
                start = -fov / 2
                step = math.radians(p_res) if p_res else fov / max(n - 1, 1)
        ranges = self._ranges(values[:n])
        yield from self._emit(self._stamp(tokens), ranges, self._beam_angles(n, start, step),
                              self._old_laser_max_range(ranges), robot,
                              relative(robot, laser_pose))

    def _old_laser_max_range(self, ranges: np.ndarray) -> float:
        """The PARAM max range, or CARMEN's 80 m; where readings contradict the PARAM
        (edmonton: ``robot_front_laser_max 10`` with real readings to 51 m) the largest
        reading seen so far marks "no return" instead (within 1%), and that is said once."""
        param = self._param_float("laser{laser}lasermaxrange", "robot{laser}lasermax",
                                  "laser{laser}maxrange")
        if param is None or param <= 0:
            return CARMEN_DEFAULT_MAX_RANGE
        top = float(np.max(ranges, initial=0.0, where=np.isfinite(ranges)))
        if top > param * CONTRADICTED_MAX_RANGE and top <= CARMEN_DEFAULT_MAX_RANGE * 1.05:
            if self._ceiling == 0.0:
                self.stats.warn(f"readings beyond the PARAM max range {param:g} m: the "
                                "largest reading marks no return instead", self._line)
            self._ceiling = max(self._ceiling, top)
        return NO_RETURN_SHARE * self._ceiling if self._ceiling else param

    def _raw_header(self, tokens: list[str], tail: int) -> tuple[int, int, np.ndarray]:
        """Check RAWLASER/ROBOTLASER counts: returns (n, m, header numbers)."""
        n = self._count(tokens, 8)
        m = self._count(tokens, 9 + n) if len(tokens) > 9 + n else -1
        if m < 0:
            raise self._fail(f"{tokens[0]} has {len(tokens) - 1} fields, too few for {n} beams")
        self._expect(tokens, 10 + n + m + tail + TRAILER,
                     f"{n} beams + {m} remissions" + (" + poses" if tail else ""))
        return n, m, self._numbers(tokens, 1, 8)

    def _raw_scan(self, tokens: list[str], n: int, header: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray, float]:
        start, _fov, step, max_range = header[1], header[2], header[3], header[4]
        ranges = self._ranges(self._numbers(tokens, 9, 9 + n))
        return ranges, self._beam_angles(n, float(start), float(step)), float(max_range)

    def _robot_laser(self, tokens: list[str]) -> Iterator[Scan]:
        n, m, header = self._raw_header(tokens, 11)
        ranges, angles, max_range = self._raw_scan(tokens, n, header)
        poses = self._poses(self._numbers(tokens, 10 + n + m, 16 + n + m))
        if poses is None:
            return
        laser_pose, robot = poses
        yield from self._emit(self._stamp(tokens), ranges, angles, max_range, robot,
                              relative(robot, laser_pose))

    def _raw_laser(self, tokens: list[str]) -> Iterator[Scan]:
        n, _m, header = self._raw_header(tokens, 0)
        ranges, angles, max_range = self._raw_scan(tokens, n, header)
        yield from self._wait_for_odometry(self._stamp(tokens), ranges, angles, max_range)

    def _bare_laser(self, tokens: list[str]) -> Iterator[Scan]:
        n = self._count(tokens, 1)
        self._expect(tokens, n + 2 + TRAILER, f"{n} beams")
        start, step = carmen_beam_angles(n)
        yield from self._wait_for_odometry(self._stamp(tokens),
                                           self._ranges(self._numbers(tokens, 2, 2 + n)),
                                           self._beam_angles(n, start, step),
                                           CARMEN_DEFAULT_MAX_RANGE)

    def _odometry(self, tokens: list[str]) -> Iterator[Scan]:
        self._expect(tokens, 7 + TRAILER, "x y theta tv rv accel")
        pose = self._numbers(tokens, 1, 4)
        stamp = self._stamp(tokens)
        if not np.isfinite(pose).all() or not math.isfinite(stamp):
            self.stats.skip("ODOM pose is NaN or infinite", self._line)
            return
        if self._kind in POSED_KINDS:
            return  # the scans carry their own odometry
        # Stamps going backwards are reported at the end, if the chosen laser needs ODOM.
        yield from self._emit_ready(self._odometry_buffer.add_odometry(
            stamp, Pose2D(*map(float, pose)), self._line))

    # -- odometry for scans without a pose ------------------------------------------------
    def _wait_for_odometry(self, stamp: float, ranges: np.ndarray, angles: np.ndarray,
                           max_range: float) -> Iterator[Scan]:
        ready = self._odometry_buffer.add_scan(stamp, (stamp, ranges, angles, max_range),
                                               self._line)
        yield from self._emit_ready(ready)

    def _emit_ready(self, ready: Iterator[tuple[object, Pose2D | None, int]]
                    ) -> Iterator[Scan]:
        offset = self._mount_offset()
        for payload, pose, line in ready:
            stamp, ranges, angles, max_range = payload  # type: ignore[misc]
            if pose is None:
                self.stats.warn("no ODOM records: scans placed at the origin", line)
                pose = Pose2D()
            yield from self._emit(stamp, ranges, angles, max_range, pose, offset, line)

    def _mount_offset(self) -> Pose2D:
        x = self._param_float("robot{laser}laseroffset") or 0.0
        return Pose2D(x, 0.0, math.pi if self.options.laser == "rear" else 0.0)

    def _emit(self, stamp: float, ranges: np.ndarray, angles: np.ndarray, max_range: float,
              odom: Pose2D, laser: Pose2D, line: int | None = None) -> Iterator[Scan]:
        line = self._line if line is None else line
        if not math.isfinite(stamp):
            self.stats.skip("time stamp is NaN or infinite", line)
            return
        self.stats.scans += 1
        yield Scan(stamp=stamp, ranges=ranges, angles=angles, max_range=max_range, odom=odom,
                   laser=laser, source_line=line)


# -- writing ------------------------------------------------------------------------------
def _line(*fields: object) -> str:
    return " ".join(str(f) for f in fields) + "\n"


def format_param(name: str, value: object, host: str = "dynslam") -> str:
    return _line("PARAM", name, value, "0.000000", host, "0.000000")


def format_odom(stamp: float, odom: Pose2D, host: str = "dynslam") -> str:
    ts = f"{stamp:.6f}"
    return _line("ODOM", f"{odom.x:.6f}", f"{odom.y:.6f}", f"{odom.theta:.6f}", 0, 0, 0, ts,
                 host, ts)


def format_flaser(stamp: float, ranges: np.ndarray, odom: Pose2D, laser: Pose2D = NO_OFFSET,
                  host: str = "dynslam") -> str:
    """An old-style FLASER line (laser pose = odom ⊕ laser mounting, then the robot pose)."""
    lp = compose(odom, laser)
    ts = f"{stamp:.6f}"
    return _line("FLASER", len(ranges), " ".join(f"{r:.3f}" for r in ranges),
                 f"{lp.x:.6f}", f"{lp.y:.6f}", f"{lp.theta:.6f}",
                 f"{odom.x:.6f}", f"{odom.y:.6f}", f"{odom.theta:.6f}", ts, host, ts)


def format_robotlaser1(stamp: float, ranges: np.ndarray, start: float, step: float,
                       max_range: float, odom: Pose2D, laser: Pose2D = NO_OFFSET,
                       host: str = "dynslam") -> str:
    lp = compose(odom, laser)
    ts = f"{stamp:.6f}"
    return _line("ROBOTLASER1", 3, f"{start:.6f}", f"{step * (len(ranges) - 1):.6f}",
                 f"{step:.6f}", f"{max_range:.3f}", "0.010000", 0, len(ranges),
                 " ".join(f"{r:.3f}" for r in ranges), 0,
                 f"{lp.x:.6f}", f"{lp.y:.6f}", f"{lp.theta:.6f}",
                 f"{odom.x:.6f}", f"{odom.y:.6f}", f"{odom.theta:.6f}",
                 "0.000000 0.000000 0.000000 0.000000 0.000000", ts, host, ts)
