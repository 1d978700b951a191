"""Scans paired with odometry that comes on records of its own (Carmen RAWLASER/LASERn +
ODOM, Player, ROS bags): interpolated at each scan's stamp."""

from __future__ import annotations

from collections import deque
from collections.abc import Iterator
from dataclasses import dataclass

from dynslam_cli.geometry import interpolate
from dynslam_cli.types import Pose2D
from dynslam_formats.base import ReadStats


class OdometryBuffer:
    """Pairs scans with odometry interpolated at their time stamps, for formats where the
    two come on separate records (Carmen RAWLASER/LASERn + ODOM, Player, ROS bags).

    A scan waits until an odometry record at or after its time arrives, then gets the pose
    interpolated between the two records around it; scans after the last record get the last
    pose (a counted warning). Memory holds only the scans between two odometry records.

    Odometry whose stamp goes backwards is the log's clock stepping back (records kept in
    the order they were made, stamped by a clock that jumped): the scans waiting for later
    odometry get the last pose, and interpolation starts again from that record (counted:
    ``backwards``). So a scan older than the odometry before it waits for the next record:
    if the clock stepped back, it is paired on the new clock; if not, it gets the pose
    before it (a counted warning). Scans come out in the order they went in."""

    def __init__(self, stats: ReadStats) -> None:
        self.stats = stats
        self._odom: deque[tuple[float, Pose2D]] = deque(maxlen=2)
        self._waiting: deque[_Waiting] = deque()
        self.backwards = 0
        self.first_backwards_line = 0
        self.records = 0

    def add_odometry(self, stamp: float, pose: Pose2D, line: int = 0
                     ) -> Iterator[tuple[object, Pose2D | None, int]]:
        if self._odom and stamp < self._odom[-1][0]:
            self.backwards += 1
            self.first_backwards_line = self.first_backwards_line or line
            last, last_pose = self._odom[-1]
            for w in self._waiting:
                if not w.paired and w.stamp >= last:
                    w.pose, w.paired = last_pose, True
            self._odom.clear()
        else:
            for w in self._waiting:
                if not w.paired and self._odom and w.stamp < self._odom[0][0]:
                    w.pose, w.paired = self._at(w.stamp, w.line), True
        self.records += 1
        self._odom.append((stamp, pose))
        yield from self._flush(final=False)

    def add_scan(self, stamp: float, payload: object, line: int = 0
                 ) -> Iterator[tuple[object, Pose2D | None, int]]:
        self._waiting.append(_Waiting(stamp, line, payload))
        yield from self._flush(final=False)

    def finish(self, report: bool = True) -> Iterator[tuple[object, Pose2D | None, int]]:
        """The scans still waiting; their pose is None if there was no odometry at all.
        Odometry stamps that went backwards are a counted warning if ``report``."""
        yield from self._flush(final=True)
        if self.backwards and report:
            self.stats.warn("odometry time stamp goes backwards (interpolation starts again "
                            "from that record)", self.first_backwards_line, self.backwards)

    def _flush(self, final: bool) -> Iterator[tuple[object, Pose2D | None, int]]:
        """The scans, from the first, that have their pose (all of them if ``final``)."""
        while self._waiting:
            w = self._waiting[0]
            if not w.paired and self._odom:
                t0, t1 = self._odom[0][0], self._odom[-1][0]
                if not final and not t0 <= w.stamp <= t1:
                    return
                w.pose = self._at(w.stamp, w.line)
            elif not w.paired and not final:
                return
            self._waiting.popleft()
            yield w.payload, w.pose, w.line

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


@dataclass
class _Waiting:
    """A scan waiting for its odometry; ``paired`` once its pose is decided."""

    stamp: float
    line: int
    payload: object
    pose: Pose2D | None = None
    paired: bool = False
