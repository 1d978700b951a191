"""The check of a log's beam spacing: a converter's fov/(n-1) for a laser's fov/n is found
from the scans and mended; a log whose spacing is right is left alone."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from dynslam_cli.localization.beams import (
    check_spacing,
    converter_spacing,
)
from dynslam_cli.localization.ekf import NoiseModel
from dynslam_cli.localization.scanmatch import MatchConfig
from dynslam_cli.simulate import ray_cast
from dynslam_cli.types import Pose2D, Scan

from .test_loopclosure import ROOM


def test_only_an_even_count_over_whole_quarter_turns_looks_converted():
    spread = np.linspace(-math.pi / 2, math.pi / 2, 180)  # 180 beams over both ends
    assert converter_spacing(spread) == pytest.approx((math.pi / 179, math.pi / 180))
    assert converter_spacing(np.radians(np.arange(-90.0, 90.0, 1.0))) is None  # CARMEN's 180
    assert converter_spacing(np.radians(np.arange(-90.0, 90.5, 1.0))) is None  # a SICK's 181
    assert converter_spacing(np.linspace(-3 * math.pi / 4, 3 * math.pi / 4, 1080)) is not None
    uneven = spread.copy()
    uneven[7] += 1e-3
    assert converter_spacing(uneven) is None


def drive(step_deg: float, n: int = 180, scans: int = 160) -> list[Scan]:
    """A robot driving a loop in the test room, its laser's ``n`` beams ``step_deg`` apart
    from -90 deg; odometry true."""
    angles = np.radians(-90.0 + step_deg * np.arange(n))
    out = []
    for k in range(scans):
        a = 2 * math.pi * k / scans
        pose = Pose2D(1.0 + 2.0 * math.cos(a), 0.5 + 1.5 * math.sin(a), a + math.pi / 2)
        r, _ = ray_cast(pose, angles, ROOM, np.zeros(len(ROOM), int), np.zeros((0, 3)),
                        np.zeros(0, int), 20.0)
        out.append(Scan(0.1 * k, r, angles, 20.0, pose))
    return out


def test_a_converters_spacing_is_found_and_a_true_one_is_kept():
    """A SICK's 180 beams 1 deg apart, logged as 180/179 deg apart (a converter's): the scans
    fit 1 deg better in most scans. A laser whose 180 beams really are 180/179 deg apart
    (both ends of its fov) looks the same in the log, and its scans fit that better."""
    cfg, noise = MatchConfig(), NoiseModel()
    converted = [s.respaced(math.pi / 179) for s in drive(1.0)]
    check = check_spacing(converted, cfg, noise)
    assert check is not None and check.convincing
    assert math.degrees(check.own) == pytest.approx(1.0)
    true_spread = drive(180 / 179)
    check = check_spacing(true_spread, cfg, noise)
    assert check is not None and not check.convincing
    assert check.better < check.matched / 2


def test_the_intel_bag_is_read_at_its_lasers_own_spacing(datasets, cli, tmp_path):
    bag = datasets / "rosbag1" / "kummerle" / "intel.orig.bag"
    out = tmp_path / "out"
    r = cli("process", bag, "-o", out, "--max-scans", 250)
    assert r.exit_code == 0
    assert "beams read 1 deg apart, not the 1.0056 the log states" in r.output
    spacing = json.loads((out / "summary.json").read_text())["input"]["beam_spacing"]
    assert spacing["taken"] and spacing["own_deg"] == pytest.approx(1.0)
    r = cli("process", bag, "-o", tmp_path / "forced", "--max-scans", 250, "--beam-step", 1.0)
    assert "beams read" not in r.output
    assert json.loads((tmp_path / "forced" / "summary.json").read_text()
                      )["input"]["beam_spacing"] is None


def test_respaced_keeps_the_first_beam():
    scan = drive(1.0, scans=1)[0]
    moved = scan.respaced(math.radians(0.5))
    assert moved.angles[0] == scan.angles[0]
    assert math.degrees(moved.angles[-1] - moved.angles[0]) == pytest.approx(89.5)
    assert moved.ranges is scan.ranges and moved.odom == scan.odom
