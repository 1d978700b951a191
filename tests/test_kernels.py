"""The compiled kernels against plain numpy versions of the same definitions."""

from __future__ import annotations

import math

import numpy as np
import pytest

from dynslam_cli.localization import _graph, _loops, _match
from dynslam_cli.localization._match import PointIndex, first_in_cells
from dynslam_cli.mapping.grid import GridStack
from dynslam_cli.types import Pose2D

RNG = np.random.default_rng(7)


def brute_nearest(points: np.ndarray, q: np.ndarray, bound: float) -> np.ndarray:
    d = np.hypot(points[None, :, 0] - q[:, None, 0], points[None, :, 1] - q[:, None, 1])
    best = d.argmin(axis=1)
    return np.where(d[np.arange(len(q)), best] < bound, best, -1)


@pytest.mark.parametrize("bound", [0.05, 0.3, 1.7])
def test_nearest_point_matches_brute_force(bound):
    # clustered points (walls) and scattered ones, queries inside and outside their extent
    wall = np.column_stack((np.linspace(0, 5, 400), 2 + 0.01 * RNG.standard_normal(400)))
    points = np.vstack((wall, RNG.uniform(-3, 8, (300, 2))))
    queries = RNG.uniform(-5, 10, (2000, 2))
    got = PointIndex(points).query(queries, bound)
    np.testing.assert_array_equal(got, brute_nearest(points, queries, bound))


def test_normals_are_the_least_spread_direction_of_the_k_nearest():
    points = RNG.uniform(0, 4, (500, 2))
    k = 6
    got = PointIndex(points, neighbours=k).normals()
    d = np.hypot(points[None, :, 0] - points[:, None, 0], points[None, :, 1] - points[:, None, 1])
    for i in range(len(points)):
        nb = points[np.argsort(d[i], kind="stable")[:k]]
        _, vecs = np.linalg.eigh(np.cov(nb.T))
        assert abs(got[i] @ vecs[:, 0]) == pytest.approx(1.0, abs=1e-9)


def test_a_short_stub_far_from_other_walls_keeps_its_own_normal():
    # a wall along y at x = 0 and, 8 m away, a 0.56 m stub along y seen from afar (5 points
    # 0.14 m apart, fewer than the 6 neighbours a normal takes): this side of the gap its
    # normal is its own (along x), not leaned toward the wall's points 8 m away
    wall = np.column_stack((np.zeros(200), np.linspace(-5, 5, 200)))
    stub = np.column_stack((np.full(5, 8.0), np.linspace(-0.28, 0.28, 5)))
    points = np.vstack((wall, stub))
    bounded = PointIndex(points, neighbours=6, gap=3.0).normals()[200:]
    np.testing.assert_allclose(np.abs(bounded[:, 0]), 1.0, atol=1e-9)
    unbounded = PointIndex(points, neighbours=6).normals()[200:]
    assert np.all(np.abs(unbounded[:, 0]) < 0.5)  # (the old way: along the stub)
    # a far wall seen outdoors, its points 0.6 m apart (1° at 35 m): they keep their normals
    far = np.column_stack((np.linspace(-6, 6, 21), np.full(21, 35.0)))
    sparse = PointIndex(np.vstack((wall, far)), neighbours=6, gap=3.0).normals()[200:]
    np.testing.assert_allclose(np.abs(sparse[:, 1]), 1.0, atol=1e-9)


def test_a_point_with_too_few_neighbours_this_side_of_a_gap_has_no_normal_and_no_pair():
    wall = np.column_stack((np.linspace(0, 5, 101), np.zeros(101)))
    lone = np.array([[2.5, 3.0], [2.6, 3.0]])  # two points: no line to speak of
    index = PointIndex(np.vstack((wall, lone)), neighbours=6, gap=3.0)
    normals = index.normals()
    np.testing.assert_array_equal(normals[101:], 0.0)
    assert np.all(np.abs(normals[:101, 1]) == pytest.approx(1.0))
    # a scan of the wall and of the lone points: the lone points are not paired
    scan = np.vstack((wall[::2], lone))
    share = _match.icp(index, scan, 0.0, 0.0, 0.0, 10, 0.3, 0.1, 0, 0, 0, 0.02, 1e-3, 1e-4)[3]
    assert share == pytest.approx(51 / 53)


def test_pairs_on_a_thick_wall_weigh_less_with_thickness_weights():
    """A thin wall (y = 0) and a cluttered one (y = 2, its points ±5 cm about it): weighed
    by their neighbours' spread along the normal, the thin wall's pairs keep their
    information and the cluttered wall's lose most of theirs."""
    rng = np.random.default_rng(3)
    x = np.linspace(-3, 3, 121)
    thin = np.column_stack((x, np.zeros_like(x)))
    thick = np.column_stack((x, 2.0 + rng.uniform(-0.05, 0.05, len(x))))
    index = PointIndex(np.vstack((thin, thick)), neighbours=6)

    def y_information(scan: np.ndarray, thickness: bool) -> float:
        out = _match.icp(index, scan, 0.0, 0.0, 0.0, 10, 0.3, 0.1, 0, 0, 0, 0.02, 1e-3,
                         1e-4, thickness)
        return float(out[6][1, 1])

    assert y_information(thin, True) == pytest.approx(y_information(thin, False), rel=0.02)
    assert y_information(thick, True) < 0.5 * y_information(thick, False)


def test_a_ledge_beyond_a_walls_last_point_pairs_only_without_segments():
    """Two walls at a right angle seen before (to x = 3 m along y = 0), and now also a ledge
    6 cm in front of the first wall's line, beyond its last point: paired with that point,
    the ledge turns and moves the match; with ``segments`` (point to segment) it has no
    pair and the match stays exactly where the walls put it."""
    x = np.arange(0.0, 3.001, 0.02)
    walls = np.vstack((np.column_stack((x, 0 * x)), np.column_stack((0 * x, x))))
    ledge = np.column_stack((np.arange(3.04, 3.49, 0.02), np.full(23, 0.06)))
    index = PointIndex(walls, neighbours=8)

    def pose(segments: bool) -> np.ndarray:
        out = _match.icp(index, np.vstack((walls, ledge)), 0.0, 0.0, 0.0, 24, 0.5, 0.1,
                         0, 0, 0, 0.02, 1e-4, 1e-5, False, segments)
        return np.array(out[:3])

    assert np.abs(pose(True)).max() < 1e-9
    assert abs(pose(False)[2]) > math.radians(0.01)


def test_traced_cells_match_sampling_each_beam_every_cell():
    g = GridStack(0.05, 1.0, ("static",))
    n = 361
    angles = np.linspace(-math.pi / 2, math.pi / 2, n)
    ranges = RNG.uniform(0.5, 12.0, n)
    ranges[::17] = math.inf  # no return: cleared to the cap
    ranges[5::23] = math.nan  # invalid: ignored
    sensor = Pose2D(3.21, -1.7, 0.4)
    obs = g.observe(sensor, ranges, angles, 30.0, 0.02, 8.0)
    assert len(np.unique(obs.free)) == len(obs.free)
    assert len(np.unique(obs.hit)) == len(obs.hit)
    assert not set(obs.free) & set(obs.hit)

    res = g.resolution

    def cell(x: np.ndarray, y: np.ndarray) -> list[tuple[int, int]]:
        return list(zip(np.floor(y / res).astype(int).tolist(),
                        np.floor(x / res).astype(int).tolist(), strict=True))

    def world(flat: np.ndarray) -> set[tuple[int, int]]:
        rows, cols = g.world_cells(flat)
        return set(zip(rows.tolist(), cols.tolist(), strict=True))

    a = angles + sensor.theta
    hit_beam = np.isfinite(ranges) & (ranges < 30.0)
    hits = set(cell(sensor.x + ranges[hit_beam] * np.cos(a[hit_beam]),
                    sensor.y + ranges[hit_beam] * np.sin(a[hit_beam])))
    free = set()
    for r, ang, is_hit in zip(ranges, a, hit_beam, strict=True):
        if math.isnan(r):
            continue
        length = max(r - res, 0.0) if is_hit else 8.0
        d = np.arange(math.ceil(length / res)) * res
        free |= set(cell(sensor.x + d * math.cos(ang), sensor.y + d * math.sin(ang)))
    assert world(obs.hit) == hits
    # the kernel steps in cell units from the sensor's cell position; a sample exactly on a
    # cell border may round the other way, so allow a handful of such cells
    assert len(world(obs.free) ^ (free - hits)) <= 0.002 * len(free)
    assert g.seen[obs.free].all() and g.seen[obs.hit].all()
    assert g.memory()["tiles"] > 1  # the scan spans several tiles


@pytest.mark.parametrize("tx", [np.arange(-5, 6), np.arange(-60, 61, 4)],
                         ids=["consecutive", "every 4th"])  # (the search's; the loop closer's)
def test_mean_scores_match_numpy(tx):
    grid = RNG.uniform(0, 1, (60, 80))
    pts = RNG.uniform(-1, 1, (50, 2))
    ty = np.arange(-3, 4)
    got = _loops.mean_scores(grid, 0.2, -0.1, 0.05, pts, 1.0, 1.2, np.array([0.3]), tx, ty)[0]
    c, s = math.cos(0.3), math.sin(0.3)
    moved = np.column_stack((1.0 + c * pts[:, 0] - s * pts[:, 1],
                             1.2 + s * pts[:, 0] + c * pts[:, 1]))
    ix, iy = np.floor((moved - [0.2, -0.1]) / 0.05 + 0.5).astype(int).T
    want = np.zeros((len(ty), len(tx)))
    for a, dy in enumerate(ty):
        for b, dx in enumerate(tx):
            r, cc = iy + dy, ix + dx
            ok = (r >= 0) & (r < 60) & (cc >= 0) & (cc < 80)
            want[a, b] = grid[r[ok], cc[ok]].sum() / len(pts)
    np.testing.assert_allclose(got, want, rtol=1e-12)


def test_sparse_solve_matches_dense_in_any_order():
    n = 60
    a = np.zeros((n, n))
    for i in range(n - 1):  # a chain with a few long links, like a pose graph's Hessian
        a[i, i + 1] = a[i + 1, i] = -1.0
    for i, j in ((0, 40), (5, 59), (17, 33)):
        a[i, j] = a[j, i] = -0.5
    a += np.diag(np.abs(a).sum(axis=1) + 0.1)
    rows, cols = np.nonzero(a)
    # compressed columns with every entry split in two duplicates (they must be summed)
    rows, cols = np.repeat(rows, 2), np.repeat(cols, 2)
    by_col = np.argsort(cols, kind="stable")
    indptr = np.concatenate(([0], np.cumsum(np.bincount(cols, minlength=n))))
    data = 0.5 * a[rows, cols][by_col]
    b = RNG.standard_normal(n)
    for order in (np.arange(n), RNG.permutation(n)):
        x = _graph.solve_spd(indptr, rows[by_col].copy(), data, order.astype(np.intp), b)
        np.testing.assert_allclose(x, np.linalg.solve(a, b), rtol=1e-10, atol=1e-12)
    a[3, 3] = -1.0  # indefinite
    with pytest.raises(ValueError, match="positive definite"):
        _graph.solve_spd(indptr, rows[by_col].copy(), 0.5 * a[rows, cols][by_col],
                          np.arange(n, dtype=np.intp), b)


def _fill(n: int, ei: np.ndarray, ej: np.ndarray, order: np.ndarray) -> int:
    """Entries of the Cholesky factor below the diagonal, eliminating in ``order``."""
    adj = [set() for _ in range(n)]
    for a, b in zip(ei, ej, strict=True):
        if a != b:
            adj[a].add(b)
            adj[b].add(a)
    done, fill = set(), 0
    for v in order:
        nb = adj[v] - done
        fill += len(nb)
        for u in nb:
            adj[u] |= nb - {u}
        done.add(v)
    return fill


def test_minimum_degree_order_fills_in_less():
    # a star: the leaves go first, lowest index first, until the centre ties with the last
    leaves = np.arange(1, 8, dtype=np.intp)
    order, flops = _graph.minimum_degree(8, np.zeros(7, dtype=np.intp), leaves)
    assert list(order) == [1, 2, 3, 4, 5, 6, 0, 7]
    assert flops == 13.5 * (6 * 2 + 2 + 0)  # each leaf 1 neighbour, then 1, then none
    # a chain that passes the same places again and again, like a robot going round a room
    n = 400
    ei = list(range(n - 1))
    ej = list(range(1, n))
    for k in range(0, n - 50, 7):
        ei.append(k)
        ej.append(k + 40 + k % 11)
    ei, ej = np.array(ei, dtype=np.intp), np.array(ej, dtype=np.intp)
    order, _ = _graph.minimum_degree(n, ei, ej)
    assert sorted(order) == list(range(n))
    assert _fill(n, ei, ej, order) < 0.5 * _fill(n, ei, ej, np.arange(n))
    assert list(_graph.minimum_degree(n, ei, ej)[0]) == list(order)  # deterministic


@pytest.mark.parametrize("spread", [0.3, 40.0, 5000.0])
def test_first_in_cells_keeps_what_unique_keeps(spread):
    """The local map's thinning: the first point of each cell, in order, as np.unique of
    the packed cell keys gives it (negative cells and far ones too)."""
    pts = RNG.normal(0.0, spread, (3000, 2))
    pts[1000:1100] = pts[:100]  # repeats: their first copies win
    for cell in (0.025, 0.1):
        q = np.floor(pts / cell).astype(np.int64)
        _, first = np.unique((q[:, 0] << 32) ^ (q[:, 1] & 0xFFFFFFFF), return_index=True)
        np.testing.assert_array_equal(first_in_cells(pts, cell), np.sort(first))
    assert len(first_in_cells(np.zeros((0, 2)), 0.1)) == 0
