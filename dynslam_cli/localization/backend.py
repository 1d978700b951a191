"""The back end: the pose graph of the run, its loop closures, and each scan's place in it.

Loop closure recognises a place seen long ago and ties the two poses together.

The EKF (Sec. 4) keeps only the landmarks of the last stretch of the run; what drift it
leaves over a long loop is removed here, the way graph-based SLAM does it. Every key scan
becomes a node of a :class:`~dynslam_cli.localization.graph.PoseGraph`, chained to the
previous one by the EKF's relative motion. When the robot is near a node it left a long way
back (near by the current estimate, within a radius that grows with the driving between
the two nodes through the graph, where a loop already closed is a shortcut), the scans
around the new node are matched against those around the old one:

1. **correlative search** over a window of translations and rotations on a likelihood field
   of the old scans (:mod:`~dynslam_cli.localization.loopmatch`);
2. **ICP refinement** (point-to-line); the edge's information comes from the search's
   ambiguity (the spread of the poses that could score as well), so a match along a
   featureless corridor constrains only the directions it can see;
3. **consistency**: a match the graph already agrees with is added; one that would move
   the graph waits for a second match, made a few metres on, that tells the same story
   (the loop of the two matches and the path between them closes), so a single false
   match never enters;
4. an accepted match becomes an edge with a Cauchy kernel (a wrong one is pulled on only
   softly), and the graph is optimized.
"""

from __future__ import annotations

import bisect
import math
from array import array
from collections import OrderedDict, deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from dynslam_cli.geometry import (
    compose,
    compound_covariance,
    inverse,
    moved_far,
    relative,
    rotated_covariance,
    transform_points,
    wrap_angles,
)
from dynslam_cli.localization.ekf import motion_std
from dynslam_cli.localization.globalsearch import BlurredMap
from dynslam_cli.localization.graph import PoseGraph, edge_errors
from dynslam_cli.localization.loopmatch import (
    ANGLE_STEP_DEG,
    FIELD_RES_M,
    LikelihoodField,
    View,
    constraint_ratio,
    correlative_match,
    likelihood_field,
    weakest_axis,
)
from dynslam_cli.localization.scanmatch import (
    icp,
    pose_difference,
    scan_points,
    sigma_covariance,
)
from dynslam_cli.sections import LoopConfig, NoiseModel
from dynslam_cli.types import Pose2D, Scan

CANDIDATE_BATCH = 8  # loop candidates whose graph distance is found first (_candidate)
# Added to a chain edge's covariance: a millimetre and 0.01° (no edge infinitely sure).
CHAIN_FLOOR = np.diag([1e-6, 1e-6, math.radians(0.01) ** 2])
ONLINE_ITERATIONS = 1  # Gauss-Newton steps per optimization while the log runs
FINAL_ITERATIONS = 10


def without_direction(info: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """An edge's information (x, y, θ) with none along the translation ``axis`` (a unit
    2-vector): an error along it costs nothing, as a match along a corridor says nothing
    of where along it the robot is."""
    u = np.array([axis[0], axis[1], 0.0])
    keep = np.eye(3) - np.outer(u, u)
    return keep @ info @ keep


class PriorWalls(NamedTuple):
    """An earlier session's map, to keep a run in its frame (``--prior``): the centres of
    its Occupied cells (N×2) and the map blurred, to make a match finer than a cell on."""

    points: np.ndarray
    blurred: BlurredMap


class Anchor(NamedTuple):
    """Where a revisit placed the robot (``[loop] revisit``): at the EKF's pose ``local``,
    node ``node`` saw it at ``seen`` (the match)."""

    node: int
    seen: Pose2D
    local: Pose2D


@dataclass(frozen=True)
class Closure:
    """A loop-closure match: node ``new`` seen from node ``old`` at ``z``, its information,
    and its χ² against the graph when it was made."""

    old: int
    new: int
    z: Pose2D
    info: np.ndarray
    chi2: float


class BackEnd:
    """The pose graph, its nodes (the EKF's pose and the scan points at each), the scans'
    offsets to their nodes and the loop closures: :meth:`place` takes a scan at the EKF's
    pose and gives its pose in the map frame."""

    def __init__(self, cfg: LoopConfig, motion_noise: NoiseModel,
                 prior: PriorWalls | None = None) -> None:
        """``prior``: an earlier session's walls (its frame is the map frame; the first
        node's pose is in it), matched like an old node's submap."""
        self.cfg = cfg
        self.motion_noise = motion_noise  # the EKF's: of its motion between two nodes
        self.graph = PoseGraph()
        self.local_poses: list[Pose2D] = []  # the EKF's pose at each node
        self.points: list[np.ndarray] = []  # each node's scan points, robot frame
        self.path: list[float] = []  # distance driven up to each node
        self.closures = 0
        self.attempts = 0
        self._last_attempt_m = -math.inf
        self._fields: OrderedDict[tuple[int, int], LikelihoodField] = OrderedDict()
        self._pending: deque[Closure] = deque(maxlen=cfg.pending_closures)
        self._chain = (Pose2D(), np.zeros((3, 3)), 0)  # since the last node: motion, its
        # covariance, scans (chain_information = "matched")
        self._prior = prior
        self._prior_field = (likelihood_field(prior.points)
                             if prior is not None and len(prior.points) else None)
        self._last_prior_m = -math.inf
        self.prior_matches = 0
        self._scan_nodes = array("i")  # per scan placed: its node ...
        self._scan_offsets = array("d")  # ... and its pose in that node's frame
        self._node_scans = array("i")  # per node: the number of the scan it was made at
        self._anchor: Anchor | None = None  # where the robot is placed on an old node ...
        self._anchors: list[Anchor] = []  # ... and where it was (revisit)
        self._scan_anchors = array("i")  # per scan placed: its anchor (-1: none; revisit)
        self._tied = array("b")  # per node: an end of a loop closure (revisit)
        self._anchor_cov = np.zeros((3, 3))  # the robot's pose where placed (map frame)
        self.revisits = 0

    def wants_node(self, local_pose: Pose2D) -> bool:
        """Whether the robot has moved far enough from the last node (or where a revisit
        last placed it) for a new one."""
        if not self.local_poses:
            return True
        since = self.local_poses[-1] if self._anchor is None else self._anchor.local
        return moved_far(since, local_pose, self.cfg.node_distance_m,
                         math.radians(self.cfg.node_angle_deg))

    def add_node(self, local_pose: Pose2D, points: np.ndarray) -> bool:
        """A new node at the EKF's pose, chained to the previous node; then a loop closure
        attempt. Returns True if the graph was optimized (the map frame moved). After a
        revisit (:meth:`revisit`) the chain goes on from the node that placed the robot."""
        graph = self.graph
        self._node_scans.append(len(self._scan_nodes))
        if not self.local_poses:
            graph.add_node(np.array([local_pose.x, local_pose.y, local_pose.theta]))
            self._append(local_pose, points, 0.0)
            return False
        anchor, self._anchor = self._anchor, None
        if anchor is None:
            k_prev = len(self.local_poses) - 1
            z = relative(self.local_poses[-1], local_pose)
        else:
            k_prev, z = anchor.node, compose(anchor.seen, relative(anchor.local, local_pose))
        est = compose(self.pose(k_prev), z)
        k = graph.add_node(np.array([est.x, est.y, est.theta]))
        graph.add_edge(k_prev, k, np.array([z.x, z.y, z.theta]), self._chain_information(z))
        self._append(local_pose, points, self.path[-1] + math.hypot(z.x, z.y))
        moved = self._try_closure(k)
        return self._try_prior(k) or moved

    def _chain_information(self, z: Pose2D) -> np.ndarray:
        """The information of the edge of motion ``z`` from the last node to a new one
        (``chain_information``; the model's where no scan since the last node came with
        its motion), divided by ``chain_noise_scale``²; the chain starts anew."""
        _, cov, scans = self._chain
        self._chain = (Pose2D(), np.zeros((3, 3)), 0)
        scale = self.cfg.chain_noise_scale ** 2
        if self.cfg.chain_information == "matched" and scans:
            return np.linalg.inv(cov * scale + CHAIN_FLOOR)
        st, sr = motion_std(z.x, z.y, z.theta, self.motion_noise)
        return np.diag(1.0 / (np.array([st * st, st * st, sr * sr]) * scale))

    def pose(self, k: int) -> Pose2D:
        x = self.graph.poses[k]
        return Pose2D(float(x[0]), float(x[1]), float(x[2]))

    def _append(self, local_pose: Pose2D, points: np.ndarray, path: float) -> None:
        if self.cfg.revisit:
            self._tied.append(0)
        self.local_poses.append(local_pose)
        self.points.append(points)
        self.path.append(path)

    def graph_distance(self, k: int, targets: np.ndarray | None = None) -> np.ndarray:
        """How far each node is from node k through the graph: the shortest path along the
        chain (metres driven) where loop closures are shortcuts of ~0 length. The drift
        between two nodes grows with it, not with the time between them: a place the robot
        closed a loop to a minute ago is near however long ago it was first seen. Nodes
        farther than where the search window stops growing get ∞ (so the search visits only
        the graph near node k); with ``targets``, only their distances are sure (the search
        stops once it has them)."""
        cfg = self.cfg
        limit = (cfg.max_search_radius_m - cfg.search_radius_m) / max(cfg.drift_per_m, 1e-9)
        return self.graph.distances([k], limit, targets=targets)

    def _candidate(self, k: int, old: int) -> tuple[int, float] | None:
        """The old node to match node k against and how far it is through the graph; None if
        there is none. Candidates are the nodes before ``old`` (``min_travel_m`` or more back
        along the path) within their search radius (it grows with the graph distance) of
        node k's estimate; the nearest is taken. The graph distances of the CANDIDATE_BATCH
        nearest are found first, the others only if none of those is inside its radius:
        where a place was revisited for hours, a search for all of them would visit most of
        the graph."""
        cfg = self.cfg
        if old == 0:
            return None
        xy = self.graph.poses[:old, :2]
        d = np.hypot(xy[:, 0] - self.graph.poses[k, 0], xy[:, 1] - self.graph.poses[k, 1])
        near = np.flatnonzero(d <= cfg.max_search_radius_m)
        near = near[np.argsort(d[near], kind="stable")]  # nearest first
        for batch in (near[:CANDIDATE_BATCH], near[CANDIDATE_BATCH:]):
            if len(batch):
                g = self.graph_distance(k, targets=batch)[batch]
                inside = np.flatnonzero(d[batch] <= self.radius(g))
                if len(inside):
                    return int(batch[inside[0]]), float(g[inside[0]])
        return None

    def radius(self, graph_m: np.ndarray | float) -> np.ndarray:
        """Search radius (m) for a node this far through the graph."""
        cfg = self.cfg
        return np.minimum(cfg.search_radius_m + cfg.drift_per_m * np.asarray(graph_m),
                          cfg.max_search_radius_m)

    def _try_closure(self, k: int) -> bool:
        cfg = self.cfg
        if self.path[k] - self._last_attempt_m < cfg.attempt_every_m:
            return False
        old = bisect.bisect_right(self.path, self.path[k] - cfg.min_travel_m)  # (nodes
        # before it lie min_travel_m or more back along the path)
        found = self._candidate(k, old)
        if found is None:
            return False
        self._last_attempt_m = self.path[k]
        self.attempts += 1
        i, graph_m = found
        radius = float(self.radius(graph_m))
        window_deg = min(cfg.search_angle_deg + graph_m / 10.0, cfg.max_search_angle_deg)
        found = self._match(lambda: self._field(i, old), self._query(k),
                            relative(self.pose(i), self.pose(k)), radius, window_deg)
        if found is None:
            return False
        pose, info, _ = found
        return self._close(Closure(i, k, pose, info, self._chi2(i, k, pose, info)), k)

    def _try_prior(self, k: int) -> bool:
        """Node k's scans matched against the prior map (``prior``) near where the
        graph has it, every ``prior_every_m``: a closure to the first node (held where
        the prior placed it), so the run stays in the prior's frame; accepted as any other."""
        cfg, prior, field = self.cfg, self._prior, self._prior_field
        if (prior is None or field is None
                or self.path[k] - self._last_prior_m < cfg.prior_every_m):
            return False
        self._last_prior_m = self.path[k]
        found = self._match(lambda: field, self._query(k), self.pose(k), cfg.search_radius_m,
                            cfg.search_angle_deg)
        if found is None:
            return False
        self.prior_matches += 1
        pose, info, query = found  # ICP on the cells' centres, made finer on the blur:
        pose = prior.blurred.refine(query, pose, FIELD_RES_M, math.radians(ANGLE_STEP_DEG))
        z = relative(self.pose(0), pose)
        return self._close(Closure(0, k, z, info, self._chi2(0, k, z, info)), k)

    def _query(self, k: int) -> np.ndarray:
        """Node k's scan points and those of ``query_nodes`` nodes before it (node k's
        frame): what a closure at node k matches."""
        return self._submap(k, range(max(0, k - self.cfg.query_nodes), k + 1))

    def _match(self, field_of: Callable[[], LikelihoodField], query: np.ndarray,
               guess: Pose2D, radius: float, window_deg: float
               ) -> tuple[Pose2D, np.ndarray, np.ndarray] | None:
        """The points ``query`` placed on the field ``field_of`` makes (only if they are
        worth matching) within the window around ``guess`` (the field's frame), refined by
        ICP, the information of the match and the points matched; None where it is poor,
        ambiguous or a corridor's."""
        cfg = self.cfg
        corridor = constraint_ratio(query) < cfg.min_constraint_ratio
        if corridor and not cfg.corridor_closures:
            return None  # a corridor: it could be anywhere along it
        field = field_of()
        match = correlative_match(field, query, guess, radius, window_deg)
        if match.score < cfg.min_score:
            return None
        spread, axes = np.linalg.eigh(match.cov[:2, :2])
        ambiguous = spread[1] > cfg.max_ambiguity_m ** 2
        free = axes[:, 1]  # (the field's frame: the old node's)
        if corridor:
            ambiguous |= match.censored
            if spread[0] > cfg.max_ambiguity_m ** 2:
                return None  # it could be anywhere: not a corridor
            if cfg.corridor_axis == "walls":
                ambiguous = True
                free = transform_points(Pose2D(0.0, 0.0, match.pose.theta),
                                        weakest_axis(query)[None])[0]
        elif ambiguous:
            return None
        refined = icp(field.index, query, match.pose, cfg.icp,
                      np.sqrt(np.diag(match.cov)))
        if refined.share < cfg.min_inliers or refined.rms > cfg.max_rms_m:
            return None
        info = np.linalg.inv(match.cov + np.diag([cfg.edge_sigma_m ** 2] * 2 + [1e-6]))
        if ambiguous:
            info = without_direction(info, free)
        return refined.pose, info, query

    def _close(self, closure: Closure, k: int) -> bool:
        """A closure found at node k through acceptance into the graph; True if the graph
        was optimized."""
        accepted = self.accept(closure)
        self.add_closures(accepted)
        if not accepted:
            return False
        if all(c.chi2 <= self.cfg.agree_chi2 for c in accepted):
            return False  # the graph already agrees: optimize later (finish() always does)
        self.optimize(around=[k, *(c.old for c in accepted)])
        return True

    def add_closures(self, closures: list[Closure]) -> None:
        """Accepted closures into the graph: edges with the robust kernel, and shortcuts of
        the graph distance."""
        for c in closures:
            self.graph.add_edge(c.old, c.new, np.array([c.z.x, c.z.y, c.z.theta]), c.info,
                                robust=True)
            if self.cfg.revisit:
                self._tied[c.old] = self._tied[c.new] = 1
        self.closures += len(closures)

    def _chi2(self, i: int, k: int, z: Pose2D, info: np.ndarray) -> float:
        """How far the graph's estimate of node k seen from node i is from ``z`` (χ²)."""
        err, _, _ = edge_errors(self.graph.poses, np.array([i]), np.array([k]),
                                np.array([[z.x, z.y, z.theta]]))
        return float(err[0] @ info @ err[0])

    def accept(self, closure: Closure) -> list[Closure]:
        """The closures to add to the graph now. One the graph already agrees with (within
        ``consistent_chi2``) is added at once; one that would move the graph waits until a
        second closure, made later along the path, tells the same story: the loop of the
        two closures and the two stretches of path between their ends must close
        (:meth:`_consistent`). A false match (a similar-looking place elsewhere) rarely
        finds a partner that agrees with it; a true one finds one a few metres later, or
        at the next revisit."""
        if closure.chi2 <= self.cfg.consistent_chi2:
            return [closure]
        for other in reversed(self._pending):
            if self._consistent(other, closure):
                self._pending.remove(other)
                return [other, closure]
        self._pending.append(closure)
        return []

    def _consistent(self, a: Closure, b: Closure) -> bool:
        """Whether two closures agree: from a's old node, a's match then the path from a's
        new node to b's new node must reach the same pose as the path between the old
        nodes then b's match, within what the two stretches of path may have drifted."""
        cfg = self.cfg
        apart = self.path[b.new] - self.path[a.new]
        if apart > cfg.pair_window_m or apart < cfg.pair_min_separation_m:
            return False
        via_new = compose(a.z, relative(self.pose(a.new), self.pose(b.new)))
        via_old = compose(relative(self.pose(a.old), self.pose(b.old)), b.z)
        gap = relative(via_new, via_old)
        driven = (self.path[b.new] - self.path[a.new]
                  + abs(self.path[b.old] - self.path[a.old]))
        return (math.hypot(gap.x, gap.y) <= cfg.pair_tolerance_m + cfg.drift_per_m * driven
                and abs(gap.theta) <= math.radians(cfg.pair_tolerance_deg
                                                   + cfg.pair_drift_deg_per_m * driven))

    def optimize(self, iterations: int = ONLINE_ITERATIONS, around: list[int] | None = None
                 ) -> None:
        """Gauss-Newton steps on the graph: a few while the log runs (the next closure goes
        on from there), over the ``online_nodes`` nearest to the nodes ``around`` (fewer
        where ``online_flops`` would not factor them); to convergence over the whole graph
        at the end."""
        if around is None:
            self.graph.optimize(iterations)
        else:
            near = self.graph.distances(around, max_nodes=self.cfg.online_nodes)
            reached = np.flatnonzero(np.isfinite(near))
            self.graph.optimize(iterations, max_flops=self.cfg.online_flops,
                                nodes=reached[np.argsort(near[reached], kind="stable")])
        self._fields.clear()  # the submaps were drawn with the old poses

    def finish(self) -> None:
        """Optimize to convergence if any loop was closed (call once the log has ended)."""
        if self.closures:
            self.optimize(FINAL_ITERATIONS)

    def _submap(self, centre: int, nodes: range) -> np.ndarray:
        """Scan points of ``nodes`` in the frame of node ``centre`` (by the graph's poses)."""
        return np.concatenate([view.points for view in self._views(centre, nodes)])

    def _views(self, centre: int, nodes: range) -> list[View]:
        """Each node's scan as a view (its position and its points) in the frame of node
        ``centre`` (by the graph's poses)."""
        ref = self.pose(centre)
        views = []
        for n in nodes:
            at = relative(ref, self.pose(n))
            views.append(View(np.array([at.x, at.y]), transform_points(at, self.points[n])))
        return views

    def _field(self, i: int, end: int) -> LikelihoodField:
        """Node i's submap as a likelihood field (cached): the scans of ``submap_nodes``
        nodes each side of it, none from node ``end`` on (the stretch just driven, whose
        poses carry the drift the closure is to measure)."""
        key = (i, min(end, i + self.cfg.submap_nodes + 1))
        cached = self._fields.get(key)
        if cached is not None:
            self._fields.move_to_end(key)
            return cached
        views = self._views(i, range(max(0, i - self.cfg.submap_nodes), key[1]))
        field = likelihood_field(np.concatenate([view.points for view in views]),
                                 views if self.cfg.seen_only else None)
        self._fields[key] = field
        if len(self._fields) > 8:
            self._fields.popitem(last=False)
        return field

    def correction(self, node: int) -> Pose2D:
        """The graph's correction of the EKF frame at ``node``: map pose ⊖ EKF pose."""
        return compose(self.pose(node), inverse(self.local_poses[node]))

    def _anchor_correction(self, anchor: Anchor) -> Pose2D:
        """The correction of the EKF frame where a revisit placed the robot."""
        return compose(compose(self.pose(anchor.node), anchor.seen), inverse(anchor.local))

    def to_map(self, points: np.ndarray) -> np.ndarray:
        """EKF-frame positions (N×2) into the map frame by the last node's correction (or
        the last revisit's)."""
        if not self.local_poses or len(points) == 0:
            return points
        return transform_points(self.correction(len(self.local_poses) - 1)
                                if self._anchor is None
                                else self._anchor_correction(self._anchor), points)

    def loop_closures(self) -> np.ndarray:
        """The closures in the graph, K × 5: the scan at which each end's node was made (old,
        new) and the new node seen from the old (x, y, θ) as matched (a prior's matches to
        its walls are closures to the first node)."""
        i, j, z, _, loop = self.graph.edges.arrays()
        made = np.asarray(self._node_scans, dtype=np.int64)
        return np.column_stack((made[i[loop]], made[j[loop]], z[loop]))

    def counts(self) -> dict[str, int]:
        """The graph's nodes, the closures tried and made (those to the prior's walls
        among them; and how many scans matched those) for ``summary.json``."""
        prior = {"prior_matches": self.prior_matches} if self._prior is not None else {}
        revisits = {"revisits": self.revisits} if self.cfg.revisit else {}
        return {"graph_nodes": len(self.local_poses), "loop_closure_attempts": self.attempts,
                "loop_closures": self.closures, **revisits, **prior}

    def place(self, local_pose: Pose2D, scan: Scan,
              motion: tuple[Pose2D, np.ndarray] | None = None) -> Pose2D:
        """A scan at the EKF's pose ``local_pose``, reached by ``motion`` (the increment
        since the scan before and its covariance, as the EKF predicted with): a new node (and
        a loop closure attempt) where the robot has moved far enough from the last, else
        kept as an offset from the last node; returns the scan's pose in the map frame (the
        node's, corrected). With ``revisit``, where the robot is back on a node of the
        graph, it is placed on that node instead of making one (:meth:`revisit`)."""
        if motion is not None and self.cfg.chain_information == "matched":
            moved, cov, scans = self._chain
            self._chain = (compose(moved, motion[0]),
                           compound_covariance(moved, cov, motion[0], motion[1]), scans + 1)
        if self.wants_node(local_pose):
            points = scan_points(scan, self.cfg.max_range_m)
            if not (self.cfg.revisit and self.revisit(local_pose, points)):
                self.add_node(local_pose, points)
        node, offset = self._offset(local_pose)
        self._scan_nodes.append(node)
        self._scan_offsets.extend((offset.x, offset.y, offset.theta))
        if self.cfg.revisit:
            self._scan_anchors.append(-1 if self._anchor is None else len(self._anchors) - 1)
        return compose(self.pose(node), offset)

    def _offset(self, local_pose: Pose2D) -> tuple[int, Pose2D]:
        """The node a scan at the EKF's pose ``local_pose`` hangs from, and its pose from
        that node: the last node's, or the node a revisit placed the robot on."""
        anchor = self._anchor
        if anchor is None:
            node = len(self.local_poses) - 1
            return node, relative(self.local_poses[node], local_pose)
        return anchor.node, compose(anchor.seen, relative(anchor.local, local_pose))

    def revisit(self, local_pose: Pose2D, points: np.ndarray) -> bool:
        """Where the robot, at the EKF's pose ``local_pose`` with the scan ``points`` (robot
        frame), is back on a node the graph holds (one ``min_travel_m`` or more back along
        the path, within ``node_distance_m`` and ``node_angle_deg`` of its estimate): the
        scan matched on that node's submap, and, where the match agrees with the graph
        (``consistent_chi2``) and a loop closure already ties the submap to the rest of the
        graph (the place was mapped, then seen again and closed), the robot placed there
        (True) instead of a new node. Each such placement is the map localizing the robot;
        a place revisited for hours keeps the nodes of its first visits. The first one
        after a node of the chain ties that node to the old one (a closure), so the chain's
        end is not left loose."""
        cfg = self.cfg
        old = (bisect.bisect_right(self.path, self.path[-1] - cfg.min_travel_m)
               if self.path else 0)
        if old == 0:
            return False
        node, offset = self._offset(local_pose)
        at = compose(self.pose(node), offset)
        poses = self.graph.poses[:old]
        d = np.hypot(poses[:, 0] - at.x, poses[:, 1] - at.y)
        near = np.flatnonzero((d <= cfg.node_distance_m) & (
            np.abs(wrap_angles(poses[:, 2] - at.theta)) <= math.radians(cfg.node_angle_deg)))
        if not len(near):
            return False
        j = int(near[np.argmin(d[near])])
        if not any(self._tied[max(0, j - cfg.submap_nodes):j + cfg.submap_nodes + 1]):
            return False
        guess = relative(self.pose(j), at)
        found = self._match(lambda: self._field(j, old), points, guess, cfg.search_radius_m,
                            cfg.search_angle_deg)
        if found is None:
            return False
        seen, info, _ = found
        if self._anchor is None:
            e = relative(guess, seen)
            e_vec = np.array([e.x, e.y, e.theta])
            chi2 = float(e_vec @ info @ e_vec)
            if chi2 > cfg.consistent_chi2:
                return False
            k = len(self.local_poses) - 1  # (the chain's last node, seen from node j)
            self.add_closures([Closure(j, k, compose(seen, relative(
                local_pose, self.local_poses[k])), info, chi2)])
            cov = np.linalg.inv(info)
        else:
            fused = self._followed(self._anchor, local_pose, j, guess, seen, info)
            if fused is None:
                return False
            seen, cov = fused
        self._anchor_cov = rotated_covariance(cov, self.pose(j).theta)
        self._anchor = Anchor(j, seen, local_pose)
        self._anchors.append(self._anchor)
        self._chain = (Pose2D(), np.zeros((3, 3)), 0)
        self.revisits += 1
        return True

    def _followed(self, anchor: Anchor, local_pose: Pose2D, j: int, guess: Pose2D,
                  seen: Pose2D, info: np.ndarray) -> tuple[Pose2D, np.ndarray] | None:
        """A revisit's match ``seen`` (node j's frame, information ``info``) fused with
        where the last revisit and the motion since put the robot (``guess``, its
        covariance the last revisit's compounded with the motion's noise model), and the
        fused pose's covariance (node j's frame); None where the two disagree beyond
        ``consistent_chi2``. So a match that could slide along a wall stays where the
        motion says along it."""
        motion = relative(anchor.local, local_pose)
        st, sr = motion_std(motion.x, motion.y, motion.theta, self.motion_noise)
        predicted = rotated_covariance(compound_covariance(
            compose(self.pose(anchor.node), anchor.seen), self._anchor_cov, motion,
            sigma_covariance((st, st, sr))), -self.pose(j).theta)
        innovation = pose_difference(seen, guess)
        spread = predicted + np.linalg.inv(info)
        if float(innovation @ np.linalg.solve(spread, innovation)) > self.cfg.consistent_chi2:
            return None
        gain = predicted @ np.linalg.inv(spread)
        step = gain @ innovation
        return (Pose2D(guess.x + step[0], guess.y + step[1], guess.theta + step[2]),
                (np.eye(3) - gain) @ predicted)

    def scan_correction(self, scan: int) -> Pose2D:
        """The graph's correction of the EKF frame at the node of scan number ``scan`` (the
        last scan placed, if it is later; where a revisit placed it, that one's)."""
        scan = min(scan, len(self._scan_nodes) - 1)
        if self._scan_anchors and self._scan_anchors[scan] >= 0:
            return self._anchor_correction(self._anchors[self._scan_anchors[scan]])
        return self.correction(self._scan_nodes[scan])

    def estimates(self, scans: np.ndarray | None = None) -> np.ndarray:
        """The current pose estimates (N×3, map frame) of the scans placed, by number
        (default: all): each from its node's pose now and its offset from the node, so a
        loop closure moves the scans before it too."""
        node = np.asarray(self._scan_nodes, dtype=np.int64)
        off = np.asarray(self._scan_offsets, dtype=np.float64).reshape(-1, 3)
        if scans is not None:
            node, off = node[scans], off[scans]
        base = self.graph.poses[node]
        c, s = np.cos(base[:, 2]), np.sin(base[:, 2])
        return np.column_stack((base[:, 0] + c * off[:, 0] - s * off[:, 1],
                                base[:, 1] + s * off[:, 0] + c * off[:, 1],
                                wrap_angles(base[:, 2] + off[:, 2])))
