"""A second session on a prior map: `dynslam process LOG --prior DIR`."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import pytest

from dynslam_cli.geometry import compose
from dynslam_cli.simulate import Box, LaserModel, OdometryNoise, World, simulate
from dynslam_cli.types import Pose2D
from dynslam_formats.changes import read_changes
from dynslam_formats.mapfile import read_map
from dynslam_formats.simlogs import write_carmen
from dynslam_formats.tum import read_tum

# A room with an alcove and a pillar: nothing symmetric, so a scan has one place in it.
ROOM = np.array([[-4, -3, 6, -3], [6, -3, 6, 4], [6, 4, 1, 4], [1, 4, 1, 5.5],
                 [1, 5.5, -1, 5.5], [-1, 5.5, -1, 4], [-1, 4, -4, 4], [-4, 4, -4, -3],
                 [2, 0, 2.6, 0], [2.6, 0, 2.6, 0.4], [2.6, 0.4, 2, 0.4], [2, 0.4, 2, 0]],
                float)
ROUTE = [(-2.5, -1.8), (4.5, -1.8), (4.5, 2.5), (-2.5, 2.5)]
# A square room with a pillar in each corner: four places look alike.
SQUARE = np.array([[0, 0, 8, 0], [8, 0, 8, 8], [8, 8, 0, 8], [0, 8, 0, 0],
                   [2, 2, 2.4, 2], [6, 2, 6, 2.4], [6, 6, 5.6, 6], [2, 6, 2, 5.6]], float)
# A 30 m corridor, 2 m wide, with one alcove (2 m × 2 m) at 21-23 m: a scan of its plain
# stretch fits anywhere along it.
CORRIDOR = np.array([[0, -1, 30, -1], [0, 1, 21, 1], [21, 1, 21, 3], [21, 3, 23, 3],
                     [23, 3, 23, 1], [23, 1, 30, 1], [0, -1, 0, 1], [30, -1, 30, 1]], float)
# Today's log's odometry starts in a frame of its own: 20 m and 135 degrees from the map's.
ELSEWHERE = Pose2D(20.0, -7.0, math.radians(135.0))
IDENTITY = Pose2D()


def session(folder: Path, walls: np.ndarray, route: list, start: Pose2D,
            odometry_frame: Pose2D = IDENTITY, seconds: float = 40.0,
            boxes: tuple[Box, ...] = (), noise: float = 0.0) -> tuple[Path, list]:
    """A simulated log of a drive round ``route`` from ``start``, its odometry in a frame of
    its own (each odometry pose q logged as odometry_frame ∘ q), exact or drifting
    (``noise`` times the simulator's default), and the true poses."""
    world = World("room", walls, route, start, boxes=list(boxes), speed=0.5)
    steps, truth = simulate(world, seconds, 10.0, 0, noise=OdometryNoise().scaled(noise))
    moved = [dataclasses.replace(s, odom=compose(odometry_frame, s.odom)) for s in steps]
    folder.mkdir(parents=True, exist_ok=True)
    log = folder / "room.log"
    with open(log, "w") as f:
        write_carmen(f, moved, LaserModel(), "flaser", "room")
    return log, truth.poses


@pytest.fixture(scope="module")
def yesterday(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The first session's output folder: the room mapped from its own start pose."""
    from click.testing import CliRunner

    from dynslam_cli.cli import main

    root = tmp_path_factory.mktemp("prior")
    log, _ = session(root / "log1", ROOM, ROUTE, Pose2D(-2.5, -1.8, 0.0))
    out = root / "yesterday"
    result = CliRunner().invoke(main, ["process", str(log), "-o", str(out), "-q"])
    assert result.exit_code == 0, result.output
    return out


def test_a_second_session_is_placed_in_the_prior_map_and_its_frame(tmp_path: Path, cli,
                                                                   yesterday: Path) -> None:
    # today the robot starts across the room, its odometry in another frame altogether
    log, truth = session(tmp_path, ROOM, ROUTE[2:] + ROUTE[:2], Pose2D(4.5, 2.5, math.pi),
                         odometry_frame=ELSEWHERE)
    out = tmp_path / "today"
    result = cli("process", log, "--prior", yesterday, "-o", out, "-q")
    assert result.exit_code == 0, result.output
    report = json.loads((out / "summary.json").read_text())["localization"]["prior"]
    assert report["searched"] == "whole map" and report["score"] > 0.8
    x, y, deg = report["start"]  # (its first scan sees little along x: 3.5 cm off alone)
    assert math.hypot(x - 4.5, y - 2.5) < 0.02 and abs(math.remainder(deg - 180.0, 360.0)) < 0.5
    # every pose in the prior's frame (= the truth's), with no alignment
    poses = read_tum(out / "trajectory.tum")
    error = np.hypot(poses[:, 1] - [p[1] for p in truth], poses[:, 2] - [p[2] for p in truth])
    assert error.max() < 0.05
    # the maps lie on the same lattice: the walls overlay cell for cell
    a, b = read_map(yesterday / "static.yaml").grid, read_map(out / "static.yaml").grid
    for origin in ((a.origin_x, b.origin_x), (a.origin_y, b.origin_y)):
        assert abs((origin[0] - origin[1]) / a.resolution % 1.0 - 0.0) < 1e-6 or \
            abs((origin[0] - origin[1]) / a.resolution % 1.0 - 1.0) < 1e-6


def test_a_second_session_on_drifting_odometry_stays_in_the_prior_frame(tmp_path: Path, cli
                                                                        ) -> None:
    log1, _ = session(tmp_path / "a", ROOM, ROUTE, Pose2D(-2.5, -1.8, 0.0), seconds=60.0)
    cli("process", log1, "-o", tmp_path / "first", "-q", "--localization", "odometry")
    log2, truth = session(tmp_path / "b", ROOM, ROUTE[2:] + ROUTE[:2], Pose2D(4.5, 2.5, math.pi),
                          odometry_frame=ELSEWHERE, seconds=150.0, noise=3.0)
    result = cli("process", log2, "--prior", tmp_path / "first", "-o", tmp_path / "o", "-q")
    assert result.exit_code == 0, result.output
    poses = read_tum(tmp_path / "o" / "trajectory.tum")
    error = np.hypot(poses[:, 1] - [p[1] for p in truth], poses[:, 2] - [p[2] for p in truth])
    assert math.sqrt(np.mean(error ** 2)) < 0.01  # no alignment: in the prior's frame
    localization = json.loads((tmp_path / "o" / "summary.json").read_text())["localization"]
    assert localization["prior_matches"] > 0


def test_a_place_that_looks_like_another_needs_an_initial_pose(tmp_path: Path, cli) -> None:
    route = [(1.2, 1.2), (6.8, 1.2), (6.8, 6.8), (1.2, 6.8)]
    log1, _ = session(tmp_path / "a", SQUARE, route, Pose2D(1.2, 4.0, -math.pi / 2))
    cli("process", log1, "-o", tmp_path / "first", "-q")
    log2, _ = session(tmp_path / "b", SQUARE, route[1:] + route[:1],
                      Pose2D(6.8, 1.2, math.pi / 2), odometry_frame=ELSEWHERE, seconds=10.0)
    result = cli("process", log2, "--prior", tmp_path / "first", "-o", tmp_path / "x", "-q")
    assert result.exit_code == 1
    assert "more than one place" in result.output and "--initial-pose" in result.output
    assert len(result.output.strip().splitlines()) == 1
    assert not (tmp_path / "x").exists()
    result = cli("process", log2, "--prior", tmp_path / "first", "-o", tmp_path / "y", "-q",
                 "--initial-pose", "6.5,1.5,80")
    assert result.exit_code == 0, result.output
    x, y, _ = json.loads((tmp_path / "y" / "summary.json").read_text()
                         )["localization"]["prior"]["start"]
    assert math.hypot(x - 6.8, y - 1.2) < 0.05


def test_a_first_scan_that_fits_anywhere_is_placed_with_the_scans_after_it(
        tmp_path: Path, cli) -> None:
    log1, _ = session(tmp_path / "a", CORRIDOR, [(1.5, 0.0), (28.5, 0.0)], Pose2D(1.5, 0.0, 0.0),
                      seconds=120.0)  # mapped with its exact odometry: the map is right
    cli("process", log1, "-o", tmp_path / "first", "-q", "--localization", "odometry")
    # today's log starts on the plain stretch, 10 m from the alcove, and drives towards it
    log2, _ = session(tmp_path / "b", CORRIDOR, [(26.0, 0.0), (2.0, 0.0)], Pose2D(11.0, 0.0, 0.0),
                      odometry_frame=ELSEWHERE, seconds=30.0)
    result = cli("process", log2, "--prior", tmp_path / "first", "-o", tmp_path / "o", "-q")
    assert result.exit_code == 0, result.output
    report = json.loads((tmp_path / "o" / "summary.json").read_text())["localization"]["prior"]
    assert 1.0 < report["driven_m"] <= 12.0
    x, y, deg = report["start"]
    assert math.hypot(x - 11.0, y) < 0.1 and abs(math.remainder(deg, 360.0)) < 1.0
    # the same log on standard input is placed the same way, from the same scans
    result = cli("process", "-", "--prior", tmp_path / "first", "-o", tmp_path / "piped", "-q",
                 input=log2.read_bytes())
    assert result.exit_code == 0, result.output
    piped = json.loads((tmp_path / "piped" / "summary.json").read_text())["localization"]
    assert piped["prior"]["start"] == report["start"]
    assert (tmp_path / "piped" / "trajectory.tum").read_bytes() == (
        tmp_path / "o" / "trajectory.tum").read_bytes()


def test_an_initial_pose_far_off_is_corrected_by_the_whole_map(tmp_path: Path, cli,
                                                               yesterday: Path) -> None:
    log, _ = session(tmp_path, ROOM, ROUTE[2:] + ROUTE[:2], Pose2D(4.5, 2.5, math.pi),
                     odometry_frame=ELSEWHERE, seconds=10.0)
    result = cli("process", log, "--prior", yesterday, "-o", tmp_path / "o", "-q",
                 "--initial-pose", "-2,0,90")  # 7 m and 90 degrees off
    assert result.exit_code == 0, result.output
    report = json.loads((tmp_path / "o" / "summary.json").read_text())["localization"]["prior"]
    assert "whole map" in report["searched"] and "warning" in report
    x, y, _ = report["start"]
    assert math.hypot(x - 4.5, y - 2.5) < 0.05


def test_a_log_from_another_place_is_not_placed(tmp_path: Path, cli, yesterday: Path) -> None:
    route = [(1.2, 1.2), (6.8, 1.2), (6.8, 6.8), (1.2, 6.8)]
    log, _ = session(tmp_path, SQUARE, route, Pose2D(1.2, 4.0, -math.pi / 2), seconds=10.0)
    result = cli("process", log, "--prior", yesterday, "-o", tmp_path / "o", "-q")
    assert result.exit_code == 1
    assert "fits nowhere" in result.output or "more than one place" in result.output
    assert not (tmp_path / "o").exists()


def test_the_prior_must_be_an_output_folder_on_the_same_cells(tmp_path: Path, cli,
                                                              yesterday: Path) -> None:
    log, _ = session(tmp_path, ROOM, ROUTE, Pose2D(-2.5, -1.8, 0.0), seconds=2.0)
    result = cli("process", log, "--prior", tmp_path, "-o", tmp_path / "o", "-q")
    assert result.exit_code == 1 and "not a dynslam output folder" in result.output
    result = cli("process", log, "--prior", yesterday, "--resolution", "0.1", "-o",
                 tmp_path / "o", "-q")
    assert result.exit_code == 1 and "--resolution 0.05" in result.output
    result = cli("process", log, "--initial-pose", "1,2,3", "-o", tmp_path / "o", "-q")
    assert result.exit_code == 2 and "needs --prior" in result.output
    result = cli("process", log, "--prior", yesterday, "--initial-pose", "1,2", "-o",
                 tmp_path / "o", "-q")
    assert result.exit_code == 2 and "X,Y,DEGREES" in result.output


def test_an_object_gone_since_the_prior_session_is_an_event(tmp_path: Path, cli) -> None:
    crate = Box("crate", 0.3, 0.3, [(-0.5, 0.3)])  # stood in the room yesterday
    log1, _ = session(tmp_path / "a", ROOM, ROUTE, Pose2D(-2.5, -1.8, 0.0), boxes=(crate,))
    cli("process", log1, "-o", tmp_path / "first", "-q")
    log2, _ = session(tmp_path / "b", ROOM, ROUTE, Pose2D(-2.5, -1.8, 0.0),
                      odometry_frame=ELSEWHERE)
    result = cli("process", log2, "--prior", tmp_path / "first", "-o", tmp_path / "o", "-q")
    assert result.exit_code == 0, result.output
    with open(tmp_path / "o" / "changes.csv") as f:
        events = read_changes(f)
    gone = [e for e in events if e.kind == "removed_since_prior"]
    assert len(gone) == 1 and math.hypot(gone[0].x + 0.5, gone[0].y - 0.3) < 0.3
    assert not any(e.kind == "vacated" for e in events)
    summary = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert summary["changes"]["counts"]["removed_since_prior"] == 1
    # the same log without the prior knows nothing of the crate
    cli("process", log2, "-o", tmp_path / "alone", "-q")
    with open(tmp_path / "alone" / "changes.csv") as f:
        assert not [e for e in read_changes(f) if e.kind != "moving"]


def test_an_object_standing_since_the_prior_session_is_an_event(tmp_path: Path, cli) -> None:
    log1, _ = session(tmp_path / "a", ROOM, ROUTE, Pose2D(-2.5, -1.8, 0.0))
    cli("process", log1, "-o", tmp_path / "first", "-q")
    crate = Box("crate", 0.3, 0.3, [(-0.5, 0.3)])  # put there overnight
    log2, _ = session(tmp_path / "b", ROOM, ROUTE, Pose2D(-2.5, -1.8, 0.0),
                      odometry_frame=ELSEWHERE, boxes=(crate,))
    events = _objects_today(cli, log2, tmp_path / "first", tmp_path / "o")
    assert [e.kind for e in events] == ["added_since_prior"]
    assert math.hypot(events[0].x + 0.5, events[0].y - 0.3) < 0.3


def _objects_today(cli, log: Path, prior: Path, out: Path) -> list:
    """The change events other than movers of ``log`` run on the ``prior`` folder."""
    result = cli("process", log, "--prior", prior, "-o", out, "-q")
    assert result.exit_code == 0, result.output
    with open(out / "changes.csv") as f:
        return [e for e in read_changes(f) if e.kind != "moving"]


def _crate_came_yesterday(folder: Path) -> None:
    """Make ``folder`` (yesterday's output) one whose run saw a crate arrive at (-0.5, 0.3)
    and still stand there at its end: its outline in D (S Free under it), an ``appeared``
    event with no ``vacated`` after it."""
    from dynslam_cli.mapping.grid import OccupancyMap
    from dynslam_formats.mapfile import write_map

    d = read_map(folder / "dynamic.yaml")
    g = d.grid
    x = g.origin_x + (np.arange(g.prob.shape[1]) + 0.5) * g.resolution
    y = g.origin_y + (np.arange(g.prob.shape[0]) + 0.5) * g.resolution
    crate = (np.abs(x[None, :] + 0.5) <= 0.35) & (np.abs(y[:, None] - 0.3) <= 0.35)
    edge = crate & ~((np.abs(x[None, :] + 0.5) <= 0.2) & (np.abs(y[:, None] - 0.3) <= 0.2))
    write_map(folder, "dynamic", OccupancyMap(np.where(edge, 1.0, g.prob), g.resolution,
                                              g.origin_x, g.origin_y),
              d.free_thresh, d.occupied_thresh)
    with open(folder / "changes.csv", "a") as f:
        f.write("99,appeared,20.000,40.000,-0.500,0.300,0.360,150,\n")


def test_an_object_the_prior_saw_arrive_is_no_change_while_it_stands(tmp_path: Path,
                                                                     cli) -> None:
    """A crate that came during yesterday's run stood in yesterday's D: standing there
    today is no change (a crate on yesterday's empty floor is one); gone today, it is
    ``removed_since_prior``."""
    log1, _ = session(tmp_path / "a", ROOM, ROUTE, Pose2D(-2.5, -1.8, 0.0))
    cli("process", log1, "-o", tmp_path / "first", "-q")
    _crate_came_yesterday(tmp_path / "first")
    log2, _ = session(tmp_path / "b", ROOM, ROUTE, Pose2D(-2.5, -1.8, 0.0),
                      odometry_frame=ELSEWHERE, boxes=(Box("crate", 0.3, 0.3, [(-0.5, 0.3)]),))
    assert _objects_today(cli, log2, tmp_path / "first", tmp_path / "o") == []
    log3, _ = session(tmp_path / "c", ROOM, ROUTE, Pose2D(-2.5, -1.8, 0.0),
                      odometry_frame=ELSEWHERE)
    events = _objects_today(cli, log3, tmp_path / "first", tmp_path / "g")
    assert [e.kind for e in events] == ["removed_since_prior"]
    assert math.hypot(events[0].x + 0.5, events[0].y - 0.3) < 0.1


def test_a_walkers_end_points_do_not_place_a_log() -> None:
    """Scans put together over 3 s: a wall seen in each stays in the cloud that places the
    log, a walker who crossed in front, each scan somewhere else, leaves it; before the
    scans span a second, every end point counts."""
    from dynslam_cli.prior import steady

    wall = np.column_stack((np.linspace(0, 4, 40), np.full(40, 2.0)))
    clouds = [np.vstack((wall, [[0.1 * k, 1.0]])) for k in range(30)]  # the walker at 0.1k
    stamps = [0.1 * k for k in range(30)]
    kept = steady(clouds, stamps, cell=0.15, seconds=1.0)
    assert len(kept) == 30 * 40 and np.allclose(kept[:, 1], 2.0)
    early = steady(clouds[:5], stamps[:5], cell=0.15, seconds=1.0)
    assert len(early) == 5 * 41
