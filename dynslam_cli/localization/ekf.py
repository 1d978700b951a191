"""EKF-SLAM after Dissanayake et al. (2001): robot pose and corner landmarks in one state.

State layout: ``x = [x_r, y_r, θ_r, l1x, l1y, l2x, l2y, ...]`` (metres, radians); ``cov`` its
covariance. Each step of the maths is one function: the motion model and its Jacobians, the
range-bearing measurement model and its Jacobian, Mahalanobis gating, augmentation with a new
landmark, and the update. Updates use the symmetric form P − K S Kᵀ (the 2×2 innovation
covariance S inverted in closed form) and P kept symmetric; cost is O(n²) per observation
because H touches only the robot and one landmark.
"""

from __future__ import annotations

import math

import numpy as np

from dynslam_cli.geometry import wrap_angle
from dynslam_cli.sections import NoiseModel

ROBOT = 3  # state entries of the robot pose
LM = 2  # state entries per landmark


# -- motion model ---------------------------------------------------------------------------
def motion(pose: np.ndarray, u: np.ndarray) -> np.ndarray:
    """pose ⊕ u: apply the odometry increment u = (dx, dy, dθ), given in the robot frame."""
    c, s = math.cos(pose[2]), math.sin(pose[2])
    return np.array([pose[0] + c * u[0] - s * u[1], pose[1] + s * u[0] + c * u[1],
                     wrap_angle(pose[2] + u[2])])


def motion_jacobians(pose: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """∂motion/∂pose and ∂motion/∂u."""
    c, s = math.cos(pose[2]), math.sin(pose[2])
    f_x = np.array([[1.0, 0.0, -s * u[0] - c * u[1]],
                    [0.0, 1.0, c * u[0] - s * u[1]],
                    [0.0, 0.0, 1.0]])
    f_u = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return f_x, f_u


def motion_std(dx: float, dy: float, dtheta: float, noise: NoiseModel) -> tuple[float, float]:
    """Standard deviations (translation per axis, rotation) of an increment (robot frame),
    growing with distance and turn."""
    dist = math.hypot(dx, dy)
    st = noise.trans_per_m * dist + noise.trans_floor_m
    sr = (noise.rot_per_rad * abs(dtheta) + math.radians(noise.rot_per_m_deg) * dist
          + math.radians(noise.rot_floor_deg))
    return st, sr


def motion_noise(u: np.ndarray, noise: NoiseModel) -> np.ndarray:
    """Covariance of the increment u (robot frame): :func:`motion_std` squared."""
    st, sr = motion_std(u[0], u[1], u[2], noise)
    return np.diag([st * st, st * st, sr * sr])


# -- measurement model ----------------------------------------------------------------------
def observe(pose: np.ndarray, landmark: np.ndarray) -> np.ndarray:
    """Expected (range, bearing) of a landmark from the robot."""
    dx, dy = landmark[0] - pose[0], landmark[1] - pose[1]
    return np.array([math.hypot(dx, dy), wrap_angle(math.atan2(dy, dx) - pose[2])])


def observe_jacobians(pose: np.ndarray, landmark: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """∂observe/∂pose (2×3) and ∂observe/∂landmark (2×2)."""
    dx, dy = landmark[0] - pose[0], landmark[1] - pose[1]
    q = max(dx * dx + dy * dy, 1e-12)
    r = math.sqrt(q)
    h_l = np.array([[dx / r, dy / r], [-dy / q, dx / q]])
    h_r = np.hstack((-h_l, np.array([[0.0], [-1.0]])))
    return h_r, h_l


def inverse_observe(pose: np.ndarray, z: np.ndarray) -> np.ndarray:
    """Landmark position from the robot pose and a (range, bearing) observation."""
    a = pose[2] + z[1]
    return np.array([pose[0] + z[0] * math.cos(a), pose[1] + z[0] * math.sin(a)])


def inverse_observe_jacobians(pose: np.ndarray, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """∂inverse_observe/∂pose (2×3) and ∂/∂z (2×2)."""
    a = pose[2] + z[1]
    c, s = math.cos(a), math.sin(a)
    g_r = np.array([[1.0, 0.0, -z[0] * s], [0.0, 1.0, z[0] * c]])
    g_z = np.array([[c, -z[0] * s], [s, z[0] * c]])
    return g_r, g_z


def measurement_noise(z: np.ndarray, noise: NoiseModel) -> np.ndarray:
    sr = noise.range_m + noise.range_per_m * z[0]
    sb = math.radians(noise.bearing_deg)
    return np.diag([sr * sr, sb * sb])


def innovation(z: np.ndarray, expected: np.ndarray) -> np.ndarray:
    return np.array([z[0] - expected[0], wrap_angle(z[1] - expected[1])])


def _inverse_2x2(s: np.ndarray) -> np.ndarray:
    """Inverse of a symmetric positive definite 2×2 matrix (the innovation covariance)."""
    det = s[0, 0] * s[1, 1] - s[0, 1] * s[1, 0]
    return np.array([[s[1, 1], -s[0, 1]], [-s[1, 0], s[0, 0]]]) / det


# -- the filter -----------------------------------------------------------------------------
class Ekf:
    """The joint Gaussian over robot pose and landmarks."""

    def __init__(self, pose: np.ndarray, noise: NoiseModel) -> None:
        self.x = np.array(pose, dtype=np.float64)
        self.cov = np.zeros((ROBOT, ROBOT))
        self.noise = noise

    @property
    def n_landmarks(self) -> int:
        return (len(self.x) - ROBOT) // LM

    def landmark(self, i: int) -> np.ndarray:
        j = ROBOT + LM * i
        return self.x[j:j + LM]

    def predict(self, u: np.ndarray, q: np.ndarray) -> None:
        """Motion update with the increment u (robot frame) and its covariance q."""
        f_x, f_u = motion_jacobians(self.x[:3], u)
        self.x[:3] = motion(self.x[:3], u)
        cov = self.cov
        cov[:3, :3] = f_x @ cov[:3, :3] @ f_x.T + f_u @ q @ f_u.T
        cov[:3, 3:] = f_x @ cov[:3, 3:]
        cov[3:, :3] = cov[:3, 3:].T

    def _blocks(self, i: int) -> tuple[np.ndarray, np.ndarray, list[int]]:
        pose, lm = self.x[:3], self.landmark(i)
        h_r, h_l = observe_jacobians(pose, lm)
        j = ROBOT + LM * i
        return h_r, h_l, [0, 1, 2, j, j + 1]

    def mahalanobis(self, i: int, z: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
        """(d², innovation, innovation covariance) of observation z against landmark i."""
        h_r, h_l, idx = self._blocks(i)
        h = np.hstack((h_r, h_l))
        sub = self.cov[np.ix_(idx, idx)]
        s = h @ sub @ h.T + measurement_noise(z, self.noise)
        nu = innovation(z, observe(self.x[:3], self.landmark(i)))
        return float(nu @ _inverse_2x2(s) @ nu), nu, s

    def update(self, i: int, z: np.ndarray) -> None:
        """Measurement update with observation z of landmark i."""
        h_r, h_l, idx = self._blocks(i)
        h = np.hstack((h_r, h_l))
        cov = self.cov
        w = cov[:, idx] @ h.T  # n×2 = P Hᵀ
        s = h @ w[idx] + measurement_noise(z, self.noise)
        s = 0.5 * (s + s.T)
        nu = innovation(z, observe(self.x[:3], self.landmark(i)))
        k = w @ _inverse_2x2(s)  # n×2 = P Hᵀ S⁻¹
        self.x += k @ nu
        self.x[2] = wrap_angle(self.x[2])
        cov -= k @ w.T
        self.cov = 0.5 * (cov + cov.T)

    def condition_on_robot(self) -> None:
        """The state given the robot's pose, its estimate taken as exact (a robocentric
        filter): the landmarks' covariance becomes their uncertainty relative to the robot,
        P_ll − P_lr P_rr⁺ P_rl, and the robot's is 0; the means stay. What is let go is how
        far the robot and everything it sees may have drifted together since the start:
        nothing a local filter can observe, and what makes its linearized updates
        inconsistent once the heading is uncertain by a few degrees."""
        cov = self.cov
        if len(self.x) > ROBOT:
            prl = cov[:3, 3:]
            lm = cov[3:, 3:] - prl.T @ np.linalg.pinv(cov[:3, :3]) @ prl
            cov[3:, 3:] = 0.5 * (lm + lm.T)
        cov[:3, :] = 0.0
        cov[:, :3] = 0.0

    def add_landmark(self, z: np.ndarray) -> int:
        """Augment the state with a landmark first seen as observation z; returns its index."""
        pose = self.x[:3]
        g_r, g_z = inverse_observe_jacobians(pose, z)
        n = len(self.x)
        cov = np.zeros((n + LM, n + LM))
        cov[:n, :n] = self.cov
        cross = g_r @ self.cov[:3, :]  # 2×n
        cov[n:, :n] = cross
        cov[:n, n:] = cross.T
        r = measurement_noise(z, self.noise)
        cov[n:, n:] = g_r @ self.cov[:3, :3] @ g_r.T + g_z @ r @ g_z.T
        self.cov = cov
        self.x = np.concatenate((self.x, inverse_observe(pose, z)))
        return self.n_landmarks - 1

    def remove_landmarks(self, indices: list[int]) -> None:
        """Marginalize landmarks out (drop their rows and columns)."""
        if not indices:
            return
        drop = {ROBOT + LM * i + k for i in indices for k in range(LM)}
        keep = np.array([j for j in range(len(self.x)) if j not in drop])
        self.x = self.x[keep]
        self.cov = self.cov[np.ix_(keep, keep)]
