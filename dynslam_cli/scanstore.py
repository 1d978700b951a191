"""The scans of a run, kept compactly so that the maps can be rebuilt from the optimized
trajectory at the end (see dynslam_cli.pipeline)."""

from __future__ import annotations

from array import array
from collections.abc import Callable, Iterable
from typing import TYPE_CHECKING

import numpy as np

from dynslam_cli.types import Pose2D, Scan

if TYPE_CHECKING:
    from dynslam_cli.mapping.dynamic import DynamicMapper


class ScanStore:
    """The scans of the run, kept compactly so the maps can be rebuilt from the optimized
    trajectory at the end: the ranges as float32 (what the rebuild reads), and as 16-bit
    whole millimetres or centimetres where that gives back exactly those float32 values
    (text logs are written to the mm or cm: 2 bytes a reading); the beam angles and mounting
    poses shared; no Python object per scan (a 4 h log has 144 000 scans). Scans are coded
    ``BATCH`` at a time, so the coding costs next to nothing a scan."""

    UNITS_M = (0.001, 0.01)  # the 16-bit codes count these
    NO_RETURN, INVALID = 65534, 65535  # codes of +inf and NaN
    BATCH = 256

    def __init__(self) -> None:
        self._codes = array("H")  # the 16-bit scans' readings, one after another ...
        self._floats = array("f")  # ... and the others'
        self._where = array("q")  # per scan: its first reading (negative: -1 - index in _floats)
        self._kind = array("b")  # per scan: index in UNITS_M, or -1 for float32
        self._stamps = array("d")
        self._max_range = array("d")
        self._geometry = array("i")  # per scan: index into _shapes
        self._shapes: list[tuple[np.ndarray, Pose2D]] = []  # (angles, laser) met so far
        self._shape_ids: dict[tuple, int] = {}
        self._odd_turn = array("d")  # per scan: its odd beams' angles less its shape's
        # (an interlaced laser's, turned by the robot's turn between its passes)
        self._batch: list[np.ndarray] = []  # float32 ranges of scans not coded yet

    def add(self, scan: Scan) -> None:
        a, laser = scan.angles, scan.laser
        even = (len(a) - 1) // 2 * 2  # (the last even beam: the shape is the even beams')
        key = ((len(a), float(a[0]), float(a[even])) if len(a) else (0, 0.0, 0.0),
               (laser.x, laser.y, laser.theta))
        shape = self._shape_ids.setdefault(key, len(self._shapes))
        if shape == len(self._shapes):
            self._shapes.append((a, laser))
        self._odd_turn.append(float(a[1] - self._shapes[shape][0][1]) if len(a) > 1 else 0.0)
        if self._batch and len(self._batch[0]) != len(a):
            self._code_batch()  # (a batch is one beam count)
        self._batch.append(scan.ranges.astype(np.float32))
        self._stamps.append(scan.stamp)
        self._max_range.append(scan.max_range)
        self._geometry.append(shape)
        if len(self._batch) == self.BATCH:
            self._code_batch()

    def _code_batch(self) -> None:
        """Code the waiting scans: each in the first unit of ``UNITS_M`` that gives back
        exactly its float32 readings, or kept as float32."""
        ranges = np.stack(self._batch)
        self._batch = []
        finite = np.isfinite(ranges)
        special_ok = ~finite & ~np.isneginf(ranges)  # +inf and NaN have codes
        kind = np.full(len(ranges), -1, np.int8)
        codes = np.full(ranges.shape, self.INVALID, np.uint16)
        codes[np.isposinf(ranges)] = self.NO_RETURN
        wide = np.where(finite, ranges, 0.0).astype(np.float64)
        for u in range(len(self.UNITS_M)):
            k = np.rint(wide / self.UNITS_M[u])
            exact = (self._decode_finite(k, u) == ranges) & (k >= 0) & (k < self.NO_RETURN)
            fits = (exact | special_ok).all(axis=1) & (kind < 0)
            kind[fits] = u
            codes[fits] = np.where(finite[fits], k[fits], codes[fits])
        for row, u in enumerate(kind.tolist()):
            if u < 0:
                self._where.append(-1 - len(self._floats))
                self._floats.frombytes(ranges[row].tobytes())
            else:
                self._where.append(len(self._codes))
                self._codes.frombytes(codes[row].tobytes())
        self._kind.frombytes(kind.tobytes())

    def _decode_finite(self, k: np.ndarray, unit: int) -> np.ndarray:
        return (k * self.UNITS_M[unit]).astype(np.float32)

    def _ranges(self, i: int, n: int) -> np.ndarray:
        """Scan i's n readings, as float32."""
        at = self._where[i]
        if at < 0:
            return np.frombuffer(self._floats, np.float32, n, (-1 - at) * 4)
        codes = np.frombuffer(self._codes, np.uint16, n, at * 2)
        out = self._decode_finite(codes.astype(np.float64), self._kind[i])
        out[codes == self.NO_RETURN] = np.inf
        out[codes == self.INVALID] = np.nan
        return out

    def __len__(self) -> int:
        return len(self._stamps)

    def scans(self) -> Iterable[Scan]:
        if self._batch:
            self._code_batch()
        for i, (stamp, max_range, shape, turn) in enumerate(zip(
                self._stamps, self._max_range, self._geometry, self._odd_turn, strict=True)):
            angles, laser = self._shapes[shape]
            if turn:
                angles = angles.copy()
                angles[1::2] += turn
            yield Scan(stamp, self._ranges(i, len(angles)).astype(np.float64), angles,
                       max_range, Pose2D(), laser)


def remap(mapper: DynamicMapper, poses: np.ndarray, store: ScanStore,
          say: Callable[[str, int, int], None]) -> None:
    """The stored scans integrated into ``mapper`` in order, each at its row of ``poses``
    (N×3: x, y, θ in the map frame); ``say("rebuilding the maps", done, total)`` every 256
    scans."""
    n = len(poses)
    for i, ((x, y, th), scan) in enumerate(zip(poses, store.scans(), strict=True)):
        if i % 256 == 0:
            say("rebuilding the maps", i, n)
        mapper.integrate(Pose2D(float(x), float(y), float(th)), scan)
