"""A 2-D pose graph and its sparse Gauss-Newton optimizer.

Nodes are robot poses (x, y, θ) at key scans; an edge says "node j seen from node i is at
z, with information Ω" (3×3). The error of an edge is the pose of j relative to i, seen from
z: ``e = t2v(Z⁻¹ (Xᵢ⁻¹ Xⱼ))``. Gauss-Newton solves the sparse normal equations (the first
node is held fixed) until the step is tiny, by an LDLᵀ factorization with the nodes in
minimum-degree order (so it fills in little, even where the robot went round the same place
many times). Loop-closure edges
carry a Cauchy kernel, so a wrong one pulls only softly.
"""

from __future__ import annotations

import numpy as np

from dynslam_cli.geometry import wrap_angles
from dynslam_cli.localization import _graph

CAUCHY_C = 3.0  # χ² scale of the robust kernel on loop edges


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


class PoseGraph:
    """Nodes, edges and :meth:`optimize`."""

    def __init__(self) -> None:
        self.poses = np.zeros((0, 3))
        self._capacity_poses = np.zeros((64, 3))
        self.edges = Edges()

    def add_node(self, pose: np.ndarray) -> int:
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
        self.edges.add(i, j, z, info, robust)

    def optimize(self, iterations: int = 10, cauchy_c: float = CAUCHY_C) -> None:
        """Gauss-Newton over all nodes but the first (held where it is)."""
        if not self.edges.count:
            return
        i, j, z, info, robust = self.edges.arrays()
        n = len(self.poses)
        rows, cols = _hessian_pattern(i, j)
        by_column = np.argsort(cols, kind="stable")  # compressed columns; duplicates summed
        indptr = np.concatenate(([0], np.cumsum(np.bincount(cols, minlength=3 * n))))
        indices = rows[by_column]
        node_order = _graph.minimum_degree(n, i, j)
        order = (3 * node_order[:, None] + np.arange(3)).ravel()
        g_index = np.concatenate([(3 * i[:, None] + np.arange(3)).ravel(),
                                  (3 * j[:, None] + np.arange(3)).ravel()])
        for _ in range(iterations):
            err, a, b = edge_errors(self.poses, i, j, z)
            chi2 = np.einsum("ka,kab,kb->k", err, info, err)
            w = np.where(robust, 1.0 / (1.0 + chi2 / cauchy_c ** 2), 1.0)
            winfo = info * w[:, None, None]
            at_w = a.transpose(0, 2, 1) @ winfo  # Aᵀ Ω, then Bᵀ Ω
            bt_w = b.transpose(0, 2, 1) @ winfo
            h_ij = at_w @ b
            vals = np.concatenate([(at_w @ a).ravel(), h_ij.ravel(),
                                   h_ij.transpose(0, 2, 1).ravel(), (bt_w @ b).ravel(),
                                   np.full(3, 1e12)])  # the first node's anchor
            g = np.bincount(g_index, np.concatenate([(at_w @ err[:, :, None]).ravel(),
                                                     (bt_w @ err[:, :, None]).ravel()]),
                            minlength=3 * n)
            try:
                step = -_graph.solve_spd(indptr, indices, vals[by_column], order,
                                          g).reshape(-1, 3)
            except ValueError:  # not positive definite (degenerate edges): keep the poses
                break
            self.poses += step
            self.poses[:, 2] = wrap_angles(self.poses[:, 2])
            if np.abs(step[:, :2]).max() < 1e-4 and np.abs(step[:, 2]).max() < 1e-5:
                break


def _hessian_pattern(i: np.ndarray, j: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Row and column of every entry of the 3×3 blocks (i,i), (i,j), (j,i), (j,j) of each
    edge, in that order, then the first node's diagonal."""
    rows, cols = [], []
    for r, c in ((i, i), (i, j), (j, i), (j, j)):
        rows.append(np.broadcast_to(3 * r[:, None, None] + np.arange(3)[None, :, None],
                                    (len(r), 3, 3)).ravel())
        cols.append(np.broadcast_to(3 * c[:, None, None] + np.arange(3)[None, None, :],
                                    (len(c), 3, 3)).ravel())
    return np.concatenate([*rows, np.arange(3)]), np.concatenate([*cols, np.arange(3)])


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
