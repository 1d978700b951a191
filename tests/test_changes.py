"""Change events (changes.csv): what a user is told changed, told as a story scan by scan,
and on a real log with people walking."""

from __future__ import annotations

import csv
import io
import json

import numpy as np
import pytest

from dynslam_cli.config import Config, load_config
from dynslam_cli.errors import ConfigError
from dynslam_cli.localization.cornerslam import EkfConfig
from dynslam_cli.mapping.changes import ChangeEvent
from dynslam_cli.pipeline import DynamicSlam
from dynslam_cli.types import Pose2D, Scan
from dynslam_formats.changes import HEADER, read_changes, write_changes

ANGLES = np.linspace(-0.3, 0.3, 61)  # 0.01 rad apart
RATE = 10.0  # scans a second


def _scan(t: float, box: bool = False, walker_at: float | None = None) -> Scan:
    """A still robot at the origin before a wall 6 m off; a 0.6 m box 3 m ahead; a walker
    (three beams wide) 4 m off at bearing ``walker_at``."""
    ranges = np.full(len(ANGLES), 6.0)
    if box:
        ranges[np.abs(ANGLES) <= 0.1] = 3.0
    if walker_at is not None:
        ranges[np.abs(ANGLES - walker_at) <= 0.011] = 4.0
    return Scan(stamp=t, ranges=ranges, angles=ANGLES, max_range=8.0, odom=Pose2D())


def _story() -> list[ChangeEvent]:
    slam = DynamicSlam(Config(ekf=EkfConfig(localization="odometry")))
    for k in range(400):
        t = k / RATE
        box = t < 5 or 15 <= t < 25  # stands, is taken away, is put back, is taken again
        walker = -0.25 + 0.5 * (t - 30) / 4 if 30 <= t < 34 else None  # 0.5 m/s across
        slam.step(_scan(t, box, walker))
    return slam.result().changes


def test_a_box_taken_away_put_back_and_a_walker_are_told_as_events():
    events = _story()
    assert [e.kind for e in events] == ["vacated", "appeared", "vacated", "moving"]
    first, back, gone, walker = events
    # The box stood on a place never seen empty, so it was static (Table 1): when it went,
    # S lost it; put back where S is Free, it appeared; taken again, its place was vacated.
    assert 5.0 <= first.first_s <= 5.5
    assert 15.0 <= back.first_s <= 15.2 and 24.8 <= back.last_s < 25.0
    assert 25.0 <= gone.first_s <= 25.3
    for e in (first, back, gone):
        assert abs(e.x - 3.0) <= 0.1 and abs(e.y) <= 0.1
        assert e.scans >= 1
    assert back.scans == 100  # seen in every scan of its ten seconds
    assert walker.first_s >= 30.0 and walker.last_s < 34.0
    assert [e.id for e in events] == [1, 2, 3, 4]


def test_a_walker_is_never_an_object_that_appeared():
    slam = DynamicSlam(Config(ekf=EkfConfig(localization="odometry")))
    for k in range(300):
        t = k / RATE
        slam.step(_scan(t, walker_at=-0.25 + 0.5 * (t % 4) / 4 if t >= 5 else None))
    kinds = [e.kind for e in slam.result().changes]
    assert kinds and set(kinds) == {"moving"}


@pytest.mark.parametrize(("stood_s", "appeared"), [(2.5, False), (3.5, True)])
def test_an_object_appeared_only_if_seen_standing_for_still_s(stood_s, appeared):
    """A thing seen still in every scan for less than ``still_s`` (3 s) is not an object
    that appeared (a slow walker's stretch, a cart pushed by), even inside a 3 s window
    that saw it more than half the time; seen standing 3.5 s, it is."""
    slam = DynamicSlam(Config(ekf=EkfConfig(localization="odometry")))
    for k in range(250):
        t = k / RATE
        slam.step(_scan(t, box=10.0 <= t < 10.0 + stood_s))
    kinds = [e.kind for e in slam.result().changes]
    assert ("appeared" in kinds) == appeared


@pytest.mark.parametrize("through_s", [5.2, 15.0])
def test_one_scan_that_sees_through_a_standing_box_neither_ends_it_nor_blinds_its_leaving(
        through_s):
    """One scan passes through a box that stands from 5 s to 25 s (placed wrong, or a
    glitch), while it arrives or while it stands: the box is seen again 0.1 s later, so it
    had not gone (no vacated then), and the face that scan cleared, seen standing since,
    is seen cleared again when the box is taken away at 25 s (vacated then)."""
    slam = DynamicSlam(Config(ekf=EkfConfig(localization="odometry")))
    for k in range(350):
        t = k / RATE
        slam.step(_scan(t, box=5.0 <= t < 25.0 and abs(t - through_s) > 0.01))
    events = slam.result().changes
    assert [e.kind for e in events] == ["appeared", "vacated"]
    assert 5.0 <= events[0].first_s <= 5.2 and 25.0 <= events[1].first_s <= 25.3


@pytest.mark.parametrize("face_y", [1.1, 1.125, 1.15, 1.175])
def test_a_box_by_a_wall_first_seen_at_a_grazing_incidence_is_vacated_when_it_goes(face_y):
    """A robot drives along a corridor past a 0.4 m box standing at its wall (seen first
    at a shallow incidence, where beams run along the face for cells before ending in it),
    then back after the box was taken away: the place is vacated wherever the face lies on
    the grid's rows (before, a face centred on a row was worn by those grazing beams into a
    "contested" one and no event came)."""
    from dynslam_cli.simulate import ray_cast

    angles = np.radians(np.arange(-90.0, 90.5, 1.0))
    walls = [(-2.0, 1.5, 14.0, 1.5), (-2.0, -1.5, 14.0, -1.5), (-2.0, -1.5, -2.0, 1.5),
             (14.0, -1.5, 14.0, 1.5)]
    box = [(4.0, face_y, 4.4, face_y), (4.0, face_y, 4.0, 1.5), (4.4, face_y, 4.4, 1.5)]
    rng = np.random.default_rng(0)
    slam = DynamicSlam(Config(ekf=EkfConfig(localization="odometry")))
    for k in range(400):
        t = k / RATE
        pose = Pose2D(0.5 * t, 0.0, 0.0) if t < 20 else Pose2D(10.0 - 0.5 * (t - 20), 0.0,
                                                                np.pi)
        segments = np.array(walls + (box if t < 20 else []))
        ranges, owner = ray_cast(pose, angles, segments, np.full(len(segments), -1),
                                 np.zeros((0, 3)), np.zeros(0, np.int64), 8.0)
        ranges = np.where(owner == -2, ranges, ranges + rng.normal(0.0, 0.01, len(angles)))
        slam.step(Scan(stamp=t, ranges=ranges, angles=angles, max_range=8.0, odom=pose))
    events = slam.result().changes
    assert [e.kind for e in events] == ["vacated"]
    assert 20.0 <= events[0].first_s <= 21.0
    assert abs(events[0].x - 4.2) <= 0.3 and abs(events[0].y - (face_y + 1.5) / 2) <= 0.3


def test_without_the_dynamic_map_there_are_no_events():
    config = load_config(overrides={"ekf": {"localization": "odometry"},
                                    "dynamic": {"enabled": False}})
    slam = DynamicSlam(config)
    for k in range(300):
        slam.step(_scan(k / RATE, box=k < 50))
    assert slam.result().changes == []


def test_changes_csv_round_trip():
    events = [ChangeEvent(1, "appeared", 10.0, 12.5, 1.25, -3.5, 0.36, 25, (4, 17)),
              ChangeEvent(2, "moving", 11.0, 13.0, 0.0, 0.125, 0.04, 20)]
    out = io.StringIO()
    write_changes(out, events)
    rows = list(csv.reader(io.StringIO(out.getvalue())))
    assert tuple(rows[0]) == HEADER
    assert rows[1][-1] == "4 17" and rows[2][-1] == ""
    assert read_changes(io.StringIO(out.getvalue())) == events


def test_change_thresholds_are_checked():
    with pytest.raises(ConfigError, match="changes"):
        load_config(overrides={"changes": {"min_scans": 0}})
    with pytest.raises(ConfigError, match="changes"):
        load_config(overrides={"changes": {"track_gate_m": -1.0}})
    with pytest.raises(ConfigError, match="walker_speed_m_s"):
        load_config(overrides={"changes": {"walker_speed_m_s": -2.0}})
    with pytest.raises(ConfigError, match="max_object_m2"):
        load_config(overrides={"changes": {"max_object_m2": 0.0}})


def test_people_walking_on_a_real_log_are_moving_tracks(datasets, tmp_path, cli):
    """leg_tracker's bag: people walking past a laser; they are tracks, and no wall
    'appeared'."""
    out = tmp_path / "out"
    result = cli("process", datasets / "rosbag1" / "people-walking-rear.bag", "-o", out, "-q")
    assert result.exit_code == 0, result.output
    with open(out / "changes.csv", encoding="utf-8") as f:
        events = read_changes(f)
    kinds = [e.kind for e in events]
    assert 2 <= kinds.count("moving") <= 4 and "appeared" not in kinds  # three people
    summary = json.loads((out / "summary.json").read_text())
    assert summary["changes"]["counts"]["moving"] == kinds.count("moving")
    assert len(summary["changes"]["events"]) == len(events)


def test_a_walker_hidden_a_moment_or_seen_as_two_legs_is_one_track():
    """Moving tracks join where they are one mover's: a walker hidden for 1.5 s who walks
    on, a walker whose legs were two tracks for a while; a second walker 4 m away, or one
    appearing 5 m from where the first vanished a second before, stays another."""
    from dynslam_cli.mapping.changes import BLOB_FIELDS, CX, CY, ChangeConfig, _one_per_mover

    def track(t0: float, t1: float, x0: float, y: float, speed: float = 1.0):
        t = np.arange(t0, t1, 0.1)
        b = np.zeros((len(t), BLOB_FIELDS))
        b[:, CX], b[:, CY] = x0 + speed * (t - t0), y
        return t, b

    walker = [track(0.0, 3.0, 0.0, 0.0), track(4.5, 7.0, 4.5, 0.0),  # hidden 1.5 s
              track(1.0, 2.0, 1.2, 0.2)]  # a leg tracked apart for a second
    others = [track(0.0, 5.0, 0.0, 4.0), track(8.0, 9.0, 12.0, 0.0)]
    joined = _one_per_mover(walker + others, ChangeConfig())
    assert sorted(len(t) for t, _ in joined) == sorted([30 + 25 + 10, 50, 10])
    t, b = max(joined, key=lambda tb: len(tb[0]))
    assert np.all(np.diff(t) >= 0) and t[0] == 0.0 and b[-1, CX] > 6.0


def test_compacting_the_evidence_changes_no_event(monkeypatch):
    """Memory follows the cells, not the log's length: letting go of what can no longer
    make an event, however often, gives the same events."""
    from dynslam_cli.mapping import changes

    whole = _story()
    monkeypatch.setattr(changes, "COMPACT_AT", 50)
    assert _story() == whole


def test_a_log_where_nothing_changes_has_no_events():
    slam = DynamicSlam(Config(ekf=EkfConfig(localization="odometry")))
    for k in range(100):
        slam.step(_scan(k / RATE))
    assert slam.result().changes == []


def test_an_objects_two_faces_are_one_blob_and_a_far_one_another():
    """A scan's sightings: two faces of one box with a beam between them that ended
    elsewhere are one object; a thing a metre away is a second one."""
    from dynslam_cli.mapping import _changes
    row = [(0.025, 0.025), (0.075, 0.025)]  # cell centres (0.05 m cells), in beam order:
    other = [(0.125, 0.025), (0.175, 0.025)]  # a face, a beam 0.15 m off, a face
    centres = np.array([*row, (0.175, 0.175), *other])
    blobs = _changes.scan_blobs(centres, 0.12, 7.0)
    assert blobs[:, 0].tolist() == [7.0, 7.0] and blobs[:, 7].tolist() == [4, 1]
    assert blobs[0, 1:].tolist() == pytest.approx([0.1, 0.025, 0.025, 0.025, 0.175, 0.025, 4])
    far = _changes.scan_blobs(np.array([(0.5, 0.5), (1.5, 0.5)]), 0.5, 0.0)  # 1 m apart
    assert far.shape == (2, 8)
    assert far[:, 1:3].tolist() == [[0.5, 0.5], [1.5, 0.5]]  # their centroids, x then y

def test_tracks_take_the_nearest_blob_and_end_when_unseen():
    """Two walkers side by side stay two tracks (each blob continues the nearer one); a
    track unseen for longer than the gap ends, and a blob there later starts another."""
    from dynslam_cli.mapping import _changes

    def blob(scan: int, x: float, y: float) -> list[float]:
        return [scan, x, y, x, y, x, y, 1]
    blobs = np.array([blob(0, 0.0, 0.0), blob(0, 0.4, 0.0),
                      blob(1, 0.45, 0.1), blob(1, 0.05, 0.1),  # (listed in the other order)
                      blob(5, 0.05, 0.2)])
    stamps = np.array([0.0, 0.1, 0.2, 0.3, 0.4, 2.0])
    track = _changes.link_tracks(blobs, stamps, 0.5, 1.0)
    assert track.tolist() == [0, 1, 1, 0, 2]


def test_a_movers_path_is_smoothed_in_time_order_even_where_stamps_step_back():
    """A log's stamps may step back (the raw Intel log's do): a moving track is put in time
    order as it is collected (as two joined tracks are), and its drawn way is finite,
    averaged over a second, one per 0.1 m."""
    from dynslam_cli.mapping.changes import BLOB_FIELDS, CX, PATH_STEP_M, _merged, _path

    t = np.array([0.0, 0.1, 0.2, 0.15, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0])
    blobs = np.zeros((len(t), BLOB_FIELDS))
    blobs[:, CX] = 0.5 * t + np.where(np.arange(len(t)) % 2, 0.05, -0.05)  # legs swing ±5 cm
    t, blobs = _merged([(t, blobs)])
    assert np.all(np.diff(t) >= 0)
    path = np.array(_path(t, blobs[:, CX:CX + 2]))
    assert np.isfinite(path).all() and len(path) >= 2
    assert np.all(np.diff(path[:, 0]) > 0)  # it walks on: no swing left
    assert np.all(np.diff(path[:-1, 0]) >= PATH_STEP_M * 0.9)
