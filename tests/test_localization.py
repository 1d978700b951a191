"""EKF-SLAM pieces (paper Sec. 4): models and Jacobians, association, corners, Table 3."""

from __future__ import annotations

import math

import numpy as np
import pytest

from dynslam_cli.localization.corners import CornerConfig, detect_corners
from dynslam_cli.localization.cornerslam import CornerSlam, EkfConfig
from dynslam_cli.localization.ekf import (
    Ekf,
    NoiseModel,
    inverse_observe,
    inverse_observe_jacobians,
    motion,
    motion_jacobians,
    motion_noise,
    observe,
    observe_jacobians,
)
from dynslam_cli.mapping.dynamic import FREE, OCCUPIED, TABLE_3, UNKNOWN
from dynslam_cli.simulate import Box, ray_cast
from dynslam_cli.types import Pose2D


def numeric_jacobian(f, x: np.ndarray, eps: float = 1e-6) -> np.ndarray:
    cols = []
    for k in range(len(x)):
        d = np.zeros(len(x))
        d[k] = eps
        diff = f(x + d) - f(x - d)
        if len(diff) > 1 and diff.shape[0] in (2, 3):
            diff[-1 if len(diff) == 3 else 1] = math.remainder(
                diff[-1 if len(diff) == 3 else 1], 2 * math.pi)
        cols.append(diff / (2 * eps))
    return np.column_stack(cols)


POSE = np.array([1.0, -2.0, 0.7])
U = np.array([0.3, 0.05, -0.2])
LM = np.array([4.0, 1.5])


def test_motion_jacobians_match_numerical():
    f_x, f_u = motion_jacobians(POSE, U)
    np.testing.assert_allclose(f_x, numeric_jacobian(lambda p: motion(p, U), POSE), atol=1e-6)
    np.testing.assert_allclose(f_u, numeric_jacobian(lambda u: motion(POSE, u), U), atol=1e-6)


def test_measurement_jacobians_match_numerical():
    h_r, h_l = observe_jacobians(POSE, LM)
    np.testing.assert_allclose(h_r, numeric_jacobian(lambda p: observe(p, LM), POSE), atol=1e-6)
    np.testing.assert_allclose(h_l, numeric_jacobian(lambda m: observe(POSE, m), LM), atol=1e-6)
    z = observe(POSE, LM)
    np.testing.assert_allclose(inverse_observe(POSE, z), LM, atol=1e-12)
    g_r, g_z = inverse_observe_jacobians(POSE, z)
    np.testing.assert_allclose(g_r, numeric_jacobian(lambda p: inverse_observe(p, z), POSE),
                               atol=1e-6)
    np.testing.assert_allclose(g_z, numeric_jacobian(lambda q: inverse_observe(POSE, q), z),
                               atol=1e-6)


def test_update_pulls_pose_and_keeps_covariance_symmetric_positive():
    ekf = Ekf(np.zeros(3), NoiseModel())
    i = ekf.add_landmark(np.array([3.0, 0.0]))
    for _ in range(20):
        u = np.array([0.1, 0.0, 0.0])
        ekf.predict(u, motion_noise(u, NoiseModel()) * 25.0)  # poor odometry
    # odometry says x = 2.0; the landmark at 3 m is seen at 0.8 m: the robot is at 2.2
    for _ in range(5):
        ekf.update(i, np.array([0.8, 0.0]))
    assert ekf.x[0] == pytest.approx(2.2, abs=0.05)
    np.testing.assert_allclose(ekf.cov, ekf.cov.T)
    assert np.linalg.eigvalsh(ekf.cov).min() > -1e-12


def _slam_with_landmark(convex: bool) -> CornerSlam:
    slam = CornerSlam(Pose2D(), EkfConfig())
    slam.ekf.add_landmark(np.array([2.0, 0.0]))
    from dynslam_cli.localization.cornerslam import LandmarkTrack

    slam.tracks.append(LandmarkTrack(0, convex))
    return slam


def test_association_nearest_within_gate_and_same_kind():
    slam = _slam_with_landmark(convex=True)
    obs = [(np.array([2.02, 0.01]), True)]
    pairs, _ = slam.associate(obs)
    assert [i for i, _ in pairs] == [0]
    pairs, not_new = slam.associate([(np.array([2.02, 0.01]), False)])  # concave: no
    assert pairs == [] and not_new == {0}  # near a landmark: ambiguous, not a new one
    pairs, _ = slam.associate([(np.array([2.0, 0.6]), True)])  # far outside gate
    assert pairs == []


def test_association_uses_each_landmark_once():
    slam = _slam_with_landmark(convex=False)
    obs = [(np.array([2.05, 0.0]), False), (np.array([2.0, 0.0]), False)]
    pairs, _ = slam.associate(obs)
    assert len(pairs) == 1 and pairs[0][1][0] == pytest.approx(2.0)


@pytest.mark.parametrize(("state", "cls"), [(FREE, "dynamic"), (UNKNOWN, "dynamic"),
                                            (OCCUPIED, "static")])
def test_table_3(state, cls):
    assert TABLE_3[state] == cls
    slam = _slam_with_landmark(convex=True)
    slam.classify([0], [TABLE_3[state]])
    assert slam.tracks[0].cls == cls
    before = slam.ekf.x.copy()
    slam.ekf.predict(np.zeros(3), motion_noise(np.zeros(3), NoiseModel()) * 100.0)
    slam.correct([(0, np.array([1.9, 0.0]))])
    moved = not np.allclose(slam.ekf.x[:3], before[:3])
    assert moved == (cls == "static")  # only static landmarks correct the pose


# -- corner detection -----------------------------------------------------------------------
ANGLES = np.radians(np.arange(-90, 90.25, 0.5))


def cast(segments: np.ndarray) -> np.ndarray:
    r, _ = ray_cast(Pose2D(), ANGLES, segments, np.zeros(len(segments), int),
                    np.zeros((0, 3)), np.zeros(0, int), 8.0)
    return r


def test_concave_room_corner_found():
    (c,) = detect_corners(cast(np.array([[3, -5, 3, 2], [3, 2, -5, 2]], float)), ANGLES, 8.0,
                          CornerConfig())
    assert (c.x, c.y, c.convex) == (pytest.approx(3.0, abs=0.02), pytest.approx(2.0, abs=0.02),
                                    False)


def test_convex_box_corner_found():
    (c,) = detect_corners(cast(Box("b", 0.5, 0.5, [(3.0, 1.5)]).segments()), ANGLES, 8.0,
                          CornerConfig())
    assert (c.x, c.y, c.convex) == (pytest.approx(2.5, abs=0.02), pytest.approx(1.0, abs=0.02),
                                    True)


def test_no_corner_on_a_smooth_wall_or_an_occlusion_edge():
    wall = np.array([[4, -6, 4, 6]], float)
    assert detect_corners(cast(wall), ANGLES, 8.0, CornerConfig()) == []
    # a short wall in front of a long one: two edges where one hides the other
    occluder = np.array([[4, -6, 4, 6], [2, 0.5, 2, 3]], float)
    assert detect_corners(cast(occluder), ANGLES, 8.0, CornerConfig()) == []


def test_no_corner_beyond_the_usable_range():
    far = np.array([[7.5, -9, 7.5, 6], [7.5, 6, -9, 6]], float)
    assert detect_corners(cast(far), ANGLES, 8.0, CornerConfig()) == []


def test_kept_scans_come_back_as_they_went_in_in_two_bytes_a_reading_when_they_can():
    """The scans kept for the final rebuild: readings written to the mm (or the cm, past
    65 m) take 2 bytes, any others 4 (float32, as the rebuild reads them); every reading,
    no-returns and invalid ones included, comes back as the float32 it was."""
    from dynslam_cli.scanstore import ScanStore
    from dynslam_cli.types import Scan

    rng = np.random.default_rng(3)
    angles = np.linspace(-1.5, 1.5, 181)
    mm = np.round(rng.uniform(0.1, 8.0, 181), 3)
    mm[[4, 9]] = [np.inf, np.nan]
    cm = np.round(rng.uniform(0.1, 81.91, 181), 2)  # (beyond 65.5 m in mm)
    raw = rng.uniform(0.1, 8.0, 181)  # a float32 bag's readings
    store = ScanStore()
    for k, ranges in enumerate((mm, cm, raw)):
        store.add(Scan(float(k), ranges, angles, 80.0, Pose2D(), Pose2D(0.1, 0.0, 0.0)))
    kept = list(store.scans())
    assert len(store._codes) == 2 * 181 and len(store._floats) == 181
    for scan, ranges in zip(kept, (mm, cm, raw), strict=True):
        assert np.array_equal(scan.ranges, ranges.astype(np.float32).astype(np.float64),
                              equal_nan=True)
        assert scan.angles is angles and scan.laser == Pose2D(0.1, 0.0, 0.0)


def test_a_corner_confirmed_twice_is_one_row_of_the_landmark_map():
    """A landmark the EKF let go of and confirmed anew is the same corner: one row, fused by
    information, the first id, the sightings summed; another kind at the same place, or the
    same kind half a metre away, stays apart."""
    from dynslam_cli.localization.cornerslam import one_per_corner

    cov = np.diag([0.02 ** 2, 0.02 ** 2])
    xy = np.array([[1.0, 2.0], [1.03, 2.0], [1.0, 2.0], [1.5, 2.0]])
    rows = one_per_corner([(7, True, 5), (3, True, 10), (4, False, 6), (9, True, 2)], xy,
                          np.array([cov, cov / 4, cov, cov]), 9.21)
    assert [(i, convex, seen) for i, convex, seen, _, _, _ in rows] == [
        (3, True, 15), (4, False, 6), (9, True, 2)]
    _, _, _, x, y, fused = rows[0]
    assert x == pytest.approx(1.03 - 0.03 / 5) and y == pytest.approx(2.0)
    assert fused[0, 0] == pytest.approx(0.02 ** 2 / 5)


def test_two_sure_corners_closer_than_a_map_cell_are_one_row():
    """The end of a partition one cell thick has two corners, each seen so often that
    their covariances keep them apart; the map draws one: closer than ``resolve_m`` they
    are one row (another kind, or a cell and more away, stay apart)."""
    from dynslam_cli.localization.cornerslam import one_per_corner

    cov = np.diag([0.005 ** 2, 0.005 ** 2])
    xy = np.array([[1.0, 2.0], [1.0, 2.048], [1.0, 2.048], [1.0, 2.11]])
    landmarks = [(1, True, 40), (2, True, 30), (3, False, 20), (4, True, 25)]
    apart = one_per_corner(landmarks, xy, np.array([cov] * 4), 9.21)
    assert [i for i, *_ in apart] == [1, 2, 3, 4]
    rows = one_per_corner(landmarks, xy, np.array([cov] * 4), 9.21, resolve_m=0.05)
    assert [(i, seen) for i, _, seen, *_ in rows] == [(1, 70), (3, 20), (4, 25)]
    assert rows[0][4] == pytest.approx(2.024)


def test_two_landmarks_fused_into_reach_of_a_corner_are_one_row_with_it():
    """Two landmarks each a little more than a cell from a corner, and within a cell of each
    other: fused, they lie within a cell of it, and the landmark map has one row, not two
    (freiburg-079 had rows 0 and 72 of one corner 4.9 cm apart)."""
    from dynslam_cli.localization.cornerslam import one_per_corner

    cov = np.diag([1e-4 ** 2, 1e-4 ** 2])  # (so sure that only the cell joins them)
    xy = np.array([[0.0, 0.0], [0.045, 0.0245], [0.045, -0.0245]])
    rows = one_per_corner([(0, True, 9), (1, True, 5), (2, True, 5)], xy,
                          np.array([cov] * 3), 9.21, resolve_m=0.05)
    assert [(i, seen) for i, _, seen, *_ in rows] == [(0, 19)]
    assert rows[0][3] == pytest.approx(0.03, abs=1e-6)


def test_conditioning_on_the_robot_keeps_the_landmarks_relative_uncertainty():
    """Ekf.condition_on_robot: the means stay, the robot's covariance is 0, a landmark's is
    its covariance given the robot's pose (the inverse of its block of the information
    matrix), so drift shared by the robot and the landmark is let go."""
    rng = np.random.default_rng(3)
    ekf = Ekf(np.array([5.0, -2.0, 0.7]), NoiseModel())
    ekf.cov = np.diag([4.0, 9.0, math.radians(8.0) ** 2])  # drifted far since the start
    ekf.add_landmark(np.array([3.0, 0.4]))
    ekf.add_landmark(np.array([6.0, -0.9]))
    ekf.predict(np.array([0.3, 0.0, 0.05]), np.diag(rng.uniform(1e-4, 1e-3, 3)))
    x, cov = ekf.x.copy(), ekf.cov.copy()
    ekf.condition_on_robot()
    assert np.array_equal(ekf.x, x)
    assert not ekf.cov[:3].any() and not ekf.cov[:, :3].any()
    given_robot = np.linalg.inv(np.linalg.inv(cov)[3:, 3:])
    assert np.allclose(ekf.cov[3:, 3:], given_robot, rtol=1e-6, atol=1e-12)
    assert np.trace(ekf.cov[3:, 3:]) < 0.01 * np.trace(cov[3:, 3:])  # the drift is gone


def test_robocentric_filter_sees_a_corner_as_surely_after_a_long_drive():
    """With ``robocentric`` the robot's covariance is 0 after each step, and a corner
    first seen after 100 m of uncertain driving is as sure as one seen at the start (its
    uncertainty relative to the robot); without, it carries all of the drift."""
    def corner_cov(robocentric: bool, metres: float) -> np.ndarray:
        slam = CornerSlam(Pose2D(), EkfConfig(robocentric=robocentric, confirm_observations=1))
        step, cov = Pose2D(0.5, 0.0, 0.0), np.diag([0.02 ** 2, 0.02 ** 2, 1e-4])
        for k in range(int(metres / 0.5)):
            slam.step(k + 1, step, cov, True, [], lambda xy: ["static"] * len(xy))
        for k in (10_000, 10_001):  # seen twice while standing: confirmed
            slam.step(k, Pose2D(), cov, True, [(np.array([3.0, 0.5]), True)],
                      lambda xy: ["static"] * len(xy))
        if robocentric:
            assert not slam.ekf.cov[:3, :3].any()
        return slam.ekf.cov[3:5, 3:5]

    near, far = corner_cov(True, 0.5), corner_cov(True, 100.0)
    assert np.allclose(near, far, rtol=1e-9, atol=1e-15)
    assert np.trace(corner_cov(False, 100.0)) > 100 * np.trace(near)
