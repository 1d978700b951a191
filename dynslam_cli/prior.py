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

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from dynslam_cli.errors import InputError
from dynslam_cli.geometry import compose, inverse
from dynslam_cli.localization.globalsearch import (
    MapField,
    Placement,
    heading_step,
    place,
    refine,
)
from dynslam_cli.localization.scanmatch import scan_points
from dynslam_cli.mapping.grid import GridStack, OccupancyMap, logit, steps
from dynslam_cli.sections import MapConfig, MatchConfig, PriorConfig
from dynslam_cli.types import Pose2D, Scan


@dataclass(frozen=True)
class PriorMap:
    """An earlier session's static map as read from its folder: the grid (probabilities
    as its file gives them) and the thresholds that class its cells."""

    folder: str
    static: OccupancyMap
    free_thresh: float
    occupied_thresh: float

    def cells(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """World (row, col) of the Free and Occupied cells, and which are Occupied."""
        grid = self.static
        prob = grid.prob
        known = (prob < self.free_thresh) | (prob > self.occupied_thresh)
        rows, cols = np.nonzero(known)
        r0 = round(grid.origin_y / grid.resolution)
        c0 = round(grid.origin_x / grid.resolution)
        return rows + r0, cols + c0, prob[rows, cols] > self.occupied_thresh


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
                 initial: Pose2D | None = None) -> None:
        """``match``: how the placement is refined (ICP, and the range of the end points
        used); ``initial``: where the user says the log starts (map frame), or None."""
        check_lattice(prior, m.resolution_m)
        self.prior, self.cfg, self.match, self.initial = prior, cfg, match, initial
        self._cells = prior.cells()
        self._frame: Pose2D | None = None  # the log's odometry frame in the prior's
        self._seed = np.array(steps(np.array([logit(m.p_clamp_min), logit(m.p_clamp_max)])),
                              dtype=np.int16)
        self.report: dict[str, Any] = {"folder": prior.folder, "initial_pose": (
            None if initial is None else [initial.x, initial.y, math.degrees(initial.theta)])}

    def seed(self, grids: GridStack) -> None:
        """Start S (the layer "static") from the prior's Free and Occupied cells, each as
        sure as the grid holds."""
        rows, cols, occupied = self._cells
        grids.seed("static", rows, cols, self._seed[occupied.astype(np.intp)])

    def to_map(self, scan: Scan) -> Pose2D:
        """The scan's odometry in the prior's frame; the first scan of the log is placed by
        :meth:`start` (an InputError if it cannot be)."""
        if self._frame is None:
            self._frame = compose(self.start(scan), inverse(scan.odom))
        return compose(self._frame, scan.odom)

    def start(self, scan: Scan) -> Pose2D:
        """The pose of the log's first scan in the prior's frame (an InputError if it cannot
        be placed)."""
        grid = self.prior.static
        res = grid.resolution
        field = MapField(grid.prob > self.prior.occupied_thresh, res,
                         (grid.origin_x + 0.5 * res, grid.origin_y + 0.5 * res))
        points = scan_points(scan, self.match.max_range_m)
        found, searched = None, "whole map"
        if self.initial is not None:
            found = self._place(field, points, (self.initial, self.cfg.initial_tolerance_m,
                                                self.cfg.initial_tolerance_deg))
            searched = "near the initial pose"
            if found.pose is None:
                found, searched = None, "whole map (nothing near the initial pose fits)"
        if found is None:
            found = self._place(field, points, None)
            self._judge(found, points)
        pose = self._refine(found.pose, points, field)
        self.report.update(searched=searched, score=round(found.score, 4),
                           rival_score=round(found.runner_up, 4),
                           start=[pose.x, pose.y, math.degrees(pose.theta)])
        return pose

    def _refine(self, pose: Pose2D, points: np.ndarray, field: MapField) -> Pose2D:
        """The search's pose (a cell's centre, a heading of its lattice) made finer, within
        a cell and a heading step of it."""
        grid = self.prior.static
        return refine(grid.prob > self.prior.occupied_thresh, grid.resolution,
                      (grid.origin_x + 0.5 * grid.resolution,
                       grid.origin_y + 0.5 * grid.resolution), points, pose,
                      grid.resolution, heading_step(points, grid.resolution))

    def _place(self, field: MapField, points: np.ndarray,
               near: tuple[Pose2D, float, float] | None) -> Placement:
        c = self.cfg
        return place(field, points, c.min_score, c.rival_m, c.rival_deg, c.rival_share, near)

    def _judge(self, found: Placement, points: np.ndarray) -> None:
        """An InputError unless the whole-map search found one place that fits well."""
        c, folder = self.cfg, self.prior.folder
        if found.pose is None:
            raise InputError(folder, f"the log's first scan fits nowhere in the prior map "
                             f"(no place scores prior.min_score {c.min_score:g}; "
                             f"{len(points)} end points): another place, or a map too old?")
        if found.runner_up >= c.rival_share * found.score:
            p = found.pose
            raise InputError(folder, f"the log's first scan fits the prior map in more than "
                             f"one place (best {found.score:.2f} at {p.x:.2f}, {p.y:.2f}, "
                             f"{math.degrees(p.theta):.0f}°; another scores "
                             f"{found.runner_up:.2f}): give --initial-pose X,Y,DEGREES")
        if self.initial is not None:
            d = math.hypot(found.pose.x - self.initial.x, found.pose.y - self.initial.y)
            self.report["warning"] = (f"nothing near --initial-pose fits; placed "
                                      f"{d:.2f} m from it")
