"""A second session on a prior map (``dynslam process LOG --prior DIR``).

The earlier session's static map S is where this one starts: its first scan is placed in it
by the global search (dynslam_cli.localization.globalsearch; near ``--initial-pose`` when
one is given), every pose is then in the prior's frame, and S^{t-1} of the first scan is
the prior's S (its Occupied cells as sure as the grid holds, its Free cells too), so Tables
1 and 2 judge today's scans against yesterday's map: an object standing where the prior
was Free goes to D, a place the prior held Occupied and today's beams pass through is
cleared. The outputs lie on the prior's lattice, so the two folders overlay cell for cell.
A log that cannot be placed (too poor a fit, or two places alike) is an error, never a map
drawn in the wrong place.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np

from dynslam_cli.errors import InputError
from dynslam_cli.geometry import compose, inverse, transform_points
from dynslam_cli.localization.backend import PriorWalls
from dynslam_cli.localization.frontend import Motion, ScanMeasurer
from dynslam_cli.localization.globalsearch import (
    BlurredMap,
    MapField,
    Placement,
    heading_step,
    log_likelihood,
    place,
)
from dynslam_cli.localization.scanmatch import scan_points, thin
from dynslam_cli.mapping.changes import ChangeRecorder
from dynslam_cli.mapping.grid import GridStack, OccupancyMap, logit, steps
from dynslam_cli.sections import MapConfig, MatchConfig, NoiseModel, PriorConfig
from dynslam_cli.types import Pose2D, Scan

SEARCH_CELLS = 3  # the search takes one end point per square of this many cells a side
# The place found is made finer with the scans of this many metres more driving (one scan
# that sees little along a direction left 2.3 cm there, and the prior's walls along it
# were taken for objects removed).
REFINE_TRAVEL_M = 2.0
OUTLIER_SHARE = 0.1  # an end point is not on the map's walls (a person, a moved box) ...
EFFECTIVE_POINTS = 40.0  # ... and a scan's end points err together, as this many at most;
# end points within a square of this side (m) lie on one stretch of wall and err together:
# a cloud of scans driven over metres counts one per square it covers (the hall world's
# second session: one scan covers 26, after 20 m 89 and after 40 m 111; without this, a
# placement ambiguous at the first scan stayed so, however far the robot drove)
INDEPENDENT_M = 1.0


@dataclass(frozen=True)
class PriorMap:
    """An earlier session's static map as read from its folder: the grid (probabilities
    as its file gives them) and the thresholds that class its cells; and its dynamic map
    (None where the folder has none)."""

    folder: str
    static: OccupancyMap
    free_thresh: float
    occupied_thresh: float
    dynamic: OccupancyMap | None = None
    objects: tuple[tuple[float, float, float], ...] = ()
    """Objects its change events say stood at its end (x, y, m²): arrived, not left."""

    @functools.cached_property
    def occupied(self) -> np.ndarray:
        """Its Occupied cells (rows × cols, row 0 at the lowest y)."""
        return self.static.prob > self.occupied_thresh

    @property
    def centre(self) -> tuple[float, float]:
        """The centre of its cell (0, 0) in its frame."""
        g = self.static
        return g.origin_x + 0.5 * g.resolution, g.origin_y + 0.5 * g.resolution

    def cells(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """World (row, col) of the Free and Occupied cells, and which are Occupied."""
        rows, cols = np.nonzero((self.static.prob < self.free_thresh) | self.occupied)
        return *_world_cells(self.static, rows, cols), self.occupied[rows, cols]

    def standing(self) -> tuple[np.ndarray, np.ndarray]:
        """World (row, col) of the cells its D held Occupied at its end: objects standing
        where S was Free (none without a dynamic map)."""
        if self.dynamic is None:
            return np.zeros(0, np.intp), np.zeros(0, np.intp)
        return _world_cells(self.dynamic, *np.nonzero(self.dynamic.prob > self.occupied_thresh))


def steady(clouds: list[np.ndarray], stamps: list[float], cell: float, seconds: float
           ) -> np.ndarray:
    """The end points of scans (each N×2, one frame, taken at ``stamps``) in squares of side
    ``cell`` where the scans saw something over at least ``seconds``: a walker's end points
    move on, a wall's stay. All of them while the scans span less than that."""
    cloud = np.vstack(clouds)
    if seconds <= 0 or stamps[-1] - stamps[0] < seconds:
        return cloud
    t = np.repeat(np.asarray(stamps), [len(c) for c in clouds])
    cells = np.floor(cloud / cell).astype(np.int64)
    _, which = np.unique(cells, axis=0, return_inverse=True)
    which = which.reshape(-1)
    first = np.full(which.max() + 1, np.inf)
    last = np.full(which.max() + 1, -np.inf)
    np.minimum.at(first, which, t)
    np.maximum.at(last, which, t)
    return cloud[(last - first)[which] >= seconds]


def _world_cells(grid: OccupancyMap, rows: np.ndarray, cols: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
    """A grid's (row, col) as world (row, col): counted from the frame's origin."""
    return (rows + round(grid.origin_y / grid.resolution),
            cols + round(grid.origin_x / grid.resolution))


def check_lattice(prior: PriorMap, resolution: float) -> None:
    """The prior's cells must be this run's: the same size, on the same lattice."""
    grid = prior.static
    if abs(grid.resolution - resolution) > 1e-9 * resolution:
        raise InputError(prior.folder, f"the prior map's cells are {grid.resolution:g} m, "
                         f"this run's {resolution:g} m: run with --resolution "
                         f"{grid.resolution:g}")
    for origin in (grid.origin_x, grid.origin_y):
        if abs(origin / resolution - round(origin / resolution)) > 1e-6:
            raise InputError(prior.folder, f"the prior map's origin {origin:g} m is not on "
                             f"its {resolution:g} m lattice (not a map dynslam wrote?)")


class PriorSession:
    """What a run on a prior map needs: the prior's S to start the grids from, and the
    first scan's place in it."""

    def __init__(self, prior: PriorMap, m: MapConfig, cfg: PriorConfig, match: MatchConfig,
                 motion_noise: NoiseModel, initial: Pose2D | None = None) -> None:
        """``match`` and ``motion_noise``: how the log's first scans are put together (the
        front end's scan matching) and which end points are used; ``initial``: where the
        user says the log starts (map frame), or None."""
        check_lattice(prior, m.resolution_m)
        self.prior, self.cfg, self.match, self.initial = prior, cfg, match, initial
        self._motion_noise = motion_noise
        self._cells = prior.cells()
        self._frame: Pose2D | None = None  # the log's odometry frame in the prior's
        self._start: Pose2D | None = None  # where the log's first scan lies in the prior
        self._seed = np.array(steps(np.array([logit(m.p_clamp_min), logit(m.p_clamp_max)])),
                              dtype=np.int16)
        self.report: dict[str, Any] = {"folder": prior.folder, "initial_pose": (
            None if initial is None else [initial.x, initial.y, math.degrees(initial.theta)])}

    def walls(self) -> PriorWalls:
        """What the pose graph matches the run's scans against as it goes, to stay in the
        prior's frame: the centres of its Occupied cells (N×2), and the blurred map to make
        a match finer than a cell on."""
        g = self.prior.static
        rows, cols = np.nonzero(self.prior.occupied)
        return PriorWalls(np.column_stack((g.origin_x + (cols + 0.5) * g.resolution,
                                           g.origin_y + (rows + 0.5) * g.resolution)),
                          self.blurred)

    def seed(self, grids: GridStack, changes: ChangeRecorder | None) -> None:
        """Start S (the layer "static") from the prior's Free and Occupied cells, each as
        sure as the grid holds; tell ``changes`` what stood in the prior's D."""
        rows, cols, occupied = self._cells
        grids.seed("static", rows, cols, self._seed[occupied.astype(np.intp)])
        if changes is not None:
            changes.note_prior_standing(*self.prior.standing(), list(self.prior.objects))

    def to_map(self, scan: Scan) -> Pose2D:
        """The scan's odometry in the prior's frame. The first scan of the run is the log's
        first: placed already (:meth:`place`), or now from itself alone."""
        if self._frame is None:
            start = self._start if self._start is not None else self.place([(scan, None)])
            self._frame = compose(start, inverse(scan.odom))
        return compose(self._frame, scan.odom)

    def place(self, scans: Iterable[tuple[Scan, Motion | None]]) -> Pose2D:
        """Where the first of ``scans`` (the log's first scans, each with the motion the
        front end measured, or None to scan-match them here) lies in
        the prior map: from it alone, or where that fits more than one place (a corridor),
        from it and the scans driven after it, put together by the front end's scan matching
        (wheel odometry alone turns 7-11° wrong within 2 m on MIT CSAIL), tried again at
        each doubling of the distance driven up to ``max_travel_m``; the place found is made
        finer with the scans of REFINE_TRAVEL_M more. An InputError if no place fits well,
        or more than one does all the way."""
        res = self.prior.static.resolution
        field = MapField(self.prior.occupied, res, self.prior.centre)
        measure = ScanMeasurer(self.match, self._motion_noise, None)
        here: Pose2D | None = None  # each scan's pose in the first's frame
        clouds: list[np.ndarray] = []
        stamps: list[float] = []
        found: Placement | None = None  # the last search's, from where it was ...
        searched, evidence, tried_m = "", 0.0, 0.0  # ... and driven how far
        travel, until, decided = 0.0, math.inf, 0.0
        for scan, motion in scans:
            step = (measure.motion(scan) if motion is None else motion).increment  # (the
            # first's: from the odometry's origin)
            if here is not None:
                travel += math.hypot(step.x, step.y)
            here = Pose2D() if here is None else compose(here, step)
            clouds.append(transform_points(here, scan_points(scan, self.match.max_range_m)))
            stamps.append(scan.stamp)
            if travel >= until:
                break
            if until == math.inf and (found is None or travel >= 2.0 * tried_m
                                      or travel > self.cfg.max_travel_m):
                cloud = steady(clouds, stamps, SEARCH_CELLS * res, self.cfg.steady_s)
                cloud = cloud[thin(cloud, SEARCH_CELLS * res)]
                found, searched = self._search(field, cloud)
                evidence = self._evidence(field, cloud, found)
                tried_m = max(travel, self.cfg.max_travel_m / 16)
                if self._problem(found, evidence) is None:
                    decided, until = travel, travel + REFINE_TRAVEL_M  # (then refined)
                elif travel > self.cfg.max_travel_m:
                    break
        if found is None:
            raise InputError(self.prior.folder, "the log has no scan to place in the prior map")
        problem = self._problem(found, evidence)
        if problem is not None:
            raise InputError(self.prior.folder, f"the log's first scans {problem} (matched "
                             f"together over {travel:.1f} m of driving)")
        if self.initial is not None and searched != "near the initial pose":
            d = math.hypot(found.pose.x - self.initial.x, found.pose.y - self.initial.y)
            self.report["warning"] = (f"nothing near --initial-pose fits; placed "
                                      f"{d:.2f} m from it")
        cloud = np.vstack(clouds)
        pose = self._refine(found.pose, cloud[thin(cloud, res)])
        self.report.update(searched=searched, score=round(found.score, 4),
                           rival_score=round(found.runner_up, 4),
                           rival_evidence=None if math.isinf(evidence) else round(evidence, 2),
                           driven_m=round(decided, 2),
                           refined_over_m=round(travel, 2),
                           start=[pose.x, pose.y, math.degrees(pose.theta)])
        self._start = pose
        return pose

    def _search(self, field: MapField, points: np.ndarray) -> tuple[Placement, str]:
        """The placement of the points: near the initial pose if one was given and
        something there fits, else over the whole map."""
        if self.initial is not None:
            near = (self.initial, self.cfg.initial_tolerance_m, self.cfg.initial_tolerance_deg)
            found = self._place(field, points, near)
            if found.pose is not None:
                return found, "near the initial pose"
            return (self._place(field, points, None),
                    "whole map (nothing near the initial pose fits)")
        return self._place(field, points, None), "whole map"

    def _refine(self, pose: Pose2D, points: np.ndarray) -> Pose2D:
        """The search's pose (a cell's centre, a heading of its lattice) made finer, within
        a cell and a heading step of it."""
        res = self.prior.static.resolution
        return self.blurred.refine(points, pose, res, heading_step(points, res))

    @functools.cached_property
    def blurred(self) -> BlurredMap:
        """The prior's Occupied cells blurred, to make poses finer than a cell on."""
        return BlurredMap(self.prior.occupied, self.prior.static.resolution, self.prior.centre)

    def _place(self, field: MapField, points: np.ndarray,
               near: tuple[Pose2D, float, float] | None) -> Placement:
        c = self.cfg
        likelier = None
        if c.rival_search == "likelihood":  # a rival matters within this of the best
            likelier = (OUTLIER_SHARE, c.rival_evidence / _counted(points))
        return place(field, points, c.min_score, c.rival_m, c.rival_deg, c.rival_share, near,
                     likelier)

    def _problem(self, found: Placement, evidence: float) -> str | None:
        """What is wrong with a placement whose best place is e^``evidence`` times as likely
        as its rival (None: one place fits well)."""
        c = self.cfg
        if found.pose is None:
            return (f"fit nowhere in the prior map (no place scores prior.min_score "
                    f"{c.min_score:g}): another place, or a map too old?")
        if evidence < c.rival_evidence:
            p = found.pose
            return (f"fit the prior map in more than one place (best {found.score:.2f} at "
                    f"{p.x:.2f}, {p.y:.2f}, {math.degrees(p.theta):.0f}°; another scores "
                    f"{found.runner_up:.2f}, log-likelihood ratio {evidence:.1f}): give "
                    f"--initial-pose X,Y,DEGREES")
        return None

    @staticmethod
    def _evidence(field: MapField, points: np.ndarray, found: Placement) -> float:
        """How much likelier the best place is than its rival: the log-likelihood ratio of
        the end points at the two (see PriorConfig.rival_evidence); ∞ without a rival."""
        if found.pose is None or found.rival is None:
            return math.inf
        best = log_likelihood(field.values(points, found.pose), OUTLIER_SHARE)
        rival = log_likelihood(field.values(points, found.rival), OUTLIER_SHARE)
        return float(np.mean(best - rival)) * _counted(points)


def _counted(points: np.ndarray) -> float:
    """How many independent end points a cloud (N×2) counts as: one scan's as at most
    EFFECTIVE_POINTS; the scans driven after it see other walls, and a cloud counts one
    per square of INDEPENDENT_M it covers where that is more."""
    covered = len(np.unique(np.floor(points / INDEPENDENT_M).astype(np.int64), axis=0))
    return float(min(len(points), max(EFFECTIVE_POINTS, covered)))
