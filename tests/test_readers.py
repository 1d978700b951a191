"""Player and ROS readers, the reader table and plugins, dynslam info, round trips."""

from __future__ import annotations

import json
from importlib.metadata import EntryPoint

import numpy as np
import pytest

from dynslam_formats.mapfile import read_map
from dynslam_formats.tum import read_tum

FORMATS = ["carmen", "player", "rosbag1", "rosbag2", "rosbag2-mcap", "mcap"]


@pytest.fixture(scope="module")
def simulated(tmp_path_factory):
    """One short simulated hall written in every format."""
    from click.testing import CliRunner

    from dynslam_cli.cli import main

    root = tmp_path_factory.mktemp("sim")
    logs = {}
    for fmt in FORMATS:
        r = CliRunner().invoke(main, ["simulate", "hall", "-o", str(root / fmt), "--duration",
                                      "40", "--format", fmt])
        assert r.exit_code == 0, r.output
        logs[fmt] = r.stdout.strip()
    return logs


def test_every_format_gives_the_same_trajectory_and_maps(simulated, cli, tmp_path):
    results = {}
    for fmt, log in simulated.items():
        out = tmp_path / fmt
        r = cli("process", log, "-o", out, "-q", "--localization", "odometry")
        assert r.exit_code == 0, (fmt, r.stderr)
        traj = read_tum(out / "trajectory.tum")
        results[fmt] = (traj, read_map(out / "static.yaml").grid, read_map(out / "dynamic.yaml")
                        .grid)
    ref_traj, ref_s, ref_d = results["carmen"]
    for fmt, (traj, s, d) in results.items():
        assert len(traj) == len(ref_traj), fmt
        np.testing.assert_allclose(traj[:, 1:], ref_traj[:, 1:], atol=2e-6, err_msg=fmt)
        assert traj[:, 0] - traj[0, 0] == pytest.approx(ref_traj[:, 0] - ref_traj[0, 0],
                                                       abs=1e-6)
        assert s.prob.shape == ref_s.prob.shape, fmt
        for a, b in ((s, ref_s), (d, ref_d)):
            # ranges are %.3f text in Carmen/Player, float32 in ROS: a few cells may differ
            assert np.mean(np.abs(a.prob - b.prob) > 0.2) < 0.002, fmt


@pytest.mark.parametrize("fmt", FORMATS)
def test_info_describes_each_format(simulated, cli, fmt):
    r = cli("info", simulated[fmt], "--json")
    assert r.exit_code == 0, r.stderr
    d = json.loads(r.stdout)
    assert d["scans"] == 401 and d["beams"] == [181] and d["odometry"] is True
    assert d["fov_deg"] == [180.0] and d["duration_s"] == pytest.approx(40.0)


def test_player_stage_log(datasets, cli, tmp_path):
    r = cli("process", datasets / "player/stage-hall-with-obstacles.log", "-o", tmp_path / "o",
            "-q")
    assert r.exit_code == 0, r.stderr
    assert len(read_tum(tmp_path / "o/trajectory.tum")) == 289
    assert json.loads((tmp_path / "o/summary.json").read_text())["input"]["format"] == "player"


def test_people_bag_stationary_sensor_people_in_d(datasets, cli, tmp_path):
    r = cli("process", datasets / "rosbag1/people-stationary-simple.bag", "-o", tmp_path / "o",
            "-q")
    assert r.exit_code == 0, r.stderr
    traj = read_tum(tmp_path / "o/trajectory.tum")
    assert len(traj) == 1265
    assert np.ptp(traj[:, 1]) < 0.05 and np.ptp(traj[:, 2]) < 0.05  # it did not move
    s, d = read_map(tmp_path / "o/static.yaml"), read_map(tmp_path / "o/dynamic.yaml")
    assert (s.grid.prob > 0.9).sum() > 100  # the room (173 cells here)
    assert (d.grid.prob > 0.9).sum() > 5  # people where the room was seen free
    assert "no odometry" in r.stderr


def test_several_topics_need_a_choice(datasets, cli, tmp_path):
    bag = datasets / "rosbag1/three-lasers-negative.bag"
    r = cli("process", bag, "-o", tmp_path / "o")
    assert r.exit_code == 1
    assert "/left_scan (435 messages), /rear_scan (435 messages)" in r.stderr
    assert "--topic" in r.stderr
    r = cli("process", bag, "-o", tmp_path / "o", "-q", "--topic", "/left_scan")
    assert r.exit_code == 0 and len(read_tum(tmp_path / "o/trajectory.tum")) == 435
    assert cli("process", bag, "--topic", "/nope", "-o", tmp_path / "x").exit_code == 1
    # info follows the same rule: no silent pick (it took /left_scan; issue 38, item 11),
    # it describes each laser and names the option process needs
    r = cli("info", bag, "--json")
    assert r.exit_code == 0, r.stderr
    d = json.loads(r.stdout)
    assert "scan_topic" not in d and d["choose_with"] == "--topic"
    assert {t: v["scans"] for t, v in d["topics"].items()} == {
        "/left_scan": 435, "/rear_scan": 435, "/right_scan": 434}
    assert json.loads(cli("info", bag, "--json", "--topic", "/rear_scan").stdout)[
        "scan_topic"] == "/rear_scan"


@pytest.mark.parametrize(("name", "message"), [
    ("handheld-hokuyo-old-index.bag", "index is not readable"),
    ("legacy-rosrecord-v1.2.bag", "pre-2.0 ROS bag"),
])
def test_bad_bags_one_line_error(datasets, cli, tmp_path, name, message):
    r = cli("process", datasets / "rosbag1" / name, "-o", tmp_path / "o")
    assert r.exit_code == 1
    assert len(r.stderr.strip().splitlines()) == 1 and message in r.stderr
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("fmt", ["rosbag1", "mcap"])
def test_truncated_bag_is_a_clear_error(simulated, cli, tmp_path, fmt):
    with open(simulated[fmt], "rb") as f:
        data = f.read()
    cut = tmp_path / ("cut.bag" if fmt == "rosbag1" else "cut.mcap")
    cut.write_bytes(data[: len(data) // 2])
    r = cli("process", cut, "-o", tmp_path / "o")
    assert r.exit_code == 1, r.output
    assert r.stderr.startswith(f"dynslam: error: {cut}: ")
    assert "Traceback" not in r.stderr


def test_reader_plugin_from_entry_point(cli, tmp_path, monkeypatch):
    import importlib.metadata

    import dynslam_formats

    ep = EntryPoint("linescan", "tests.plugin_example:ENTRY", dynslam_formats.PLUGIN_GROUP)
    monkeypatch.setattr(importlib.metadata, "entry_points",
                        lambda group: [ep] if group == ep.group else [])
    dynslam_formats.all_readers.cache_clear()
    try:
        log = tmp_path / "run.linescan"
        rows = [f"{t} {0.1 * t} 0 0 8 -1.5 0.1 " + " ".join(["3.0"] * 31) for t in range(5)]
        log.write_text("%linescan\n" + "\n".join(rows) + "\n")
        r = cli("process", log, "-o", tmp_path / "o", "-q", "--localization", "odometry")
        assert r.exit_code == 0, r.stderr
        assert json.loads((tmp_path / "o/summary.json").read_text())["input"]["format"] == \
            "linescan"
        assert len(read_tum(tmp_path / "o/trajectory.tum")) == 5
    finally:
        dynslam_formats.all_readers.cache_clear()
