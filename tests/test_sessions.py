"""Sessions of a simulated world a day apart (`dynslam simulate --sessions`), and the
second placed in the first's map and scored (`--prior`, `dynslam evaluate`)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from dynslam_cli.geometry import distance_to_segments
from dynslam_cli.simulate import (
    FIXTURE_HALF_M,
    FIXTURE_SPOTS,
    FIXTURE_WALL_GAP_M,
    FIXTURES,
    PAUSE_EVERY_M,
    WORLD_NAMES,
    Walker,
    build_world,
    furnish,
    next_session,
)


@pytest.mark.parametrize("name", WORLD_NAMES)
def test_every_world_has_room_for_fixtures_clear_of_its_walls(name: str) -> None:
    world = build_world(name)
    spots = furnish(world, seed=0)
    assert len(spots) == FIXTURE_SPOTS and len(world.fixtures) == FIXTURES
    gaps = distance_to_segments(np.array(spots), world.walls) - FIXTURE_HALF_M
    assert gaps.min() >= FIXTURE_WALL_GAP_M - 1e-9
    assert furnish(build_world(name), seed=0) == spots  # the same world every time


def test_between_sessions_three_fixtures_change_and_the_robot_starts_elsewhere() -> None:
    world = build_world("hall")
    spots = furnish(world, seed=0)
    before = {f.id: f.center for f in world.fixtures}
    start = world.start
    changes = next_session(world, spots, 2, seed=0)
    after = {f.id: f.center for f in world.fixtures}
    assert [(c["from"] is None, c["to"] is None) for c in changes] == [
        (False, True), (False, False), (True, False)]  # taken away, moved, brought in
    for c in changes:
        assert c["from"] is None or tuple(c["from"]) == before[c["object"]]
        assert c["to"] is None or tuple(c["to"]) == after[c["object"]]
    unchanged = set(before) - {c["object"] for c in changes}
    assert len(unchanged) == FIXTURES - 2 and all(before[k] == after[k] for k in unchanged)
    assert len(set(after.values())) == len(after) and set(after.values()) <= set(spots)
    assert math.dist((start.x, start.y), (world.start.x, world.start.y)) > 5
    assert world.relocations == 0


EARLIER_FRONT_END = """[match]
skip_seen_free = false
confirm_jumps = false
"""


@pytest.mark.parametrize("config", ["", EARLIER_FRONT_END])
def test_two_sessions_the_second_placed_in_the_first_and_its_changes_found(tmp_path: Path,
                                                                            cli, config) -> None:
    """The defaults, whose second session's pose thins one wall of the first session's map
    by a cell (8 cells, a third "removed" object without ``[changes] skip_wall_faces``);
    and the local SLAM without ``skip_seen_free`` and ``confirm_jumps`` (the default before
    stop 54)."""
    made = cli("simulate", "hall", "-o", tmp_path / "sim", "--sessions", "2", "--duration",
               "150")
    assert made.exit_code == 0, made.output
    first, second = (Path(p) for p in made.stdout.split())
    truth = json.loads((second.parent / "truth.json").read_text())
    assert truth["session"] == 2 and len(truth["prior_changes"]) == 3
    assert truth["odometry"][0][1:] == [0.0, 0.0, 0.0]  # its own frame, a day later
    (tmp_path / "c.toml").write_text(config)
    options = ("-q", "--config", tmp_path / "c.toml")
    assert cli("process", first, "-o", tmp_path / "day1", *options).exit_code == 0
    run = cli("process", second, "-o", tmp_path / "day2", *options, "--prior",
              tmp_path / "day1")
    assert run.exit_code == 0, run.output
    report = json.loads(cli("evaluate", tmp_path / "day2", "--truth",
                            second.parent / "truth.json", "--json").stdout)
    sessions = report["truth"]["sessions"]
    assert sessions["ate_in_prior_frame_m"] < 0.05
    for kind in ("removed_since_prior", "added_since_prior"):
        assert sessions[kind]["true"] == 2, sessions  # one moved, one taken away / brought in
        assert sessions[kind]["recall"] == 1.0 and sessions[kind]["precision"] == 1.0, sessions


def test_a_second_session_whose_first_scans_fit_many_places_is_placed_as_it_drives_on(
        tmp_path: Path, cli) -> None:
    """The corridors world is a ring of look-alike corridors: the second session's first
    scans fit several places, and so did every cloud of the scans driven after them while
    a cloud's end points counted as 40 independent ones however many walls they covered
    (refused after 40 m, the best place e^2.9 as likely as its rival). Counted by the
    squares of wall they cover, the scans of the whole drive tell the places apart."""
    made = cli("simulate", "corridors", "-o", tmp_path / "sim", "--sessions", "2",
               "--duration", "150")
    assert made.exit_code == 0, made.output
    first, second = (Path(p) for p in made.stdout.split())
    assert cli("process", first, "-o", tmp_path / "day1", "-q").exit_code == 0
    run = cli("process", second, "-o", tmp_path / "day2", "-q", "--prior", tmp_path / "day1")
    assert run.exit_code == 0, run.output
    placed = json.loads((tmp_path / "day2" / "summary.json").read_text())
    assert placed["localization"]["prior"]["driven_m"] > 10  # (not from the first scans)
    report = json.loads(cli("evaluate", tmp_path / "day2", "--truth",
                            second.parent / "truth.json", "--json").stdout)
    sessions = report["truth"]["sessions"]
    assert sessions["ate_in_prior_frame_m"] < 0.1  # (the ring's other places: metres off)
    for kind in ("removed_since_prior", "added_since_prior"):
        assert sessions[kind]["recall"] == 1.0 and sessions[kind]["precision"] == 1.0, sessions


def test_stop_and_go_walkers_stand_still_after_every_few_metres(cli, tmp_path: Path) -> None:
    """``simulate --stop-and-go S``: each walker walks PAUSE_EVERY_M, stands S seconds, walks
    on (issue: a person who stops and walks on); its truth says so."""
    walker = Walker("p", 0.2, [(0.0, 0.0), (10.0, 0.0), (10.0, 10.0), (0.0, 10.0)], 0.5,
                    pause_s=5.0)
    leg = PAUSE_EVERY_M / walker.speed
    assert walker.position(leg + 0.1) == walker.position(leg + 4.9) == (PAUSE_EVERY_M, 0.0)
    assert walker.position(leg + 5.0 + 2.0) == pytest.approx((PAUSE_EVERY_M + 1.0, 0.0))
    r = cli("simulate", "crowd", "-o", tmp_path / "sg", "--duration", "5", "--stop-and-go", "5")
    assert r.exit_code == 0, r.stderr
    truth = json.loads((tmp_path / "sg" / "truth.json").read_text())
    walkers = [o for o in truth["objects"].values() if o["kind"] == "walker"]
    assert len(walkers) == 3 and all(w["pause_s"] == 5.0 for w in walkers)
