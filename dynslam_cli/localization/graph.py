"""A 2-D pose graph and its sparse Gauss-Newton optimizer.

Nodes are robot poses (x, y, θ) at key scans; an edge says "node j seen from node i is at
z, with information Ω" (3×3). The error of an edge is the pose of j relative to i, seen from
z: ``e = t2v(Z⁻¹ (Xᵢ⁻¹ Xⱼ))``. Gauss-Newton solves the sparse normal equations (the first
node is held fixed) until the step is tiny: by an LDLᵀ factorization with the nodes in
minimum-degree order, or, for a graph of more than ``DIRECT_MAX_NODES`` (hours in one place,
where the factor fills in), by preconditioned conjugate gradients. An optimization can move
only part of the graph, holding the rest (the online window of a long log). Loop-closure
edges carry a Cauchy kernel, so a wrong one pulls only softly.
"""

from __future__ import annotations

import math

import numpy as np

from dynslam_cli.geometry import wrap_angles
from dynslam_cli.localization import _graph, _loops

CAUCHY_C = 3.0  # χ² scale of the robust kernel on loop edges
# Above this many moving nodes a step is solved by conjugate gradients instead of LDLᵀ: where
# a place is revisited for hours the factor fills in faster than the graph grows (4 h in one
# hall: 15 570 nodes, 11 M nonzeros in L, 21 s a step; conjugate gradients 1.3 s, the same
# step to 5e-8 m). Compiled here rather than scipy's: importing scipy.sparse.linalg costs
# 30 MB, a tenth of a long log's memory bound.
DIRECT_MAX_NODES = 2000
CG_TOLERANCE = 1e-8  # relative residual of the conjugate-gradient solve
MIN_MOVING_NODES = 200  # an optimization bounded in flops still moves this many nodes
LOOP_EDGE_LENGTH_M = 1e-3  # a loop closure's length in the graph distance


class Edges:
    """The edges as parallel arrays, grown by doubling: nodes ``i`` and ``j``, measurement
    ``z`` (j seen from i), information ``info`` (3×3), ``robust`` (a loop closure)."""

    def __init__(self) -> None:
        self.count = 0
        self._store = (np.zeros(64, np.intp), np.zeros(64, np.intp), np.zeros((64, 3)),
                       np.zeros((64, 3, 3)), np.zeros(64, bool))

    def add(self, *edge: object) -> None:
        k = self.count
        if k == len(self._store[0]):
            self._store = tuple(np.concatenate((a, np.zeros_like(a))) for a in self._store)
        for array, value in zip(self._store, edge, strict=True):
            array[k] = value
        self.count = k + 1

    def arrays(self) -> tuple[np.ndarray, ...]:
        """(i, j, z, info, robust), the filled part."""
        return tuple(a[:self.count] for a in self._store)


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


class PoseGraph:
    """Nodes, edges, :meth:`optimize`, and the graph distance between nodes
    (:meth:`distances`)."""

    def __init__(self) -> None:
        self.poses = np.zeros((0, 3))
        self._capacity_poses = np.zeros((64, 3))
        self.edges = Edges()
        self._links = Links()

    def add_node(self, pose: np.ndarray) -> int:
        self._links.add_node()
        n = len(self.poses)
        if n == len(self._capacity_poses):
            grown = np.zeros((2 * n, 3))
            grown[:n] = self._capacity_poses[:n]
            self._capacity_poses = grown
        self._capacity_poses[n] = pose
        self.poses = self._capacity_poses[:n + 1]
        return n

    def add_edge(self, i: int, j: int, z: np.ndarray, info: np.ndarray,
                 robust: bool = False) -> None:
        """Node j seen from node i at ``z`` with information ``info``; ``robust``: a loop
        closure (the Cauchy kernel; a shortcut of LOOP_EDGE_LENGTH_M in the graph
        distance, where another edge is as long as its motion's translation)."""
        self.edges.add(i, j, z, info, robust)
        self._links.link(i, j, LOOP_EDGE_LENGTH_M if robust
                         else math.hypot(float(z[0]), float(z[1])))

    def distances(self, sources: list[int], limit: float = math.inf,
                  max_nodes: int | None = None, targets: np.ndarray | None = None
                  ) -> np.ndarray:
        """How far each node is through the graph from the nearest of ``sources``: the
        shortest path along the edges (metres driven, loop closures shortcuts of ~0);
        ∞ beyond ``limit`` and beyond the ``max_nodes`` nearest; with ``targets``, exact for
        them (others may be ∞ where the search stopped, once it had them all)."""
        return self._links.shortest_paths(sources, limit, max_nodes, targets)

    def optimize(self, iterations: int = 10, cauchy_c: float = CAUCHY_C,
                 nodes: np.ndarray | None = None, max_flops: float = math.inf) -> None:
        """Gauss-Newton over all nodes but the first (held where it is); or over ``nodes``
        alone, every other node held where it is, so the cost is that of the part of the
        graph that moves. With ``max_flops`` (``nodes`` nearest first), over only as many
        of them as an LDLᵀ factorization of about that many multiplications holds: where a
        place was revisited for hours, loop closures tie many passes together and the same
        number of nodes fills the factor in several times as much."""
        if not self.edges.count:
            return
        i, j, z, info, robust = self.edges.arrays()
        n = len(self.poses)
        nodes = np.arange(n) if nodes is None else np.asarray(nodes, dtype=np.intp)
        while True:
            moving, li, lj, keep = _moving_part(n, nodes, i, j)
            both = (li >= 0) & (lj >= 0)
            m = len(moving)
            direct = m <= DIRECT_MAX_NODES
            if not direct:
                break
            node_order, flops = _graph.minimum_degree(m, li[both], lj[both])
            if flops <= max_flops or m <= MIN_MOVING_NODES:
                break
            shrink = min(0.9, (max_flops / flops) ** (2.0 / 3.0))  # flops grow as ~m^1.5
            nodes = nodes[:max(MIN_MOVING_NODES, int(m * shrink))]
        nodes = moving
        if keep is not None:
            i, j, z, info, robust = i[keep], j[keep], z[keep], info[keep], robust[keep]
        moves_i, moves_j = li >= 0, lj >= 0
        anchor = np.arange(3) if nodes[0] == 0 else np.zeros(0, np.intp)  # the first node
        rows, cols = _hessian_pattern(((li[moves_i], li[moves_i]), (li[both], lj[both]),
                                       (lj[both], li[both]), (lj[moves_j], lj[moves_j])))
        rows, cols = np.concatenate((rows, anchor)), np.concatenate((cols, anchor))
        by_column = np.argsort(cols, kind="stable")  # compressed columns; duplicates summed
        indptr = np.concatenate(([0], np.cumsum(np.bincount(cols, minlength=3 * m))))
        indices = rows[by_column]
        if direct:
            order = (3 * node_order[:, None] + np.arange(3)).ravel()
        g_index = np.concatenate([(3 * li[moves_i, None] + np.arange(3)).ravel(),
                                  (3 * lj[moves_j, None] + np.arange(3)).ravel()])
        for _ in range(iterations):
            err, a, b = edge_errors(self.poses, i, j, z)
            chi2 = np.einsum("ka,kab,kb->k", err, info, err)
            w = np.where(robust, 1.0 / (1.0 + chi2 / cauchy_c ** 2), 1.0)
            winfo = info * w[:, None, None]
            at_w = a.transpose(0, 2, 1) @ winfo  # Aᵀ Ω, then Bᵀ Ω
            bt_w = b.transpose(0, 2, 1) @ winfo
            h_ii, h_ij, h_jj = (at_w @ a)[moves_i], (at_w @ b)[both], (bt_w @ b)[moves_j]
            vals = np.concatenate([h_ii.ravel(), h_ij.ravel(), h_ij.transpose(0, 2, 1).ravel(),
                                   h_jj.ravel(), np.full(len(anchor), 1e12)])
            g = np.bincount(g_index, np.concatenate([(at_w @ err[:, :, None])[moves_i].ravel(),
                                                     (bt_w @ err[:, :, None])[moves_j].ravel()]),
                            minlength=3 * m)
            if not direct:
                diagonal = np.zeros((m, 3, 3))  # the 3×3 blocks of the preconditioner
                np.add.at(diagonal, li[moves_i], h_ii)
                np.add.at(diagonal, lj[moves_j], h_jj)
                if len(anchor):
                    diagonal[0] += np.eye(3) * 1e12
                step = -_graph.conjugate_gradients(indptr, indices, vals[by_column],
                                                   np.linalg.inv(diagonal), g, CG_TOLERANCE,
                                                   30 * m).reshape(-1, 3)
            else:
                try:
                    step = -_graph.solve_spd(indptr, indices, vals[by_column], order,
                                              g).reshape(-1, 3)
                except ValueError:  # not positive definite (degenerate edges): keep the poses
                    break
            self.poses[nodes] += step
            self.poses[nodes, 2] = wrap_angles(self.poses[nodes, 2])
            if np.abs(step[:, :2]).max() < 1e-4 and np.abs(step[:, 2]).max() < 1e-5:
                break


def _moving_part(n: int, nodes: np.ndarray, i: np.ndarray, j: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
    """The moving nodes sorted, each edge's ends' places among them (-1: held) and which
    edges touch them (None: all, when every node moves)."""
    if len(nodes) == n:
        return np.arange(n), i, j, None
    moving = np.sort(nodes)
    local = np.full(n, -1, np.intp)
    local[moving] = np.arange(len(moving))
    li, lj = local[i], local[j]
    keep = (li >= 0) | (lj >= 0)
    return moving, li[keep], lj[keep], keep


def _hessian_pattern(blocks: tuple[tuple[np.ndarray, np.ndarray], ...]
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Row and column of every entry of the 3×3 blocks at node pairs (r[k], c[k]), block
    list after block list."""
    rows, cols = [], []
    for r, c in blocks:
        rows.append(np.broadcast_to(3 * r[:, None, None] + np.arange(3)[None, :, None],
                                    (len(r), 3, 3)).ravel())
        cols.append(np.broadcast_to(3 * c[:, None, None] + np.arange(3)[None, None, :],
                                    (len(c), 3, 3)).ravel())
    return np.concatenate(rows), np.concatenate(cols)


def edge_errors(poses: np.ndarray, i: np.ndarray, j: np.ndarray, z: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each edge's error and its Jacobians with respect to node i (A) and node j (B)."""
    xi, xj = poses[i], poses[j]
    ci, si = np.cos(xi[:, 2]), np.sin(xi[:, 2])
    cz, sz = np.cos(z[:, 2]), np.sin(z[:, 2])
    dx, dy = xj[:, 0] - xi[:, 0], xj[:, 1] - xi[:, 1]
    # pose of j in i's frame, then seen from z
    lx, ly = ci * dx + si * dy, -si * dx + ci * dy
    ex = cz * (lx - z[:, 0]) + sz * (ly - z[:, 1])
    ey = -sz * (lx - z[:, 0]) + cz * (ly - z[:, 1])
    eth = wrap_angles(xj[:, 2] - xi[:, 2] - z[:, 2])
    err = np.column_stack((ex, ey, eth))
    k = len(i)
    # R_zᵀ R_iᵀ (rows: e_x, e_y; columns: x, y)
    r00, r01 = cz * ci - sz * si, cz * si + sz * ci
    r10, r11 = -sz * ci - cz * si, -sz * si + cz * ci
    # R_zᵀ ∂R_iᵀ/∂θ (t_j − t_i) = R_zᵀ (l_y, −l_x)
    d0 = cz * ly - sz * lx
    d1 = -sz * ly - cz * lx
    a = np.zeros((k, 3, 3))
    b = np.zeros((k, 3, 3))
    a[:, 0, 0], a[:, 0, 1], a[:, 0, 2] = -r00, -r01, d0
    a[:, 1, 0], a[:, 1, 1], a[:, 1, 2] = -r10, -r11, d1
    a[:, 2, 2] = -1.0
    b[:, 0, 0], b[:, 0, 1] = r00, r01
    b[:, 1, 0], b[:, 1, 1] = r10, r11
    b[:, 2, 2] = 1.0
    return err, a, b
