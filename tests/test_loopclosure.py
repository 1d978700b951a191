"""Pose graph, loop closure and the scan matcher's recovery from odometry glitches."""

from __future__ import annotations

import math

import numpy as np
import pytest

from dynslam_cli.geometry import compose, relative, transform_points
from dynslam_cli.localization.backend import BackEnd, Closure, LoopConfig
from dynslam_cli.localization.cornerslam import EkfConfig
from dynslam_cli.localization.ekf import NoiseModel
from dynslam_cli.localization.graph import PoseGraph, edge_errors
from dynslam_cli.localization.loopmatch import View, correlative_match, likelihood_field
from dynslam_cli.localization.scanmatch import MatchConfig, ScanMatcher, scan_points
from dynslam_cli.sections import IcpConfig
from dynslam_cli.simulate import ray_cast
from dynslam_cli.types import Pose2D, Scan

ANGLES = np.radians(np.arange(-90, 90.25, 0.5))
# A room with an alcove and a pillar: nothing symmetric, so a match has one answer.
ROOM = np.array([[-4, -3, 6, -3], [6, -3, 6, 4], [6, 4, 1, 4], [1, 4, 1, 5.5],
                 [1, 5.5, -1, 5.5], [-1, 5.5, -1, 4], [-1, 4, -4, 4], [-4, 4, -4, -3],
                 [2, 0, 2.6, 0], [2.6, 0, 2.6, 0.4], [2.6, 0.4, 2, 0.4], [2, 0.4, 2, 0]],
                float)


def scan_at(pose: Pose2D, odom: Pose2D, stamp: float = 0.0) -> Scan:
    r, _ = ray_cast(pose, ANGLES, ROOM, np.zeros(len(ROOM), int), np.zeros((0, 3)),
                    np.zeros(0, int), 20.0)
    return Scan(stamp, r, ANGLES, 20.0, odom)


def robot_points(pose: Pose2D) -> np.ndarray:
    return scan_points(scan_at(pose, pose), 20.0)


def test_edge_jacobians_match_numerical():
    rng = np.random.default_rng(3)
    poses = rng.normal(size=(2, 3))
    z = rng.normal(size=(1, 3))
    i, j = np.array([0]), np.array([1])
    _, a, b = edge_errors(poses, i, j, z)
    for node, analytic in ((0, a[0]), (1, b[0])):
        num = np.zeros((3, 3))
        for k in range(3):
            d = np.zeros((2, 3))
            d[node, k] = 1e-6
            e1, _, _ = edge_errors(poses + d, i, j, z)
            e0, _, _ = edge_errors(poses - d, i, j, z)
            diff = e1[0] - e0[0]
            diff[2] = math.remainder(diff[2], 2 * math.pi)
            num[:, k] = diff / 2e-6
        np.testing.assert_allclose(analytic, num, atol=1e-6)


def test_graph_spreads_a_loop_closure_over_the_chain():
    """A square driven with a biased turn: the chain does not close; the loop edge closes it
    and the corners come back to their true places."""
    truth = [Pose2D(0, 0, 0), Pose2D(4, 0, math.pi / 2), Pose2D(4, 4, math.pi),
             Pose2D(0, 4, -math.pi / 2), Pose2D(0, 0, 0)]
    g = PoseGraph()
    info = np.diag([100.0, 100.0, 400.0])
    est = truth[0]
    g.add_node(np.zeros(3))
    for k in range(1, 5):
        step = relative(truth[k - 1], truth[k])
        biased = Pose2D(step.x, step.y, step.theta + math.radians(4))  # odometry's bias
        est = compose(est, biased)
        g.add_node(np.array([est.x, est.y, est.theta]))
        g.add_edge(k - 1, k, np.array([biased.x, biased.y, biased.theta]), info)
    assert math.hypot(g.poses[4, 0], g.poses[4, 1]) > 0.5  # the open loop
    g.add_edge(0, 4, np.zeros(3), np.diag([1e4, 1e4, 1e5]), robust=True)
    g.optimize()
    assert math.hypot(g.poses[4, 0], g.poses[4, 1]) < 0.05
    assert abs(math.remainder(g.poses[4, 2], 2 * math.pi)) < math.radians(1)
    assert np.allclose(g.poses[0], 0.0)  # the first node holds the frame


def test_an_optimization_over_part_of_the_graph_moves_only_that_part():
    """Online, a closure moves only the nodes nearest to it through the graph (a long log's
    closure costs the same as an early one's); the rest hold, and the part that moves still
    takes up the closure's error."""
    g = PoseGraph()
    info = np.diag([100.0, 100.0, 400.0])
    g.add_node(np.zeros(3))
    for k in range(1, 40):  # a straight chain whose odometry says it bends
        g.add_node(g.poses[k - 1] + np.array([1.0, 0.0, 0.0]))
        g.add_edge(k - 1, k, np.array([1.0, 0.0, 0.0]), info)
    g.poses[20:, 1] += 0.5  # the later half has drifted sideways
    g.add_edge(19, 39, np.array([20.0, 0.0, 0.0]), np.diag([1e4, 1e4, 1e5]), robust=True)
    before = g.poses.copy()
    moving = np.arange(30, 40)
    e0 = edge_errors(g.poses, np.array([19]), np.array([39]), np.array([[20.0, 0, 0]]))[0]
    g.optimize(nodes=moving)
    e1 = edge_errors(g.poses, np.array([19]), np.array([39]), np.array([[20.0, 0, 0]]))[0]
    assert np.array_equal(g.poses[:30], before[:30])  # held where they were
    assert not np.allclose(g.poses[30:], before[30:])
    assert abs(e1[0, 1]) < 0.5 * abs(e0[0, 1])


def test_an_optimization_bounded_in_flops_moves_only_the_nearest_nodes(monkeypatch):
    """A place passed again and again, each pass tied to the ones before: the factor of
    the same number of nodes fills in more and more. An online optimization given its
    nodes nearest first and a bound on the factorization's multiplications moves only the
    nearest of them, and still takes up the closure's error; unbounded, it moves them all."""
    from dynslam_cli.localization import _graph, graph

    def passes() -> PoseGraph:
        g = PoseGraph()
        info = np.diag([100.0, 100.0, 400.0])
        g.add_node(np.zeros(3))
        for k in range(1, 120):  # a chain of 120 nodes, 0.2 m apart ...
            g.add_node(g.poses[k - 1] + np.array([0.2, 0.0, 0.0]))
            g.add_edge(k - 1, k, np.array([0.2, 0.0, 0.0]), info)
            if k >= 20:  # ... each also tied to the node 20 back, as passes are by closures
                g.add_edge(k - 20, k, np.array([0.2 * 20, 0.0, 0.0]), info, robust=True)
        g.poses[110:, 1] += 0.3  # the end of the last pass has drifted
        return g

    monkeypatch.setattr(graph, "MIN_MOVING_NODES", 5)
    nearest_first = np.arange(119, -1, -1)
    g = passes()
    i, j, _, _, _ = g.edges.arrays()
    _, all_flops = _graph.minimum_degree(120, i, j)
    before = g.poses.copy()
    e0 = edge_errors(g.poses, np.array([99]), np.array([119]), np.array([[4.0, 0, 0]]))[0]
    g.optimize(1, nodes=nearest_first, max_flops=all_flops / 8)
    e1 = edge_errors(g.poses, np.array([99]), np.array([119]), np.array([[4.0, 0, 0]]))[0]
    held = np.flatnonzero(np.all(g.poses == before, axis=1))
    assert len(held) > 10 and held.max() < 100  # the far ones held, the nearest moved
    assert abs(e1[0, 1]) < 0.5 * abs(e0[0, 1])
    unbounded = passes()
    unbounded.optimize(1, nodes=nearest_first)
    assert not np.any(np.all(unbounded.poses[1:] == before[1:], axis=1))


def test_a_large_graph_is_solved_by_conjugate_gradients_to_the_same_poses(monkeypatch):
    """Above DIRECT_MAX_NODES the steps come from conjugate gradients: the same optimum."""
    from dynslam_cli.localization import graph

    def drifted_loop() -> PoseGraph:
        g = PoseGraph()
        info = np.diag([100.0, 100.0, 400.0])
        g.add_node(np.zeros(3))
        for k in range(1, 60):  # a circle of 60 steps driven with a biased turn
            z = np.array([1.0, 0.0, 2 * math.pi / 60 + math.radians(0.5)])
            p = g.poses[k - 1]
            g.add_node(p + np.array([math.cos(p[2]), math.sin(p[2]), z[2]]))
            g.add_edge(k - 1, k, z, info)
        g.add_edge(0, 59, np.array([0.0, -1.0, -2 * math.pi / 60]), np.eye(3) * 1e3, robust=True)
        return g

    direct = drifted_loop()
    direct.optimize()
    monkeypatch.setattr(graph, "DIRECT_MAX_NODES", 10)
    iterative = drifted_loop()
    iterative.optimize()
    assert np.abs(direct.poses - iterative.poses).max() < 1e-6
    assert not np.allclose(direct.poses, drifted_loop().poses)  # (it did move)


def test_graph_distance_stops_at_the_nearest_nodes():
    """The window of an online optimization: the nodes nearest to the closure's two ends,
    and no more than asked for; and a search for given nodes stops once it has them."""
    closer = BackEnd(LoopConfig(min_travel_m=1e9), EkfConfig().noise)
    for x in np.arange(0.0, 20.01, 0.5):
        closer.add_node(Pose2D(x, 0.0, 0.0), robot_points(Pose2D()))
    d = closer.graph.distances([0, 40], max_nodes=6)
    assert sorted(np.flatnonzero(np.isfinite(d))) == [0, 1, 2, 38, 39, 40]
    d = closer.graph.distances([40], targets=np.array([37]))  # stops once it has 37
    assert d[37] == pytest.approx(1.5) and np.isinf(d[:30]).all()
    assert closer.graph_distance(40, targets=np.array([0]))[0] == pytest.approx(20.0)


def test_correlative_match_finds_a_large_offset():
    """The place seen again 1.2 m and 9° away from where the drifted estimate says."""
    old = Pose2D(0.0, 0.0, 0.0)
    new = Pose2D(0.5, 0.3, math.radians(20))
    field = likelihood_field(robot_points(old))
    true = relative(old, new)
    guess = Pose2D(true.x + 1.0, true.y - 0.7, true.theta + math.radians(9))
    m = correlative_match(field, robot_points(new), guess, 1.5, 12.0)
    assert m.score > 0.8
    assert math.hypot(m.pose.x - true.x, m.pose.y - true.y) < 0.08
    assert abs(m.pose.theta - true.theta) < math.radians(1.0)
    assert np.sqrt(np.diag(m.cov))[:2].max() < 0.2  # one clear answer


def test_match_in_a_corridor_is_ambiguous_along_it_and_stays_at_the_guess():
    corridor = np.array([[-20, -1, 20, -1], [-20, 1, 20, 1]], float)
    r, _ = ray_cast(Pose2D(), ANGLES, corridor, np.zeros(2, int), np.zeros((0, 3)),
                    np.zeros(0, int), 20.0)
    scan = Scan(0.0, r, ANGLES, 20.0, Pose2D())
    field = likelihood_field(scan_points(scan, 20.0))  # the corridor seen before ...
    near = scan_points(scan, 6.0)  # ... and now only its near part: it fits anywhere along
    m = correlative_match(field, near, Pose2D(0.6, 0.1, 0.0), 2.0, 10.0)
    sx, sy, _ = np.sqrt(np.diag(m.cov))
    assert sx > 0.8 and sy < 0.2  # along: anything goes; across: pinned
    assert m.pose.x == pytest.approx(0.6, abs=0.5)  # no sliding off to the window edge (2 m)
    assert m.pose.y == pytest.approx(0.0, abs=0.06)


def test_a_corridor_closure_ties_across_the_corridor_and_never_along_it():
    """[loop] corridor_closures: a corridor's match (equally good offsets out to the
    window's edge along it) enters with no information along the corridor, firm across it
    and in heading; off, it is not matched at all."""
    corridor = np.array([[-20, -1, 20, -1], [-20, 1, 20, 1]], float)
    r, _ = ray_cast(Pose2D(), ANGLES, corridor, np.zeros(2, int), np.zeros((0, 3)),
                    np.zeros(0, int), 20.0)
    scan = Scan(0.0, r, ANGLES, 20.0, Pose2D())
    field = likelihood_field(scan_points(scan, 20.0))
    near = scan_points(scan, 6.0)
    guess = Pose2D(0.6, 0.1, 0.02)
    off = BackEnd(LoopConfig(), NoiseModel())
    assert off._match(lambda: field, near, guess, 2.0, 10.0) is None
    on = BackEnd(LoopConfig(corridor_closures=True), NoiseModel())
    pose, info, _ = on._match(lambda: field, near, guess, 2.0, 10.0)
    assert pose.y == pytest.approx(0.0, abs=0.03) and pose.theta == pytest.approx(0, abs=0.01)
    along, across = np.array([1.0, 0, 0]), np.array([0, 1.0, 0])
    assert along @ info @ along < 1.0 / 10.0 ** 2  # (along the match's own axis: none)
    assert across @ info @ across > 1.0 / 0.2 ** 2 and info[2, 2] > 1.0 / math.radians(5) ** 2


def test_corridor_axis_walls_frees_along_the_corridor_even_where_a_niche_pins_it():
    """[loop] corridor_axis = "walls": a corridor match whose search a door niche pinned
    along the corridor ("ambiguity" keeps that) enters with no information along it, as
    firm across it and in heading as before."""
    walls = np.array([[-20, -1, 20, -1], [-20, 1, 2, 1], [2, 1, 2, 1.4], [2, 1.4, 3, 1.4],
                      [3, 1.4, 3, 1], [3, 1, 20, 1]], float)

    def points_within(reach: float) -> np.ndarray:
        r, _ = ray_cast(Pose2D(), ANGLES, walls, np.zeros(len(walls), int), np.zeros((0, 3)),
                        np.zeros(0, int), 20.0)
        return scan_points(Scan(0.0, r, ANGLES, 20.0, Pose2D()), reach)

    field = likelihood_field(points_within(20.0))
    near, guess = points_within(6.0), Pose2D(0.3, 0.1, 0.02)
    along, across = np.array([1.0, 0, 0]), np.array([0, 1.0, 0])
    infos = {}
    for axis in ("ambiguity", "walls"):
        closer = BackEnd(LoopConfig(corridor_closures=True, corridor_axis=axis), NoiseModel())
        pose, infos[axis], _ = closer._match(lambda: field, near, guess, 2.0, 10.0)
        assert abs(pose.x) < 0.05 and abs(pose.y) < 0.03  # (the niche found either way)
    assert along @ infos["ambiguity"] @ along > 1.0 / 0.3 ** 2  # (the niche pins it)
    assert along @ infos["walls"] @ along < 1.0 / 10.0 ** 2  # (σ over 10 m: none)
    for k in (1, 2):
        assert infos["walls"][k, k] == pytest.approx(infos["ambiguity"][k, k], rel=0.01)
    assert across @ infos["walls"] @ across > 1.0 / 0.2 ** 2


def test_a_wall_the_old_submap_never_saw_does_not_slide_the_match():
    """A corridor's end wall, seen now by a robot facing it and never by the old scans
    (they faced away): scored everywhere, the points beside it slide the match 1 m along
    the corridor to overlap the old submap; scored only where the old scans looked
    ([loop] seen_only), the match stays within a coarse step of the truth."""
    walls = np.array([[-3, -1, 30, -1], [-3, 1, 30, 1], [-3, -1, -3, 1]], float)

    def points_at(pose: Pose2D) -> np.ndarray:
        r, _ = ray_cast(pose, ANGLES, walls, np.zeros(3, int), np.zeros((0, 3)),
                        np.zeros(0, int), 8.0)
        return scan_points(Scan(0.0, r, ANGLES, 8.0, pose), 8.0)

    old = [Pose2D(x, 0.0, 0.0) for x in np.arange(0.0, 4.01, 0.5)]  # facing away
    views = [View(np.array([p.x, p.y]), transform_points(p, points_at(p))) for p in old]
    submap = np.vstack([v.points for v in views])
    new = Pose2D(1.0, 0.05, math.pi)  # facing the end wall, 4 m ahead
    slid = correlative_match(likelihood_field(submap), points_at(new), new, 2.0, 10.0)
    held = correlative_match(likelihood_field(submap, views), points_at(new), new, 2.0, 10.0)
    assert slid.pose.x - new.x > 0.8
    assert abs(held.pose.x - new.x) <= 0.15 and abs(held.pose.y - new.y) < 0.05
    assert held.censored  # (and along the corridor it could be anywhere)


@pytest.mark.parametrize("submap_nodes", [4, 8])
def test_loop_closer_closes_a_revisit(submap_nodes):
    """Drive out and back while the estimate's heading drifts 0.4° a step: the return is tied
    to the places seen on the way out, however large the submaps (the old node's submap holds
    none of the stretch just driven: at 8 nodes each side it reached it and closed less)."""
    closer = BackEnd(LoopConfig(min_travel_m=3.0, submap_nodes=submap_nodes),
                        EkfConfig().noise)
    path = [Pose2D(x, 0.0, 0.0) for x in np.arange(0.0, 3.01, 0.5)]
    path += [Pose2D(x, 0.5, 0.0) for x in np.arange(3.0, -0.01, -0.5)]
    front = path[0]
    closures = []
    for k, p in enumerate(path):
        if k:
            step = relative(path[k - 1], p)
            front = compose(front, Pose2D(step.x, step.y, step.theta + math.radians(0.4)))
        closures.append(closer.add_node(front, robot_points(p)))
    closer.finish()
    assert closer.closures >= 1 and closures.index(True) >= 8  # only on the way back

    def worst(poses: list[Pose2D]) -> float:
        return max(math.hypot(e.x, e.y) for e in (
            relative(relative(poses[0], q), relative(path[0], t)) for q, t in zip(
                poses, path, strict=True)))

    open_loop = worst(closer.local_poses)
    closed = worst([closer.pose(k) for k in range(len(path))])
    assert open_loop > 0.12
    assert closed < 0.5 * open_loop


def test_matcher_recovers_from_a_doubled_turn():
    """Odometry reports twice the real turn (real logs do this in fast turns): ICP's match
    from the odometry's guess fails, a turned guess finds the true motion."""
    matcher = ScanMatcher(MatchConfig(method="icp"), NoiseModel())
    matcher.increment(scan_at(Pose2D(), Pose2D()))
    true = Pose2D(0.05, 0.0, math.radians(-22))
    reported = Pose2D(0.05, 0.0, math.radians(-46))
    inc, source, _ = matcher.increment(scan_at(true, reported, 0.2))
    assert source == "recovered"
    assert abs(inc.theta - true.theta) < math.radians(0.5)


def corridor_points(length: float = 40.0) -> np.ndarray:
    corridor = np.array([[-length / 2, -1, length / 2, -1], [-length / 2, 1, length / 2, 1]])
    r, _ = ray_cast(Pose2D(), ANGLES, corridor, np.zeros(2, int), np.zeros((0, 3)),
                    np.zeros(0, int), 20.0)
    return scan_points(Scan(0.0, r, ANGLES, 20.0, Pose2D()), 20.0)


def test_match_information_in_a_corridor_is_degenerate_along_it():
    """The walls pin the pose across the corridor and in heading, not along it: there the
    fused covariance is the odometry prior's."""
    from dynslam_cli.localization._match import PointIndex
    from dynslam_cli.localization.scanmatch import fused_covariance, icp

    pts = corridor_points()
    ref = PointIndex(pts)
    match = icp(ref, pts, Pose2D(0.3, 0.05, 0.01), IcpConfig(),
                (0.2, 0.2, 0.1))
    info = match.information
    assert info[0, 0] < 0.01 * info[1, 1]  # along: next to nothing; across: a lot
    assert info[2, 2] > 0
    cov = fused_covariance(info, (0.2, 0.2, 0.1))
    assert math.sqrt(cov[0, 0]) > 10 * math.sqrt(cov[1, 1])
    assert math.sqrt(cov[1, 1]) < 0.01
    assert abs(match.pose.y) < 0.01  # pinned across

    room = PointIndex(robot_points(Pose2D()))  # a room pins every direction
    m = icp(room, robot_points(Pose2D(0.1, 0.0, 0.0)), Pose2D(),
            IcpConfig(), (0.2, 0.2, 0.1))
    assert np.linalg.eigvalsh(m.information[:2, :2]).min() > 1e3


def test_a_false_loop_closure_waits_and_never_enters_alone():
    """A closure that would bend the graph is held; it enters only with a second closure
    that tells the same story. A lone false one never does, a pair of true ones do."""
    closer = BackEnd(LoopConfig(min_travel_m=1e9), EkfConfig().noise)
    for x in np.arange(0.0, 20.01, 0.5):  # a straight run, nodes every 0.5 m
        closer.add_node(Pose2D(x, 0.0, 0.0), robot_points(Pose2D()))
    info = np.diag([400.0, 400.0, 3000.0])

    def closure(old: int, new: int, shift: float) -> Closure:
        z = relative(closer.pose(old), closer.pose(new))
        z = Pose2D(z.x + shift, z.y, z.theta)
        return Closure(old, new, z, info, closer._chi2(old, new, z, info))

    false = closure(2, 30, 1.5)  # "node 30 is 1.5 m farther from node 2 than the graph says"
    assert closer.accept(false) == []
    assert closer.accept(closure(3, 32, -0.8)) == []  # another, disagreeing with the first
    agreeing = closure(4, 34, 0.0)  # the graph already agrees: in at once
    assert closer.accept(agreeing) == [agreeing]
    first, second = closure(5, 33, 0.6), closure(8, 39, 0.6)  # true drift, seen twice
    assert closer.accept(first) == []
    assert closer.accept(second) == [first, second]


def test_two_closures_from_nearly_the_same_place_do_not_vouch_for_each_other():
    """Matches made a step apart see the same view and share its aliasing (a corridor's
    doors matched one door off): they agree with each other, and still wait until a match
    from farther along (``pair_min_separation_m``) tells the same story."""
    closer = BackEnd(LoopConfig(min_travel_m=1e9), EkfConfig().noise)
    for x in np.arange(0.0, 20.01, 0.5):
        closer.add_node(Pose2D(x, 0.0, 0.0), robot_points(Pose2D()))
    info = np.diag([400.0, 400.0, 3000.0])

    def closure(old: int, new: int) -> Closure:
        z = relative(closer.pose(old), closer.pose(new))
        z = Pose2D(z.x + 1.2, z.y, z.theta)  # one door spacing off, or a true drift
        return Closure(old, new, z, info, closer._chi2(old, new, z, info))

    a, b, c = closure(2, 30), closure(3, 31), closure(9, 37)  # 0.5 m, then 3.5 m on
    assert closer.accept(a) == []
    assert closer.accept(b) == []  # agrees with a, but from the same place
    assert closer.accept(c) == [b, c]  # from far enough along: the story holds


def test_graph_distance_follows_the_chain_and_takes_loop_shortcuts():
    """The search window grows with the driving between two nodes through the graph, so a
    place tied by a loop closure is near again however long ago it was first seen."""
    closer = BackEnd(LoopConfig(min_travel_m=1e9, max_search_radius_m=100.0),
                        EkfConfig().noise)
    for x in np.arange(0.0, 20.01, 0.5):
        closer.add_node(Pose2D(x, 0.0, 0.0), robot_points(Pose2D()))
    d = closer.graph_distance(40)
    assert d[0] == pytest.approx(20.0, abs=1e-3) and d[20] == pytest.approx(10.0, abs=1e-3)
    closer.add_closures([Closure(0, 40, Pose2D(20.0, 0.0, 0.0), np.eye(3), 0.0)])
    d = closer.graph_distance(40)
    assert d[0] < 0.01 and d[10] == pytest.approx(5.0, abs=0.01)  # round the loop
    assert closer.radius(d[0]) < closer.radius(20.0)


def test_a_match_keeps_none_of_the_odometrys_error():
    """Matched from guesses off by up to 0.3 m and 4° (harsh wheel odometry), the scan comes
    out where it was taken: the match converges instead of stopping part way and keeping a
    share of the guess's error."""
    from dynslam_cli.localization._match import PointIndex
    from dynslam_cli.localization.scanmatch import icp

    ref = PointIndex(robot_points(Pose2D()))
    true = Pose2D(0.4, -0.2, math.radians(3.0))
    pts = robot_points(true)
    for dx, dy, dth in ((0.3, 0.0, 4.0), (-0.2, 0.25, -4.0), (0.0, -0.3, 2.5)):
        guess = Pose2D(true.x + dx, true.y + dy, true.theta + math.radians(dth))
        m = icp(ref, pts, guess, IcpConfig(), (0.3, 0.3, math.radians(5)))
        assert m.share > 0.9
        assert math.hypot(m.pose.x - true.x, m.pose.y - true.y) < 0.005
        assert abs(math.degrees(m.pose.theta - true.theta)) < 0.05


def test_matched_chain_edges_are_loose_where_the_matches_could_not_see():
    """chain_information = "matched": the edge between two nodes is as sure as the scan
    matches between them were: along a corridor (the matches' long axis, x) far less sure
    than across it; with the motion model ("motion", the default) as sure both ways."""
    corridor = np.diag([0.05 ** 2, 0.002 ** 2, math.radians(0.1) ** 2])  # per scan
    scan = Scan(0.0, np.full(len(ANGLES), 5.0), ANGLES, 20.0, Pose2D())
    infos = {}
    for mode in ("motion", "matched"):
        closer = BackEnd(LoopConfig(min_travel_m=1e9, chain_information=mode),
                            EkfConfig().noise)
        step = Pose2D(0.1, 0.0, 0.0)
        for k in range(6):  # 0.5 m: a node at the first scan and one at the last
            closer.place(Pose2D(0.1 * k, 0.0, 0.0), scan, (step, corridor) if k else None)
        _, _, _, info, _ = closer.graph.edges.arrays()
        assert len(info) == 1
        infos[mode] = info[0]
    motion, matched = infos["motion"], infos["matched"]
    assert motion[0, 0] == pytest.approx(motion[1, 1])
    assert matched[1, 1] > 100 * matched[0, 0]
    # five matches, each 5 cm along: the edge's standard deviation along is about 11 cm
    assert 1.0 / math.sqrt(matched[0, 0]) == pytest.approx(1.5 * 0.05 * math.sqrt(5), rel=0.05)


def test_a_place_revisited_for_hours_does_not_grow_the_graph(cli, tmp_path):
    """The arena driven round and round: with ``[loop] revisit`` the robot, back on nodes
    a closure has tied to the graph, is placed on them instead of making new ones, so the
    graph after 300 s holds about as many nodes as after 150 s (without it: twice as
    many), and the trajectory stays within a centimetre of the truth."""
    import json

    r = cli("simulate", "arena", "-o", tmp_path / "sim", "--duration", "300", "--seed", "0")
    assert r.exit_code == 0, r.output
    log, truth = tmp_path / "sim" / "arena.log", tmp_path / "sim" / "truth.json"
    config = tmp_path / "revisit.toml"
    config.write_text("[loop]\nrevisit = true\n")
    nodes = {}
    for name, extra in (("plain", ()), ("revisit", ("--config", config))):
        for end in (150, 300):
            out = tmp_path / f"{name}-{end}"
            assert cli("process", log, "-o", out, "-q", "--end", end, *extra).exit_code == 0
            counts = json.loads((out / "summary.json").read_text())["localization"]
            nodes[name, end] = counts["graph_nodes"]
        r = cli("evaluate", out, "--truth", truth, "--json")
        assert json.loads(r.stdout)["truth"]["trajectory"]["ate_rmse_m"] < 0.01, name
    assert counts["revisits"] > nodes["revisit", 300]  # most placements are revisits
    assert nodes["plain", 300] > 1.8 * nodes["plain", 150]
    assert nodes["revisit", 300] < 1.1 * nodes["revisit", 150]


def test_a_loop_drifted_past_the_old_fixed_radius_is_found():
    """After 160 m driven between two nodes the graph may have them metres apart: the
    window grows with that drift (``search_radius_m`` plus ``drift_per_m`` of the graph
    distance) past the 6 m it was once held to, and the place 8.6 m and 15° from where
    the graph has it is found; a window held to 6 m does not reach it."""
    old, new = Pose2D(0.0, 0.0, 0.0), Pose2D(0.5, 0.3, math.radians(20))
    field = likelihood_field(robot_points(old))
    true = relative(old, new)
    guess = Pose2D(true.x + 7.0, true.y - 5.0, true.theta + math.radians(15))
    wide = BackEnd(LoopConfig(), NoiseModel())
    held = BackEnd(LoopConfig(max_search_radius_m=6.0), NoiseModel())
    assert float(held.radius(160.0)) == 6.0 and float(wide.radius(160.0)) > 8.0
    found = wide._match(lambda: field, robot_points(new), guess, float(wide.radius(160.0)),
                        20.0)
    assert found is not None
    pose, _, _ = found
    assert math.hypot(pose.x - true.x, pose.y - true.y) < 0.05
    assert abs(pose.theta - true.theta) < math.radians(0.5)
    missed = held._match(lambda: field, robot_points(new), guess, 6.0, 20.0)
    assert missed is None or math.hypot(missed[0].x - true.x, missed[0].y - true.y) > 1.0


@pytest.mark.parametrize("window_m", [7.5, 12.0])
def test_a_wide_window_searched_block_by_block_finds_what_every_cell_would(monkeypatch,
                                                                          window_m):
    """Branch and bound over blocks of coarse cells (wide windows) gives the very match,
    score and ambiguity of the coarse pass over every cell."""
    old, new = Pose2D(0.0, 0.0, 0.0), Pose2D(0.5, 0.3, math.radians(20))
    field = likelihood_field(robot_points(old))
    true = relative(old, new)
    for dx, dy, dth in ((6.0, -5.0, 15.0), (-2.0, 1.0, -4.0), (0.3, 0.2, 1.0)):
        guess = Pose2D(true.x + dx, true.y + dy, true.theta + math.radians(dth))
        blocks = correlative_match(field, robot_points(new), guess, window_m, 20.0)
        with monkeypatch.context() as m:
            m.setattr("dynslam_cli.localization.loopmatch.BLOCK_MIN_CELLS", 10 ** 6)
            every = correlative_match(field, robot_points(new), guess, window_m, 20.0)
        assert blocks.pose == every.pose and blocks.score == every.score
        assert np.array_equal(blocks.cov, every.cov) and blocks.censored == every.censored


def test_look_alike_corridors_close_their_loops_and_no_false_one(tmp_path):
    """The wards world: a ring of corridors with a door every 4 m, so each stretch looks
    like the next and like the other side turned round. Driven 1.5 laps (150 m) on a
    drifting odometry (2.7 m off), with the 30 m search window: no closure ties two places
    a door apart or the ring's two sides (every one within 2 m, half a door's spacing, of
    the true poses; 51 of 52 within 0.1 m and 1°: one slid 0.83 m along the short
    corridor, whose plain walls say nothing along it, keeping the graph's guess there),
    and the trajectory stays within 3 cm of the truth."""
    import json

    from dynslam_cli.config import Config
    from dynslam_cli.evaluate import MapThresholds, score_closures, score_run
    from dynslam_cli.pipeline import run
    from dynslam_cli.simulate import LaserModel, build_world, simulate
    from dynslam_formats import ReaderOptions, open_log
    from dynslam_formats.simlogs import write_carmen

    steps, truth_obj = simulate(build_world("wards"), 190, 10.0, 0)
    log = tmp_path / "wards.log"
    with open(log, "w") as f:
        write_carmen(f, steps, LaserModel(), "flaser", "wards")
    source, _, reader = open_log(str(log), ReaderOptions())
    result = run(reader.scans(), Config())
    source.close()
    truth = json.loads(json.dumps({
        "walls": truth_obj.walls, "static_corners": truth_obj.corners, "poses": truth_obj.poses,
        "odometry": truth_obj.odometry, "objects": truth_obj.objects,
        "events": truth_obj.events, "hits": truth_obj.hits}))
    closures = score_closures(result.closures, result.trajectory, truth)
    assert closures["reported"] >= 20 and closures["error_m_max"] < 2.0
    assert closures["right"] >= 0.95 * closures["reported"]
    scores = score_run(result.static, result.dynamic, result.trajectory, [], truth,
                       MapThresholds(0.1, 0.9))
    assert scores["trajectory"]["odometry_ate_rmse_m"] > 0.5
    assert scores["trajectory"]["ate_rmse_m"] < 0.03
