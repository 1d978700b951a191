"""Player writelog text logs (playerproject/player readlog/writelog).

``#`` lines are comments (``## File version V`` is read). Laser and odometry come on separate
lines; each scan gets the odometry interpolated at its time (:class:`OdometryBuffer`).

* File 0.3.0 (Player 2.x/3.x): ``time host robot interface index type subtype payload``.
  ``laser .. 1 1`` scan: id min max res max_range count (range intensity)×count;
  ``laser .. 1 2`` scanpose: id px py pa min max res max_range count pairs;
  ``laser .. 1 3`` scanangle: id max_range count (range angle intensity)×count;
  ``position2d .. 1 1`` state: px py pa vx vy va stall;
  ``laser .. 4 1`` geometry: px py pyaw sl sw (the laser's mounting pose).
* File 0.0.0/0.2.0 (Player 1.x): ``time host port interface index data_time payload``;
  ``laser``: min max res count (range intensity)×count; ``position``: px py pa vx vy va stall.

``--laser N`` picks the laser device index (default: the first one seen). Bad input follows
the Carmen reader's rules: a malformed or non-numeric record is an error naming file and
line (a damaged last line is a counted skip); other interfaces are counted and ignored.
Per case: a file version other than 0.0, 0.2 or 0.3 is an error (the layouts differ); a
device index, type, subtype or beam count that is not a whole number (or a count beyond
``MAX_BEAMS``) is an error; a record with fewer values than its layout needs is an error; a
time stamp that is not finite is a counted skip; laser records of other types or subtypes
are counted and ignored, as are ``--topic`` and ``--odom-topic`` (ROS only). Scans with a
non-finite resolution, minimum angle or max range, or a zero resolution, are counted skips
(the common guard, ``dynslam_formats.guard``); a negative resolution or min > max is a sweep
in the other direction and is kept.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from typing import ClassVar

import numpy as np

from dynslam_cli.errors import InputError
from dynslam_cli.types import Pose2D, Scan
from dynslam_formats.base import ReaderOptions, ReadStats, warn_ros_only_options
from dynslam_formats.guard import MAX_BEAMS
from dynslam_formats.odometry import OdometryBuffer
from dynslam_formats.source import Source, text_lines

VERSIONS = ("0.0", "0.2", "0.3")


def sniff(head: bytes) -> bool:
    text = head.decode("ascii", "replace")
    if "## Player version" in text or "## File version" in text:
        return True
    for line in text.splitlines()[:50]:
        tokens = line.split()
        if len(tokens) > 4 and not tokens[0].startswith("#"):
            return tokens[3] in ("laser", "position2d", "position", "sync")
    return False


class PlayerReader:
    format_name: ClassVar[str] = "player"

    def __init__(self, source: Source, options: ReaderOptions) -> None:
        self.source = source
        self.stats = ReadStats()
        warn_ros_only_options(options, self.stats, "Player log")
        self.version = "0.3.0"
        self._device: str | None = None if options.laser in ("front", "") else options.laser
        self._mount = Pose2D()
        self._buffer = OdometryBuffer(self.stats)
        self._line = 0

    def _fail(self, message: str) -> InputError:
        return InputError(self.source.name, message, self._line)

    def _numbers(self, tokens: list[str]) -> np.ndarray:
        try:
            return np.array(tokens, dtype=np.float64)
        except ValueError:
            bad = next(t for t in tokens if not _is_number(t))
            raise self._fail(f"field {bad!r} is not a number") from None

    def _integer(self, token: str, what: str) -> int:
        try:
            return int(token)
        except ValueError:
            raise self._fail(f"{what} {token!r} is not a whole number") from None

    def _count(self, value: float) -> int:
        """A beam count read as a number: whole, 0 to ``MAX_BEAMS``."""
        if not (math.isfinite(value) and value == int(value) and 0 <= value <= MAX_BEAMS):
            raise self._fail(f"beam count {value:g} is not a whole number from 0 to {MAX_BEAMS}")
        return int(value)

    def scans(self) -> Iterator[Scan]:
        any_record = False
        for lineno, line, terminated in text_lines(self.source, self.stats):
            self._line = lineno
            if line.startswith("#"):
                if "File version" in line:
                    self.version = line.split()[-1]
                    if not self.version.startswith(VERSIONS):
                        raise self._fail(f"unknown Player file version {self.version!r} "
                                         f"(known: {', '.join(VERSIONS)})")
                continue
            tokens = line.split()
            if not tokens:
                continue
            any_record = True
            try:
                yield from self._record(tokens)
            except InputError:
                if terminated:
                    raise
                self.stats.skip("damaged last line (log cut off while written)", lineno)
        if not any_record:
            raise InputError(self.source.name, "empty log: no records at all")
        yield from self._emit(self._buffer.finish())
        if self.stats.scans == 0:
            raise InputError(self.source.name, "no laser scans for device "
                             f"{self._device or 'any'} (records: {dict(self.stats.records)})")

    def _record(self, tokens: list[str]) -> Iterator[Scan]:
        old = not self.version.startswith("0.3")
        if len(tokens) < 6:
            raise self._fail(f"a record has at least 6 header fields, found {len(tokens)}")
        iface, index = tokens[3], tokens[4]
        self.stats.records[iface] += 1
        stamp = float(self._numbers(tokens[:1])[0])
        if not math.isfinite(stamp):
            self.stats.skip("time stamp is not a finite number", self._line)
            return
        if old:
            payload, kind = tokens[6:], ("1", "1")
        else:
            if len(tokens) < 7:
                raise self._fail("a 0.3 record has 7 header fields")
            kind = (str(self._integer(tokens[5], "type")),
                    str(self._integer(tokens[6], "subtype")))
            payload = tokens[7:]
        if iface in ("position2d", "position") and kind == ("1", "1"):
            v = self._numbers(payload[:3])
            if len(v) < 3:
                raise self._fail(f"{iface} state needs px py pa")
            yield from self._emit(self._buffer.add_odometry(
                stamp, Pose2D(float(v[0]), float(v[1]), float(v[2])), self._line))
        elif iface == "laser":
            device = str(self._integer(index, "laser index"))
            if self._device is None:
                self._device = device
            if device != self._device:
                self.stats.skip(f"laser {device} (using {self._device})", self._line)
                return
            if kind == ("4", "1"):
                v = self._numbers(payload[:3])
                if len(v) < 3:
                    raise self._fail("laser geometry needs px py pyaw")
                self._mount = Pose2D(float(v[0]), float(v[1]), float(v[2]))
            elif kind[0] == "1":
                scan = self._laser(payload, kind[1], old)
                if scan is not None:
                    yield from self._emit(self._buffer.add_scan(stamp, (stamp, *scan),
                                                                self._line))
            else:
                self.stats.warn(f"laser type {kind[0]} subtype {kind[1]} ignored", self._line)
        else:
            self.stats.warn(f"interface {iface} ignored", self._line)

    def _laser(self, p: list[str], subtype: str, old: bool
               ) -> tuple[np.ndarray, np.ndarray, float] | None:
        if old:  # min max res count pairs
            head, n_at, max_range = 0, 3, 8.0
        elif subtype == "1":  # id min max res max_range count pairs
            head, n_at, max_range = 1, 5, None
        elif subtype == "2":  # id px py pa min max res max_range count pairs
            head, n_at, max_range = 4, 8, None
        elif subtype == "3":  # id max_range count (range angle intensity)×
            v = self._numbers(p[1:3])
            if len(v) < 2:
                raise self._fail("scanangle needs id, max range and count")
            n = self._count(float(v[1]))
            body = self._numbers(p[3:3 + 3 * n])
            if len(body) != 3 * n or len(p) != 3 + 3 * n:
                raise self._fail(f"scanangle expects {n} triples")
            return body[0::3].copy(), body[1::3].copy(), float(v[0])
        else:
            self.stats.warn(f"laser subtype {subtype} ignored", self._line)
            return None
        if len(p) <= n_at:
            raise self._fail("laser record too short")
        v = self._numbers(p[head:n_at + 1])
        lo, hi, res = v[0], v[1], v[2]
        max_range = float(v[3]) if max_range is None else max_range
        n = self._count(float(v[-1]))
        if len(p) != n_at + 1 + 2 * n:
            raise self._fail(f"laser record has {len(p) - n_at - 1} values after the count, "
                             f"expected {2 * n} (range, intensity) for {n} beams")
        ranges = self._numbers(p[n_at + 1::2])
        angles = lo + res * np.arange(n) if n > 1 else np.array([lo])
        if n > 1 and abs(angles[-1] - hi) > abs(res):
            angles = np.linspace(lo, hi, n)
        return ranges, angles, max_range

    def _emit(self, ready: Iterator[tuple[object, Pose2D | None, int]]) -> Iterator[Scan]:
        for payload, pose, line in ready:
            stamp, ranges, angles, max_range = payload  # type: ignore[misc]
            has_odometry = pose is not None
            if pose is None:
                self.stats.warn("no odometry in the log: stationary motion prior", line)
            with np.errstate(invalid="ignore"):
                bad = np.isnan(ranges) | (ranges < 0)
            if bad.any():
                self.stats.warn("invalid ranges (NaN or negative): beam dropped", line,
                                int(bad.sum()))
                ranges = np.where(bad, np.nan, ranges)
            self.stats.scans += 1
            yield Scan(stamp, ranges, angles, max_range, pose or Pose2D(), self._mount, line,
                       has_odometry)


def _is_number(token: str) -> bool:
    try:
        float(token)
    except ValueError:
        return False
    return True
