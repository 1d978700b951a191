"""Global localization by branch and bound: a scan placed in a whole map from no guess."""

from __future__ import annotations

import math

import numpy as np
import pytest

from dynslam_cli.localization.globalsearch import BlurredMap, Lattice, MapField, place
from dynslam_cli.simulate import ray_cast
from dynslam_cli.types import Pose2D

RES = 0.05
ANGLES = np.radians(np.arange(-90, 90.25, 1.0))
# A room with an alcove and a pillar: nothing symmetric, so a scan has one place.
ROOM = np.array([[-4, -3, 6, -3], [6, -3, 6, 4], [6, 4, 1, 4], [1, 4, 1, 5.5],
                 [1, 5.5, -1, 5.5], [-1, 5.5, -1, 4], [-1, 4, -4, 4], [-4, 4, -4, -3],
                 [2, 0, 2.6, 0], [2.6, 0, 2.6, 0.4], [2.6, 0.4, 2, 0.4], [2, 0.4, 2, 0]],
                float)
# A square room with a pillar in each corner: every quarter turn looks the same.
SQUARE = np.array([[0, 0, 8, 0], [8, 0, 8, 8], [8, 8, 0, 8], [0, 8, 0, 0],
                   [2, 2, 2.4, 2], [6, 2, 6, 2.4], [6, 6, 5.6, 6], [2, 6, 2, 5.6]], float)


def occupancy(walls: np.ndarray) -> tuple[np.ndarray, tuple[float, float]]:
    """The walls drawn into a grid of RES cells (row 0 at the lowest y) and the centre of
    cell (0, 0)."""
    lo = walls.reshape(-1, 2).min(axis=0) - 1.0
    hi = walls.reshape(-1, 2).max(axis=0) + 1.0
    cols, rows = (np.ceil((hi - lo) / RES).astype(int) + 1)
    grid = np.zeros((rows, cols), bool)
    for x1, y1, x2, y2 in walls:
        n = int(math.hypot(x2 - x1, y2 - y1) / (RES / 4)) + 2
        x, y = np.linspace(x1, x2, n), np.linspace(y1, y2, n)
        grid[np.floor((y - lo[1]) / RES + 0.5).astype(int),
             np.floor((x - lo[0]) / RES + 0.5).astype(int)] = True
    return grid, (float(lo[0]), float(lo[1]))


def scan_from(walls: np.ndarray, pose: Pose2D, seed: int = 0) -> np.ndarray:
    """End points (robot frame) of a 181-beam scan with 1 cm range noise."""
    ranges, owner = ray_cast(pose, ANGLES, walls, np.zeros(len(walls), np.int64),
                             np.zeros((0, 3)), np.zeros(0, np.int64), 8.0)
    ranges = ranges + np.random.default_rng(seed).normal(0.0, 0.01, len(ranges))
    ok = owner != -2
    return np.column_stack((ranges * np.cos(ANGLES), ranges * np.sin(ANGLES)))[ok]


@pytest.mark.parametrize("truth", [Pose2D(0.2, -0.4, 1.3), Pose2D(4.1, 2.2, -2.9),
                                   Pose2D(0.3, 3.1, -1.2)])
def test_a_scan_is_placed_where_it_was_taken_from_no_guess(truth: Pose2D) -> None:
    grid, origin = occupancy(ROOM)
    found = place(MapField(grid, RES, origin), scan_from(ROOM, truth), min_score=0.5)
    assert math.hypot(found.pose.x - truth.x, found.pose.y - truth.y) <= 1.5 * RES
    assert abs(math.remainder(found.pose.theta - truth.theta, math.tau)) <= math.radians(1.0)
    assert found.score > 0.8
    assert found.runner_up < 0.9 * found.score  # one place fits: the answer is unique


def test_a_symmetric_room_is_reported_as_ambiguous() -> None:
    grid, origin = occupancy(SQUARE)
    found = place(MapField(grid, RES, origin), scan_from(SQUARE, Pose2D(1.5, 4.0, 0.3)),
                  min_score=0.5)
    assert found.runner_up > 0.95 * found.score  # another quarter turn fits as well


def test_the_likeliest_rival_is_found_only_where_it_could_be_mistaken() -> None:
    """The rival searched on the log-likelihood, down to a margin under the best's: in the
    symmetric room the quarter turn is found (as likely as the best), in the room with one
    place nothing comes within a margin, and with a margin wide enough one no less likely
    than the best-scoring pose elsewhere."""
    grid, origin = occupancy(SQUARE)
    field = MapField(grid, RES, origin)
    points = scan_from(SQUARE, Pose2D(1.5, 4.0, 0.3))
    found = place(field, points, min_score=0.5, likelier=(0.1, 0.05))
    assert found.rival is not None and found.runner_up > 0.95 * found.score
    grid, origin = occupancy(ROOM)
    field = MapField(grid, RES, origin)
    points = scan_from(ROOM, Pose2D(0.2, -0.4, 1.3))
    assert place(field, points, min_score=0.5, likelier=(0.1, 0.05)).rival is None
    by_score = place(field, points, min_score=0.5, rival_share=0.01)
    wide = place(field, points, min_score=0.5, likelier=(0.1, 10.0))
    assert wide.rival is not None and by_score.rival is not None

    def log_likelihood(pose: Pose2D) -> float:
        return float(np.mean(np.log1p(9.0 * field.values(points, pose))))

    # the likeliest elsewhere: no less likely than the best-scoring pose elsewhere
    assert log_likelihood(wide.rival) >= log_likelihood(by_score.rival) - 1e-6


def test_the_bound_of_each_level_is_above_every_pose_it_covers() -> None:
    grid, origin = occupancy(ROOM)
    field = MapField(grid, RES, origin)
    lattice = Lattice(field, scan_from(ROOM, Pose2D(1.0, 1.0, 0.5)))
    rng = np.random.default_rng(1)
    for level in range(1, field.top + 1):
        span = 1 << level
        th = rng.integers(0, len(lattice.thetas), 40)
        col = rng.integers(0, field.size[1], 40) + field.pad
        row = rng.integers(0, field.size[0], 40) + field.pad
        bound = lattice.scores(level, th, col, row)
        for i in range(40):
            dc, dr = np.meshgrid(np.arange(span), np.arange(span))
            fine = lattice.scores(0, np.full(span * span, th[i]), col[i] + dc.ravel(),
                                  row[i] + dr.ravel())
            assert fine.max() <= bound[i] + 1e-12


def test_the_compiled_scores_are_the_mean_field_at_the_end_points() -> None:
    grid, origin = occupancy(ROOM)
    field = MapField(grid, RES, origin)
    lattice = Lattice(field, scan_from(ROOM, Pose2D(1.0, 1.0, 0.5)))
    rng = np.random.default_rng(2)
    th = rng.integers(0, len(lattice.thetas), 50)
    col = rng.integers(-20, field.levels[0].shape[1] + 20, 50)  # some points off the grid
    row = rng.integers(-20, field.levels[0].shape[0] + 20, 50)
    fine = field.levels[0]
    r, c = lattice.dr[th] + row[:, None], lattice.dc[th] + col[:, None]
    on = (r >= 0) & (r < fine.shape[0]) & (c >= 0) & (c < fine.shape[1])
    expected = np.where(on, fine[np.clip(r, 0, fine.shape[0] - 1),
                                 np.clip(c, 0, fine.shape[1] - 1)], 0.0).mean(axis=1)
    assert np.allclose(lattice.scores(0, th, col, row), expected, rtol=0, atol=1e-6)  # float32


def test_a_placement_is_made_finer_than_a_cell_on_the_blurred_map() -> None:
    """The search answers on its lattice (a cell, a heading step); the blurred map's
    refinement moves a pose 2 cm and 0.6° off back onto the truth, to a few millimetres."""
    grid, origin = occupancy(ROOM)
    blurred = BlurredMap(grid, RES, origin)
    truth = Pose2D(0.2, -0.4, 1.3)
    points = np.vstack([scan_from(ROOM, truth, seed) for seed in range(3)])
    start = Pose2D(truth.x + 0.015, truth.y - 0.013, truth.theta + math.radians(0.6))
    found = blurred.refine(points, start, RES, math.radians(1.0))
    assert math.hypot(found.x - truth.x, found.y - truth.y) < 0.005
    assert abs(math.remainder(found.theta - truth.theta, math.tau)) < math.radians(0.1)
    # a pose already at the best stays there
    again = blurred.refine(points, found, RES, math.radians(1.0))
    assert math.hypot(again.x - found.x, again.y - found.y) < 1e-4
