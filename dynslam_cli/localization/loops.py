"""Loop closure: recognise a place seen long ago and tie the two poses together.

The EKF (Sec. 4) keeps only the landmarks of the last stretch of the run; what drift it
leaves over a long loop is removed here, the way graph-based SLAM does it. Every key scan
becomes a node of a :class:`~dynslam_cli.localization.graph.PoseGraph`, chained to the
previous one by the EKF's relative motion. When the robot is near a node it left a long way
back (near by the current estimate, within a radius that grows with the driving between
the two nodes through the graph, where a loop already closed is a shortcut), the scans
around the new node are matched against those around the old one:

1. **correlative search** over a window of translations and rotations on a likelihood field
   of the old scans (a coarse pass on a max-pooled field bounds every fine cell below it,
   then the best coarse cells are searched finely);
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
    transform_points,
    wrap_angles,
)
from dynslam_cli.localization import _loops
from dynslam_cli.localization._match import PointIndex
from dynslam_cli.localization.ekf import motion_std
from dynslam_cli.localization.globalsearch import BlurredMap, gaussian
from dynslam_cli.localization.graph import PoseGraph, edge_errors
from dynslam_cli.localization.scanmatch import icp, scan_points
from dynslam_cli.sections import LoopConfig, NoiseModel
from dynslam_cli.types import Pose2D, Scan

FIELD_RES_M = 0.05
FIELD_REACH_CELLS = 7  # the field is 0 beyond 0.35 m (4.4 σ) of every point
COARSE_CELLS = 6  # the coarse pass steps this many fine cells (0.3 m)
TOP_COARSE = 6
ANGLE_STEP_DEG = 1.0
NORMAL_NEIGHBOURS = 6
CANDIDATE_BATCH = 8  # loop candidates whose graph distance is found first (_candidate)
LOOP_EDGE_LENGTH_M = 1e-3  # a loop closure's length in the graph distance
# Added to a chain edge's covariance: a millimetre and 0.01° (no edge infinitely sure).
CHAIN_FLOOR = np.diag([1e-6, 1e-6, math.radians(0.01) ** 2])
ONLINE_ITERATIONS = 1  # Gauss-Newton steps per optimization while the log runs
FINAL_ITERATIONS = 10


def _field_kernels() -> tuple[np.ndarray, np.ndarray]:
    """The fine field around one occupied cell, exp(−d²/2σ²) out to FIELD_REACH_CELLS, and
    its max over the coarse pass's window (COARSE_CELLS + 1 cells square): the value at the
    window's cell nearest the centre, as the field falls with distance."""
    h, w = FIELD_REACH_CELLS, COARSE_CELLS // 2
    wide = np.arange(-h - w, h + w + 1)
    return (gaussian(np.arange(-h, h + 1) * FIELD_RES_M),
            gaussian(np.sign(wide) * np.maximum(np.abs(wide) - w, 0) * FIELD_RES_M))


FINE_KERNEL, COARSE_KERNEL = _field_kernels()
FIELD_MARGIN_M = (COARSE_KERNEL.shape[0] // 2 + 1) * FIELD_RES_M


@dataclass
class LikelihoodField:
    """exp(−d²/2σ²) of the distance d from each cell to the nearest occupied cell of the
    submap, on a fine grid, and its max-pooled copy for the coarse pass; the submap's points
    indexed, with their normals for ICP."""

    fine: np.ndarray
    coarse: np.ndarray
    origin: np.ndarray  # map coordinates of cell (0, 0)
    index: PointIndex


def likelihood_field(points: np.ndarray) -> LikelihoodField:
    lo = points.min(axis=0) - FIELD_MARGIN_M
    hi = points.max(axis=0) + FIELD_MARGIN_M
    shape = np.ceil((hi - lo) / FIELD_RES_M).astype(int) + 1
    cols, rows = np.floor((points - lo) / FIELD_RES_M + 0.5).astype(np.intp).T.copy()
    fine = np.zeros((shape[1], shape[0]))
    coarse = np.zeros((shape[1], shape[0]))
    _loops.splat_max(fine, rows, cols, FINE_KERNEL)
    _loops.splat_max(coarse, rows, cols, COARSE_KERNEL)
    index = PointIndex(points, neighbours=NORMAL_NEIGHBOURS)
    return LikelihoodField(fine, coarse, lo, index)


def _scores(grid: np.ndarray, origin: np.ndarray, pts: np.ndarray, thetas: np.ndarray,
            base: np.ndarray, tx: np.ndarray, ty: np.ndarray) -> np.ndarray:
    """Mean field value of ``pts`` rotated by each θ and moved to base + (tx, ty) cells, for
    every (θ, ty, tx): an array of shape (len(thetas), len(ty), len(tx))."""
    return _loops.mean_scores(grid, float(origin[0]), float(origin[1]), FIELD_RES_M, pts,
                               float(base[0]), float(base[1]), thetas,
                               tx.astype(np.intp), ty.astype(np.intp))


def constraint_ratio(points: np.ndarray) -> float:
    """How well a set of points pins down a position, weakest direction over strongest
    (eigenvalues of the sum of n nᵀ over the points' normals): about 0 for the two walls of a
    corridor, which say nothing about the position along it."""
    n = PointIndex(points, neighbours=NORMAL_NEIGHBOURS).normals()
    ev = np.linalg.eigvalsh(n.T @ n)
    return float(ev[0] / max(ev[1], 1e-12))


@dataclass(frozen=True)
class Match:
    """A correlative match: the pose, its score (mean likelihood of the points, 0–1) and the
    covariance of the poses that score almost as well (its ambiguity)."""

    pose: Pose2D
    score: float
    cov: np.ndarray


def correlative_match(field: LikelihoodField, pts: np.ndarray, guess: Pose2D,
                      window_m: float, window_deg: float) -> Match:
    """Best pose of ``pts``' frame in the field's frame within the window around ``guess``.

    Scores are weighed by a mild preference for the guess's position, so along a
    featureless corridor (where every offset scores the same) the estimate stays put
    instead of sliding."""
    half = math.ceil(window_m / (COARSE_CELLS * FIELD_RES_M))
    coarse_t = np.arange(-half, half + 1) * COARSE_CELLS
    n_ang = math.ceil(window_deg / ANGLE_STEP_DEG)
    dthetas = np.radians(np.arange(-n_ang, n_ang + 1) * ANGLE_STEP_DEG)
    base = np.array([guess.x, guess.y])
    bounds = _scores(field.coarse, field.origin, pts, guess.theta + dthetas, base, coarse_t,
                     coarse_t)
    t_m = coarse_t * FIELD_RES_M
    ranked = bounds * _preference(t_m[None, None, :], t_m[None, :, None], window_m)
    fine_t = np.arange(-(COARSE_CELLS // 2), COARSE_CELLS // 2 + 1)
    sub_angles = np.radians(np.array([-0.5, 0.0, 0.5]) * ANGLE_STEP_DEG)
    best = (-1.0, 0.0, guess)  # (weighed score, score, pose)
    for flat in np.argsort(ranked, axis=None)[::-1][:TOP_COARSE]:
        a, r, c = np.unravel_index(int(flat), ranked.shape)
        if ranked[a, r, c] <= best[0]:
            break  # the coarse score bounds every fine score below it
        tx, ty = coarse_t[c] + fine_t, coarse_t[r] + fine_t
        ths = dthetas[a] + sub_angles
        fine = _scores(field.fine, field.origin, pts, guess.theta + ths, base, tx, ty)
        for th, sc in zip(ths, fine, strict=True):
            w = sc * _preference(tx[None, :] * FIELD_RES_M, ty[:, None] * FIELD_RES_M,
                                 window_m)
            i, j = np.unravel_index(int(np.argmax(w)), w.shape)
            if w[i, j] > best[0]:
                best = (float(w[i, j]), float(sc[i, j]), Pose2D(
                    guess.x + tx[j] * FIELD_RES_M, guess.y + ty[i] * FIELD_RES_M,
                    guess.theta + th))
    _, score, pose = best
    return Match(pose, score, _ambiguity(bounds, t_m, dthetas, score))


DISTANCE_PREFERENCE = 0.5  # weight falls by a quarter from the guess to the window edge
AMBIGUITY_SHARE = 0.95  # poses whose coarse bound reaches this share of the best score


def _preference(dx_m: np.ndarray, dy_m: np.ndarray, window_m: float) -> np.ndarray:
    """Weight of an offset from the guess's position (broadcast over the arguments): 1 at
    the guess, falling to 1 − DISTANCE_PREFERENCE at the window's corner. Its heading gets
    none: walls pin a heading, and the heading is what a loop closure most often corrects
    (preferring the guess's, closures kept 2.5–8° of a wrong graph's heading on fhw)."""
    d2 = (dx_m ** 2 + dy_m ** 2) / max(window_m, 1e-9) ** 2
    return 1.0 - DISTANCE_PREFERENCE * 0.5 * d2


# Spread of one coarse cell (uniform over its width): the least uncertainty a match has.
CELL_COV = np.diag([COARSE_CELLS * FIELD_RES_M, COARSE_CELLS * FIELD_RES_M,
                    math.radians(ANGLE_STEP_DEG)]) ** 2 / 12.0


def _ambiguity(bounds: np.ndarray, t_m: np.ndarray, dthetas: np.ndarray,
               score: float) -> np.ndarray:
    """Covariance (x, y, θ) of the coarse cells that could hold a pose about as good as the
    best: wide along a corridor, small where the scene pins the match down."""
    a, r, c = np.nonzero(bounds >= AMBIGUITY_SHARE * score)
    if len(a) < 2:
        return CELL_COV.copy()
    return np.cov(np.column_stack((t_m[c], t_m[r], dthetas[a])), rowvar=False) + CELL_COV


class PriorWalls(NamedTuple):
    """An earlier session's map, to keep a run in its frame (``--prior``): the centres of
    its Occupied cells (N×2) and the map blurred, to make a match finer than a cell on."""

    points: np.ndarray
    blurred: BlurredMap


@dataclass(frozen=True)
class Closure:
    """A loop-closure match: node ``new`` seen from node ``old`` at ``z``, its information,
    and its χ² against the graph when it was made."""

    old: int
    new: int
    z: Pose2D
    info: np.ndarray
    chi2: float


class Links:
    """The graph's edges as adjacency lists (for :func:`_loops.shortest_paths`), grown by
    doubling: ``head[v]`` is node v's first half-edge, each half-edge leads ``to`` a node
    with a ``length`` and is followed by ``nxt`` (-1 ends a list)."""

    def __init__(self) -> None:
        self.nodes = 0
        self.head = np.full(64, -1, np.intp)
        self.nxt, self.to = np.zeros(64, np.intp), np.zeros(64, np.intp)
        self.length = np.zeros(64)
        self.count = 0

    def add_node(self) -> None:
        if self.nodes == len(self.head):
            self.head = np.concatenate((self.head, np.full(len(self.head), -1, np.intp)))
        self.nodes += 1

    def link(self, i: int, j: int, length: float) -> None:
        """An edge between nodes i and j (both ways)."""
        if self.count + 2 > len(self.to):
            self.nxt, self.to, self.length = (np.concatenate((a, np.zeros_like(a)))
                                              for a in (self.nxt, self.to, self.length))
        for a, b in ((i, j), (j, i)):
            e = self.count
            self.to[e], self.length[e], self.nxt[e] = b, length, self.head[a]
            self.head[a] = e
            self.count += 1

    def shortest_paths(self, sources: list[int], limit: float = math.inf,
                       max_nodes: int | None = None, targets: np.ndarray | None = None
                       ) -> np.ndarray:
        """Distances from the nearest of ``sources`` to every node, ∞ beyond ``limit`` and
        beyond the ``max_nodes`` nearest; with ``targets``, exact for them (others may be ∞
        where the search stopped, once it had them all)."""
        return _loops.shortest_paths(self.head, self.nxt, self.to, self.length, self.nodes,
                                     np.asarray(sources, dtype=np.intp), limit,
                                     self.nodes if max_nodes is None else max_nodes,
                                     np.zeros(0, np.intp) if targets is None
                                     else np.asarray(targets, dtype=np.intp))


class LoopCloser:
    """Keeps the graph, the key scans and the closures."""

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
        self._links = Links()  # the graph, for its distances
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
        self._scan_offsets = array("d")  # ... and its pose in that node's EKF frame

    def wants_node(self, local_pose: Pose2D) -> bool:
        return not self.local_poses or moved_far(self.local_poses[-1], local_pose,
                                                 self.cfg.node_distance_m,
                                                 math.radians(self.cfg.node_angle_deg))

    def add_node(self, local_pose: Pose2D, points: np.ndarray) -> bool:
        """A new node at the EKF's pose, chained to the previous node; then a loop closure
        attempt. Returns True if the graph was optimized (the map frame moved)."""
        graph = self.graph
        if not self.local_poses:
            graph.add_node(np.array([local_pose.x, local_pose.y, local_pose.theta]))
            self._append(local_pose, points, 0.0)
            return False
        k_prev = len(self.local_poses) - 1
        z = relative(self.local_poses[-1], local_pose)
        est = compose(self.pose(k_prev), z)
        k = graph.add_node(np.array([est.x, est.y, est.theta]))
        graph.add_edge(k_prev, k, np.array([z.x, z.y, z.theta]), self._chain_information(z))
        step = math.hypot(z.x, z.y)
        self._append(local_pose, points, self.path[-1] + step)
        self._links.link(k_prev, k, step)
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
        self._links.add_node()
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
        return self._links.shortest_paths([k], limit, targets=targets)

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
        found = self._match(lambda: self._field(i, old), k,
                            relative(self.pose(i), self.pose(k)), radius, window_deg)
        if found is None:
            return False
        pose, info, _ = found
        return self._close(Closure(i, k, pose, info, self._chi2(i, k, pose, info)), k)

    def _try_prior(self, k: int) -> bool:
        """Node k's scans matched against the prior map (``prior``) near where the
        graph has it, every ``attempt_every_m``: a closure to the first node (held where
        the prior placed it), so the run stays in the prior's frame; accepted as any other."""
        cfg, prior, field = self.cfg, self._prior, self._prior_field
        if (prior is None or field is None
                or self.path[k] - self._last_prior_m < cfg.attempt_every_m):
            return False
        self._last_prior_m = self.path[k]
        found = self._match(lambda: field, k, self.pose(k), cfg.search_radius_m,
                            cfg.search_angle_deg)
        if found is None:
            return False
        self.prior_matches += 1
        pose, info, query = found  # ICP on the cells' centres, made finer on the blur:
        pose = prior.blurred.refine(query, pose, FIELD_RES_M, math.radians(ANGLE_STEP_DEG))
        z = relative(self.pose(0), pose)
        return self._close(Closure(0, k, z, info, self._chi2(0, k, z, info)), k)

    def _match(self, field_of: Callable[[], LikelihoodField], k: int, guess: Pose2D,
               radius: float, window_deg: float
               ) -> tuple[Pose2D, np.ndarray, np.ndarray] | None:
        """Node k's scans (and ``query_nodes`` before it) placed on the field ``field_of``
        makes (only if they are worth matching) within the window around ``guess`` (the
        field's frame), refined by ICP, the information of the match and the points matched
        (node k's frame); None where it is poor, ambiguous or a corridor's."""
        cfg = self.cfg
        query = self._submap(k, range(max(0, k - cfg.query_nodes), k + 1))
        if constraint_ratio(query) < cfg.min_constraint_ratio:
            return None  # a corridor: it could be anywhere along it
        field = field_of()
        match = correlative_match(field, query, guess, radius, window_deg)
        if (match.score < cfg.min_score
                or np.linalg.eigvalsh(match.cov[:2, :2]).max() > cfg.max_ambiguity_m ** 2):
            return None
        refined = icp(field.index, query, match.pose, cfg.icp,
                      np.sqrt(np.diag(match.cov)))
        if refined.share < cfg.min_inliers or refined.rms > cfg.max_rms_m:
            return None
        info = np.linalg.inv(match.cov + np.diag([cfg.edge_sigma_m ** 2] * 2 + [1e-6]))
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
            self._links.link(c.old, c.new, LOOP_EDGE_LENGTH_M)
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
            near = self._links.shortest_paths(around, max_nodes=self.cfg.online_nodes)
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
        ref = self.pose(centre)
        return np.concatenate([transform_points(relative(ref, self.pose(n)), self.points[n])
                               for n in nodes])

    def _field(self, i: int, end: int) -> LikelihoodField:
        """Node i's submap as a likelihood field (cached): the scans of ``submap_nodes``
        nodes each side of it, none from node ``end`` on (the stretch just driven, whose
        poses carry the drift the closure is to measure)."""
        key = (i, min(end, i + self.cfg.submap_nodes + 1))
        cached = self._fields.get(key)
        if cached is not None:
            self._fields.move_to_end(key)
            return cached
        pts = self._submap(i, range(max(0, i - self.cfg.submap_nodes), key[1]))
        field = likelihood_field(pts)
        self._fields[key] = field
        if len(self._fields) > 8:
            self._fields.popitem(last=False)
        return field

    def correction(self, node: int) -> Pose2D:
        """The graph's correction of the EKF frame at ``node``: map pose ⊖ EKF pose."""
        return compose(self.pose(node), inverse(self.local_poses[node]))

    def to_map(self, points: np.ndarray) -> np.ndarray:
        """EKF-frame positions (N×2) into the map frame by the last node's correction."""
        if not self.local_poses or len(points) == 0:
            return points
        return transform_points(self.correction(len(self.local_poses) - 1), points)

    def loop_closures(self) -> np.ndarray:
        """The closures in the graph, K × 5: the scan at which each end's node was made (old,
        new) and the new node seen from the old (x, y, θ) as matched (a prior's matches to
        its walls are closures to the first node)."""
        i, j, z, _, loop = self.graph.edges.arrays()
        made = np.searchsorted(np.asarray(self._scan_nodes, dtype=np.int64),
                               np.arange(len(self.local_poses)))
        return np.column_stack((made[i[loop]], made[j[loop]], z[loop]))

    def counts(self) -> dict[str, int]:
        """The graph's nodes, the closures tried and made (those to the prior's walls
        among them; and how many scans matched those) for ``summary.json``."""
        prior = {"prior_matches": self.prior_matches} if self._prior is not None else {}
        return {"graph_nodes": len(self.local_poses), "loop_closure_attempts": self.attempts,
                "loop_closures": self.closures, **prior}

    def place(self, local_pose: Pose2D, scan: Scan,
              motion: tuple[Pose2D, np.ndarray] | None = None) -> Pose2D:
        """A scan at the EKF's pose ``local_pose``, reached by ``motion`` (the increment
        since the scan before and its covariance, as the EKF predicted with): a new node (and
        a loop closure attempt) where the robot has moved far enough from the last, else
        kept as an offset from the last node; returns the scan's pose in the map frame (the
        node's, corrected)."""
        if motion is not None and self.cfg.chain_information == "matched":
            moved, cov, scans = self._chain
            self._chain = (compose(moved, motion[0]),
                           compound_covariance(moved, cov, motion[0], motion[1]), scans + 1)
        if self.wants_node(local_pose):
            self.add_node(local_pose, scan_points(scan, self.cfg.max_range_m))
        node = len(self.local_poses) - 1
        offset = relative(self.local_poses[node], local_pose)
        self._scan_nodes.append(node)
        self._scan_offsets.extend((offset.x, offset.y, offset.theta))
        return compose(self.pose(node), offset)

    def scan_correction(self, scan: int) -> Pose2D:
        """The graph's correction of the EKF frame at the node of scan number ``scan`` (the
        last scan placed, if it is later)."""
        return self.correction(self._scan_nodes[min(scan, len(self._scan_nodes) - 1)])

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
