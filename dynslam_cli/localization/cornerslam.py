"""Localization (paper Sec. 4): EKF-SLAM over corner landmarks, nearest-neighbour data
association, and Table 3 — a landmark corrects the pose only if its place in S is Occupied.

Landmarks pass a tentative stage first (seen ``confirm_observations`` times close together)
so that clutter does not fill the state. Per-scan cost is bounded by the size of the state:
a landmark not seen for ``active_window_scans`` leaves the filter (the pose graph, not the
EKF, closes long loops: see dynslam_cli.localization.backend) and the state never holds more than
``max_landmarks``. Landmarks that leave are kept for the landmark map if they were seen
``keep_observations`` times; rarer ones were clutter and are forgotten.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

import numpy as np

from dynslam_cli.geometry import compose
from dynslam_cli.localization.corners import Corner, detect_corners
from dynslam_cli.localization.ekf import Ekf, inverse_observe, motion_noise
from dynslam_cli.sections import CornerConfig, EkfConfig
from dynslam_cli.types import Pose2D, Scan

NO_ODOMETRY_NOISE_SCALE = 50.0  # × the motion-noise floor: ~0.1 m and 5° per scan


@dataclass
class LandmarkTrack:
    """Bookkeeping beside the filter state for one landmark."""

    id: int
    convex: bool
    cls: str = "dynamic"
    observations: int = 1
    last_seen: int = 0


@dataclass(frozen=True)
class LandmarkRecord:
    """A landmark for the map: EKF-frame position and covariance, and its bookkeeping."""

    id: int
    x: float
    y: float
    convex: bool
    observations: int
    last_seen: int
    cov: np.ndarray


@dataclass
class Candidate:
    x: float
    y: float
    convex: bool
    count: int
    last_seen: int


def to_range_bearing(corner: Corner, laser: Pose2D) -> np.ndarray:
    """A corner from the laser frame to (range, bearing) from the robot."""
    p = compose(laser, Pose2D(corner.x, corner.y, 0.0))
    return np.array([math.hypot(p.x, p.y), math.atan2(p.y, p.x)])


def observe_corners(scan: Scan, config: CornerConfig) -> list[tuple[np.ndarray, bool]]:
    """Corners of the scan as ((range, bearing) from the robot, convex): the landmark
    observations."""
    corners = detect_corners(scan.ranges, scan.angles, scan.max_range, config)
    return [(to_range_bearing(c, scan.laser), c.convex) for c in corners]


class CornerSlam:
    """The EKF, its landmark bookkeeping and the tentative landmarks."""

    def __init__(self, start: Pose2D, config: EkfConfig) -> None:
        self.config = config
        self.ekf = Ekf(np.array([start.x, start.y, start.theta]), config.noise)
        self.tracks: list[LandmarkTrack] = []
        self.candidates: list[Candidate] = []
        self.retired: list[LandmarkRecord] = []
        self.scan_index = 0
        self._next_id = 0

    @property
    def pose(self) -> Pose2D:
        x = self.ekf.x
        return Pose2D(float(x[0]), float(x[1]), float(x[2]))

    def step(self, scan_index: int, increment: Pose2D, cov: np.ndarray | None,
             has_odometry: bool, observations: list[tuple[np.ndarray, bool]],
             classify: Callable[[np.ndarray], list[str]]) -> Pose2D:
        """Sec. 4 for scan number ``scan_index``: predict from the motion ``increment``
        (covariance ``cov``, None: the noise model's), associate the corners seen,
        classify the landmarks seen by Table 3 (``classify``: their positions, N×2 in this
        filter's frame, to "static" or "dynamic"), correct with the static ones, start
        landmarks from the corners left, let go of those not seen for long; returns the
        corrected pose."""
        self.scan_index = scan_index
        self.predict(increment, cov, has_odometry)
        pairs, not_new = self.associate(observations)
        seen = [i for i, _ in pairs]  # only these can correct the pose: classify them
        if seen:
            self.classify(seen, classify(self.landmark_positions()[seen]))
        self.correct(pairs)
        self.add_new(observations, not_new)
        self.prune()
        if self.config.robocentric:
            self.ekf.condition_on_robot()
        return self.pose

    def predict(self, increment: Pose2D, cov: np.ndarray | None, has_odometry: bool = True
                ) -> None:
        """EKF prediction from the motion increment (robot frame) with its covariance: a
        scan-matched increment's own (tight where the scan sees, the odometry's where it
        does not), else the odometry's noise model (without odometry: the wide stationary
        prior)."""
        u = np.array([increment.x, increment.y, increment.theta])
        self.ekf.predict(u, self.motion_covariance(increment, cov, has_odometry))

    def motion_covariance(self, increment: Pose2D, cov: np.ndarray | None,
                          has_odometry: bool = True) -> np.ndarray:
        """The covariance the prediction takes for a motion increment: its own (a scan
        match's), else the odometry's noise model (without odometry: the wide stationary
        prior)."""
        if cov is not None:
            return cov
        scale = 1.0 if has_odometry else NO_ODOMETRY_NOISE_SCALE
        u = np.array([increment.x, increment.y, increment.theta])
        return motion_noise(u, self.config.noise) * scale ** 2

    def associate(self, observations: list[tuple[np.ndarray, bool]]
                  ) -> tuple[list[tuple[int, np.ndarray]], set[int]]:
        """Nearest neighbour by Mahalanobis distance within the gate, same convex/concave
        flag, each landmark used once. Returns (landmark index, z) pairs and the indices of
        observations that are not new landmarks: matched ones, and unmatched ones lying near
        a landmark (ambiguous)."""
        ekf, cfg = self.ekf, self.config
        pose = ekf.x[:3]
        lms = ekf.x[3:].reshape(-1, 2)
        scored = []
        near_something = []
        for k, (z, convex) in enumerate(observations):
            p = inverse_observe(pose, z)
            if len(lms):
                close = np.flatnonzero(np.hypot(lms[:, 0] - p[0], lms[:, 1] - p[1])
                                       < cfg.search_radius_m)
            else:
                close = np.zeros(0, dtype=np.int64)
            if len(close):
                near_something.append(k)
            for i in close:
                if self.tracks[i].convex != convex:
                    continue
                d2, _, _ = ekf.mahalanobis(int(i), z)
                if d2 < cfg.gate_chi2:
                    scored.append((d2, k, int(i)))
        scored.sort()
        used_obs: set[int] = set()
        used_lm: set[int] = set()
        pairs = []
        for _, k, i in scored:
            if k in used_obs or i in used_lm:
                continue
            used_obs.add(k)
            used_lm.add(i)
            pairs.append((i, observations[k][0]))
        return pairs, used_obs | set(near_something)

    def classify(self, landmarks: list[int], classes: list[str]) -> None:
        """These landmarks' classes by Table 3 ("static" or "dynamic", from the static map:
        :meth:`DynamicMapper.classify_landmarks`); only static ones correct the pose."""
        for i, cls in zip(landmarks, classes, strict=True):
            self.tracks[i].cls = cls

    def correct(self, pairs: list[tuple[int, np.ndarray]]) -> int:
        """Update with every associated static landmark; returns how many were used."""
        used = 0
        for i, z in pairs:
            track = self.tracks[i]
            track.observations += 1
            track.last_seen = self.scan_index
            if track.cls == "static":
                self.ekf.update(i, z)
                used += 1
        return used

    def add_new(self, observations: list[tuple[np.ndarray, bool]], not_new: set[int]
                ) -> None:
        """Tentative stage: corners that are not landmarks yet (all but ``not_new``) become
        landmarks once confirmed."""
        cfg, pose = self.config, self.ekf.x[:3]
        self.candidates = [c for c in self.candidates
                           if self.scan_index - c.last_seen <= cfg.candidate_expiry_scans]
        for k, (z, convex) in enumerate(observations):
            if k in not_new:
                continue
            x, y = inverse_observe(pose, z)
            best = min((c for c in self.candidates if c.convex == convex),
                       key=lambda c: math.hypot(c.x - x, c.y - y), default=None)
            if best is None or math.hypot(best.x - x, best.y - y) > cfg.candidate_radius_m:
                self.candidates.append(Candidate(x, y, convex, 1, self.scan_index))
                continue
            best.count += 1
            best.x += (x - best.x) / best.count
            best.y += (y - best.y) / best.count
            best.last_seen = self.scan_index
            if best.count >= cfg.confirm_observations:
                self.candidates.remove(best)
                self.ekf.add_landmark(z)
                self.tracks.append(LandmarkTrack(self._next_id, convex,
                                                 observations=best.count,
                                                 last_seen=self.scan_index))
                self._next_id += 1

    def prune(self) -> None:
        """Keep the state bounded: landmarks out of sight for ``active_window_scans`` leave
        the filter, then the least recently seen while there are too many."""
        cfg = self.config
        drop = {i for i, t in enumerate(self.tracks)
                if self.scan_index - t.last_seen > cfg.active_window_scans}
        excess = len(self.tracks) - len(drop) - cfg.max_landmarks
        if excess > 0:
            rest = sorted((t.last_seen, i) for i, t in enumerate(self.tracks) if i not in drop)
            drop.update(i for _, i in rest[:excess])
        if not drop:
            return
        order = sorted(drop)
        self.retired += [r for r in self._records(order)
                         if r.observations >= cfg.keep_observations]
        self.ekf.remove_landmarks(order)
        self.tracks = [t for i, t in enumerate(self.tracks) if i not in drop]

    def landmark_records(self) -> list[LandmarkRecord]:
        """Every landmark for the map: those that left the filter, then those in it."""
        return self.retired + self._records(range(len(self.tracks)))

    def _records(self, indices: Iterable[int]) -> list[LandmarkRecord]:
        xy = self.landmark_positions()
        out = []
        for i in indices:
            t, j = self.tracks[i], 3 + 2 * i
            out.append(LandmarkRecord(t.id, float(xy[i, 0]), float(xy[i, 1]), t.convex,
                                      t.observations, t.last_seen,
                                      self.ekf.cov[j:j + 2, j:j + 2].copy()))
        return out

    def landmark_map(self, correction: Callable[[int], Pose2D] | None = None,
                     resolve_m: float = 0.0
                     ) -> list[tuple[int, bool, int, float, float, np.ndarray]]:
        """Every landmark confirmed (those let go of included), one per corner
        (:func:`one_per_corner`, corners closer than ``resolve_m`` one): (id, convex,
        observations, x, y, 2×2 covariance), each moved by ``correction`` (a scan number →
        the correction of this filter's frame at that scan, the pose graph's; None: none) at
        the scan it was last seen."""
        records = self.landmark_records()
        if not records:
            return []
        xy = np.array([[r.x, r.y] for r in records])
        angles = np.zeros(len(records))
        if correction is not None:
            for k, r in enumerate(records):
                corr = correction(r.last_seen)
                p = compose(corr, Pose2D(xy[k, 0], xy[k, 1], 0.0))
                xy[k] = (p.x, p.y)
                angles[k] = corr.theta
        covs = []
        for r, a in zip(records, angles, strict=True):
            c, s = math.cos(a), math.sin(a)
            rot = np.array([[c, -s], [s, c]])
            covs.append(rot @ r.cov @ rot.T)
        return one_per_corner([(r.id, r.convex, r.observations) for r in records], xy,
                              np.array(covs), self.config.gate_chi2, resolve_m)

    def landmark_positions(self) -> np.ndarray:
        return self.ekf.x[3:].reshape(-1, 2)


@dataclass(eq=False)
class _Corner:
    """A corner of the landmark map being built: its first id, kind, sightings, the sum of
    its landmarks' information and information-weighted positions, and from these its
    covariance and position."""

    id: int
    convex: bool
    seen: int
    info: np.ndarray
    weighted: np.ndarray
    cov: np.ndarray = field(init=False)
    xy: np.ndarray = field(init=False)

    def __post_init__(self) -> None:
        self.cov = np.linalg.inv(self.info)
        self.xy = self.cov @ self.weighted


def one_per_corner(landmarks: list[tuple[int, bool, int]], xy: np.ndarray, covs: np.ndarray,
                   gate_chi2: float, resolve_m: float = 0.0
                   ) -> list[tuple[int, bool, int, float, float, np.ndarray]]:
    """The landmark map with one row per corner: a landmark the EKF let go of and confirmed
    anew when the robot came back is the same corner twice. Landmarks (id, convex,
    observations) of the same kind whose positions ``xy`` agree within their combined
    covariance (``covs``, N×2×2; the association gate ``gate_chi2``, χ² 2 dof), or lie
    closer than ``resolve_m`` (the map's cell: the end of a partition one cell thick has
    two corners that S draws as one), are one: the first id, the observations summed, the
    positions fused by their information, again over the corners so made until no two are
    one (a fused position can come within reach of a corner it was not within before). In
    order of id; returns (id, convex, observations, x, y, covariance)."""
    while True:
        merged = _one_pass(landmarks, xy, covs, gate_chi2, resolve_m)
        if len(merged) == len(landmarks):
            return merged
        landmarks = [(i, convex, seen) for i, convex, seen, _, _, _ in merged]
        xy = np.array([[x, y] for _, _, _, x, y, _ in merged])
        covs = np.array([cov for *_, cov in merged])


def _one_pass(landmarks: list[tuple[int, bool, int]], xy: np.ndarray, covs: np.ndarray,
              gate_chi2: float, resolve_m: float
              ) -> list[tuple[int, bool, int, float, float, np.ndarray]]:
    """:func:`one_per_corner`'s landmarks merged in one pass, each into the first corner
    made so far that it agrees with."""
    corners: list[_Corner] = []
    for k in np.argsort([i for i, _, _ in landmarks], kind="stable"):
        ident, convex, seen = landmarks[k]
        info = np.linalg.inv(covs[k])
        for n, c in enumerate(corners):
            if c.convex != convex:
                continue
            d = xy[k] - c.xy
            both = c.cov + covs[k]
            # (d²/trace bounds the Mahalanobis distance from below: far corners skip solve)
            if float(d @ d) < resolve_m * resolve_m or (
                    float(d @ d) <= gate_chi2 * float(np.trace(both))
                    and float(d @ np.linalg.solve(both, d)) < gate_chi2):
                corners[n] = _Corner(c.id, convex, c.seen + seen, c.info + info,
                                     c.weighted + info @ xy[k])
                break
        else:
            corners.append(_Corner(ident, convex, seen, info, info @ xy[k]))
    return [(int(c.id), bool(c.convex), int(c.seen), float(c.xy[0]), float(c.xy[1]), c.cov)
            for c in corners]
