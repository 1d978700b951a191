"""Scans paired with odometry that comes on records of its own (Carmen RAWLASER/LASERn +
ODOM, Player, ROS bags): interpolated at each scan's stamp."""

from __future__ import annotations

from collections import deque
from collections.abc import Iterator

from dynslam_cli.geometry import interpolate
from dynslam_cli.types import Pose2D
from dynslam_formats.base import ReadStats


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
