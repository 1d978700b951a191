"""The growable grid and beam tracing."""

from __future__ import annotations

import math

import numpy as np

from dynslam_cli.mapping.grid import GridStack
from dynslam_cli.types import Pose2D


def cells(grid: GridStack, flat: np.ndarray) -> set[tuple[int, int]]:
    rows, cols = np.divmod(flat, grid.shape[1])
    return {(int(r) + grid.origin_row, int(c) + grid.origin_col)
            for r, c in zip(rows, cols, strict=True)}


def test_beam_marks_free_cells_then_a_hit():
    g = GridStack(0.1, 1.0, ("static",))
    obs = g.observe(Pose2D(0.05, 0.05, 0.0), np.array([1.0]), np.array([0.0]), 10.0, 0.01, 5.0)
    assert cells(g, obs.hit) == {(0, 10)}
    assert cells(g, obs.free) == {(0, c) for c in range(9)}  # stops a cell short of the hit


def test_no_return_clears_up_to_cap_and_marks_no_hit():
    g = GridStack(0.1, 1.0, ("static",))
    obs = g.observe(Pose2D(0.05, 0.05, 0.0), np.array([10.0, math.inf]),
                    np.array([0.0, math.pi / 2]), 10.0, 0.01, 2.0)
    assert len(obs.hit) == 0
    free = cells(g, obs.free)
    assert (0, 19) in free and (0, 20) not in free
    assert (19, 0) in free and (20, 0) not in free


def test_invalid_beams_are_ignored():
    g = GridStack(0.1, 1.0, ("static",))
    obs = g.observe(Pose2D(), np.array([np.nan, 0.0]), np.array([0.0, 1.0]), 10.0, 0.01, 2.0)
    assert len(obs.hit) == 0 and len(obs.free) == 0


def test_grid_grows_in_every_direction_keeping_content():
    g = GridStack(0.1, 0.5, ("static",))
    obs = g.observe(Pose2D(), np.array([1.0]), np.array([0.0]), 10.0, 0.01, 2.0)
    g.layers["static"].reshape(-1)[obs.hit] = 7.0
    before = (g.origin_row, g.origin_col)
    for angle in (math.pi, math.pi / 2, -math.pi / 2):
        g.observe(Pose2D(), np.array([30.0]), np.array([angle]), 40.0, 0.01, 2.0)
    assert (g.origin_row, g.origin_col) != before
    r, c = np.argwhere(g.layers["static"] == 7.0)[0]
    assert (r + g.origin_row, c + g.origin_col) == (0, 10)
    assert g.shape[0] > 600 and g.shape[1] > 300
