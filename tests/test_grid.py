"""The growable grid and beam tracing."""

from __future__ import annotations

import math

import numpy as np

from dynslam_cli.mapping.grid import GridStack, steps
from dynslam_cli.types import Pose2D


def cells(grid: GridStack, flat: np.ndarray) -> set[tuple[int, int]]:
    rows, cols = grid.world_cells(flat)
    return {(int(r), int(c)) for r, c in zip(rows, cols, strict=True)}


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
    g.layers["static"][obs.hit] = steps(7.0)
    before = (g.origin_row, g.origin_col)
    for angle in (math.pi, math.pi / 2, -math.pi / 2):
        g.observe(Pose2D(), np.array([30.0]), np.array([angle]), 40.0, 0.01, 2.0)
    assert (g.origin_row, g.origin_col) != before
    dense = g.window("static", 0, g.shape[0], 0, g.shape[1])
    r, c = np.argwhere(dense == steps(7.0))[0]
    assert (r + g.origin_row, c + g.origin_col) == (0, 10)
    assert g.shape[0] > 600 and g.shape[1] > 300


def test_memory_follows_the_area_seen_not_the_space_between():
    """Two rooms 1 km apart: the grid's extent spans the kilometre, its cells the rooms."""
    g = GridStack(0.05, 1.0, ("static", "dynamic"), max_extent_m=2000.0)
    angles = np.linspace(-math.pi, math.pi, 720, endpoint=False)
    hits = 0
    for x in (0.0, 1000.0):  # a 4 m round room at each end, its wall marked in S
        obs = g.observe(Pose2D(x, 0.0, 0.0), np.full(720, 2.0), angles, 8.0, 0.01, 8.0)
        g.layers["static"][obs.hit] = steps(3.0)
        hits += len(obs.hit)
    assert g.shape[1] * g.resolution > 1000.0
    stored = g.memory()["cells_stored"]
    room = (4.2 / 0.05) ** 2
    assert 2 * room <= stored <= 2 * 9 * room  # the two rooms, in whole tiles
    nbytes = sum(a.nbytes for a in (*g.layers.values(), g._listed))  # capacity included
    assert nbytes < 4e6  # (a dense grid over the extent: 20000 × 90 cells × 5 B = 9 MB)
    snap = g.snapshot("static")
    assert snap.shape == g.snapshot("dynamic").shape and snap.shape[1] > 20000
    walls = sum(int((band > 0.5).sum()) for _, band in snap.bands())
    assert walls == hits  # both walls, read back band by band


def test_a_tile_border_does_not_change_the_neighbourhood_rule():
    """A cell's window that reaches into the next tile, or into one never stored, reads
    the same values a dense grid would (cells not stored: p = 0.5)."""
    from dynslam_cli.mapping import _grid

    g = GridStack(0.05, 1.0, ("static",))
    tile = _grid.TILE_SIDE
    # a beam along row 0 across a tile border: the cells just left and right of it
    obs = g.observe(Pose2D(0.025, 0.025, 0.0), np.array([tile * 0.05 + 1.0]),
                    np.array([0.0]), 100.0, 0.01, 8.0)
    g.layers["static"][obs.hit] = steps(5.0)  # one Occupied cell, at column tile + 20
    _, cols = g.world_cells(obs.free)
    border = obs.free[cols == tile]  # first cell of the second tile
    left = obs.free[cols == tile - 1]
    g.layers["static"][obs.free] = steps(-5.0)  # the traced cells Free
    high, low = 2.0, -2.0
    assert g.classify_cells("static", left, 0, low, high)[0] == 0  # Free
    assert g.classify_cells("static", left, 1, low, high)[0] == 1  # row −1: not stored
    hit_col = int(g.world_cells(obs.hit)[1][0])
    assert g.classify_world_cells("static", np.array([0]), np.array([hit_col - 1]), 1, low,
                                  high)[0] == 2
    assert g.classify_cells("static", border, 0, low, high)[0] == 0
    far = g.classify_world_cells("static", np.array([10**6]), np.array([0]), 2, low, high)
    assert far[0] == 1  # far outside anything stored: Unknown
