"""SE(2) helpers: angle wrapping, composition, inversion, interpolation, key poses; points and
segments."""

from __future__ import annotations

import math

import numpy as np

from dynslam_cli.types import Pose2D


def wrap_angle(a: float) -> float:
    """Wrap an angle to [-pi, pi)."""
    return (a + math.pi) % (2.0 * math.pi) - math.pi


def wrap_angles(a: np.ndarray) -> np.ndarray:
    """Vectorized :func:`wrap_angle`."""
    return (a + np.pi) % (2.0 * np.pi) - np.pi


def compose(a: Pose2D, b: Pose2D) -> Pose2D:
    """a ⊕ b: pose b (given in the frame of a) expressed in a's parent frame."""
    c, s = math.cos(a.theta), math.sin(a.theta)
    return Pose2D(a.x + c * b.x - s * b.y, a.y + s * b.x + c * b.y, wrap_angle(a.theta + b.theta))


def inverse(a: Pose2D) -> Pose2D:
    """⊖a, so that compose(a, inverse(a)) is the identity."""
    c, s = math.cos(a.theta), math.sin(a.theta)
    return Pose2D(-c * a.x - s * a.y, s * a.x - c * a.y, wrap_angle(-a.theta))


def relative(a: Pose2D, b: Pose2D) -> Pose2D:
    """⊖a ⊕ b: pose b expressed in the frame of pose a."""
    return compose(inverse(a), b)


def compound_covariance(a: Pose2D, cov_a: np.ndarray, b: Pose2D, cov_b: np.ndarray
                        ) -> np.ndarray:
    """Covariance (x, y, θ) of a ⊕ b from those of a and of b (independent), to first order:
    J_a Σ_a J_aᵀ + J_b Σ_b J_bᵀ with the Jacobians of the composition."""
    c, s = math.cos(a.theta), math.sin(a.theta)
    ja = np.array([[1.0, 0.0, -s * b.x - c * b.y], [0.0, 1.0, c * b.x - s * b.y],
                   [0.0, 0.0, 1.0]])
    jb = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return ja @ cov_a @ ja.T + jb @ cov_b @ jb.T


def rotated_covariance(cov: np.ndarray, theta: float) -> np.ndarray:
    """A pose covariance (x, y, θ) seen in a frame turned by −``theta`` from its own (its
    x, y turned by ``theta``): R Σ Rᵀ."""
    c, s = math.cos(theta), math.sin(theta)
    r = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return r @ cov @ r.T


def moved_far(a: Pose2D, b: Pose2D, distance_m: float, angle_rad: float) -> bool:
    """Whether pose b lies at least ``distance_m`` from pose a or is turned at least
    ``angle_rad`` from it: the rule by which a new key scan, graph node or path pose is
    taken."""
    d = relative(a, b)
    return math.hypot(d.x, d.y) >= distance_m or abs(d.theta) >= angle_rad


def interpolate(a: Pose2D, b: Pose2D, f: float) -> Pose2D:
    """Pose a fraction f of the way from a to b (heading along the shorter arc)."""
    dth = wrap_angle(b.theta - a.theta)
    return Pose2D(a.x + f * (b.x - a.x), a.y + f * (b.y - a.y), wrap_angle(a.theta + f * dth))


def transform_points(pose: Pose2D, points: np.ndarray) -> np.ndarray:
    """Points (N×2) given in the frame of ``pose``, expressed in its parent frame."""
    c, s = math.cos(pose.theta), math.sin(pose.theta)
    return np.column_stack((pose.x + c * points[:, 0] - s * points[:, 1],
                            pose.y + s * points[:, 0] + c * points[:, 1]))


def distance_to_segments(points: np.ndarray, segs: np.ndarray, chunk: int = 4096) -> np.ndarray:
    """Distance of each point (N×2) to the nearest segment (K×4), in chunks."""
    if len(segs) == 0:
        return np.full(len(points), np.inf)
    a, ab = segs[:, :2], segs[:, 2:] - segs[:, :2]
    ab2 = np.maximum((ab ** 2).sum(1), 1e-18)
    out = np.empty(len(points))
    for s in range(0, len(points), chunk):
        p = points[s:s + chunk, None, :]
        t = np.clip(((p - a) * ab).sum(-1) / ab2, 0.0, 1.0)
        d = p - (a + t[..., None] * ab)
        out[s:s + chunk] = np.sqrt((d ** 2).sum(-1)).min(1)
    return out


def segment_crosses(s: np.ndarray, walls: np.ndarray) -> bool:
    """Whether segment ``s`` (x1 y1 x2 y2) crosses any of ``walls`` (K×4) strictly inside it."""
    p, r = s[:2], s[2:] - s[:2]
    q, e = walls[:, :2], walls[:, 2:] - walls[:, :2]
    den = r[0] * e[:, 1] - r[1] * e[:, 0]
    w = q - p
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (w[:, 0] * e[:, 1] - w[:, 1] * e[:, 0]) / den
        u = (w[:, 0] * r[1] - w[:, 1] * r[0]) / den
    return bool(np.any((np.abs(den) > 1e-12) & (t > 0) & (t < 1) & (u >= 0) & (u <= 1)))
