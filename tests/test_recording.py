"""The recording (``--record``): read back by rosbags and by mcap, equal to the other outputs
at its end, played back through our own reader into the same run."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from PIL import Image
from ruamel.yaml import YAML

from dynslam_cli.mapping.grid import GridStack, probability, steps
from dynslam_cli.types import Pose2D
from dynslam_formats import open_log
from dynslam_formats.base import ReaderOptions
from dynslam_formats.recording import TOPICS, StoredClasses, occupancy_values, path_cdr
from dynslam_formats.tum import read_tum
from tests.conftest import SAMPLES, flaser

SAMPLE = SAMPLES / "hall" / "hall.log"
PGM_CLASSES = {254: 0, 0: 100, 205: -1}  # map_server trinary pixels → OccupancyGrid values


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """The hall sample processed with a recording every 2 s of log time."""
    from click.testing import CliRunner

    from dynslam_cli.cli import main

    out = tmp_path_factory.mktemp("rec") / "out"
    r = CliRunner().invoke(main, ["process", str(SAMPLE), "-o", str(out), "-q",
                                  "--record", "run.mcap", "--record-period", "2"])
    assert r.exit_code == 0, r.output
    return out


def read_scans(path) -> list:
    source, _, reader = open_log(str(path), ReaderOptions())
    try:
        return list(reader.scans())
    finally:
        source.close()


def read_all(path):
    """(topic, type, log time ns, message) in file order, through rosbags' AnyReader."""
    from rosbags.highlevel import AnyReader

    with AnyReader([path]) as reader:
        return [(c.topic, c.msgtype, t, reader.deserialize(raw, c.msgtype))
                for c, t, raw in reader.messages()]


def test_rosbags_reads_every_topic_with_increasing_stamps(recorded):
    summary = json.loads((recorded / "summary.json").read_text())
    messages = read_all(recorded / "run.mcap")
    types = {topic: msgtype for topic, msgtype, _ in TOPICS}
    assert {(t, m) for t, m, _, _ in messages} == set(types.items())
    counts = {t: sum(1 for m in messages if m[0] == t) for t in types}
    assert counts == summary["recording"]["messages"]
    n = summary["scans_processed"]
    assert counts["/scan"] == counts["/tf"] == n and counts["/tf_static"] == 1
    assert 2 <= counts["/map"] <= n
    for topic in types:
        times = [t for name, _, t, _ in messages if name == topic]
        assert times == sorted(times), topic
        stamps = [m.header.stamp.sec * 10**9 + m.header.stamp.nanosec
                  for name, _, _, m in messages if name == topic and hasattr(m, "header")]
        assert stamps == [t for name, _, t, m in messages if name == topic
                          and hasattr(m, "header")], topic  # the log time is the stamp
    assert summary["recording"]["bytes"] == (recorded / "run.mcap").stat().st_size
    assert "run.mcap" in summary["outputs"]


def test_the_last_map_and_path_are_the_written_outputs(recorded):
    messages = read_all(recorded / "run.mcap")
    last = {topic: msg for topic, _, _, msg in messages}
    grid = last["/map"]
    with Image.open(recorded / "static.pgm") as im:
        pixels = np.asarray(im)[::-1]  # (row 0 at the lowest y, as an OccupancyGrid)
    expected = np.vectorize(PGM_CLASSES.get)(pixels)
    assert grid.header.frame_id == "map"
    assert (grid.info.height, grid.info.width) == pixels.shape
    np.testing.assert_array_equal(grid.data.reshape(pixels.shape), expected)
    meta = YAML(typ="safe").load((recorded / "static.yaml").read_text())
    assert meta["origin"][:2] == pytest.approx([grid.info.origin.position.x,
                                                grid.info.origin.position.y], abs=1e-6)
    assert meta["resolution"] == pytest.approx(grid.info.resolution)

    path = last["/path"]
    tum = read_tum(recorded / "trajectory.tum")
    got = np.array([(p.header.stamp.sec + 1e-9 * p.header.stamp.nanosec, p.pose.position.x,
                     p.pose.position.y, 2 * math.atan2(p.pose.orientation.z,
                                                       p.pose.orientation.w))
                    for p in path.poses])
    assert len(got) == len(tum)
    np.testing.assert_allclose(got[:, :3], tum[:, :3], atol=1e-6)
    turn = np.angle(np.exp(1j * (got[:, 3] - tum[:, 3])))
    assert np.abs(turn).max() < 1e-6


def test_a_running_path_stays_bounded_and_spans_the_run(cli, tmp_path, monkeypatch):
    """A running /path never holds more than PATH_MAX_POSES (+ the latest scan): the file
    grows with the log, not with its square. It still starts at the first scan and ends at
    the scan it was sent with; the last /path is every scan."""
    from dynslam_formats import recording

    monkeypatch.setattr(recording, "PATH_MAX_POSES", 12)
    out = tmp_path / "out"
    assert cli("process", SAMPLE, "-o", out, "-q", "--record", "run.mcap",
               "--record-period", "1").exit_code == 0
    paths = [(t, m) for topic, _, t, m in read_all(out / "run.mcap") if topic == "/path"]
    first = read_tum(out / "trajectory.tum")[0, 0]
    sizes = [len(m.poses) for _, m in paths[:-1]]
    assert max(sizes) <= 12 + 1 and sizes.count(max(sizes)) > 1
    for t, m in paths:
        times = [p.header.stamp.sec * 10**9 + p.header.stamp.nanosec for p in m.poses]
        assert times == sorted(times) and times[-1] == t
        assert times[0] == pytest.approx(first * 1e9, abs=1e3)
    assert len(paths[-1][1].poses) == len(read_tum(out / "trajectory.tum"))


def test_the_change_events_appear_when_they_were_first_seen(recorded):
    """/changes: at each event's first sighting every event seen by then, and at the end
    changes.csv's list (a disc and a label per event, in map.png's colours)."""
    import csv

    from dynslam_formats.picture import CHANGE_RGB

    with open(recorded / "changes.csv") as f:
        rows = list(csv.DictReader(f))
    assert rows  # (the hall sample has events)
    sent = [(t, m) for topic, _, t, m in read_all(recorded / "run.mcap") if topic == "/changes"]
    assert len(sent) == len({r["first_s"] for r in rows}) + 1
    start = read_scans(SAMPLE)[0].stamp  # (a Carmen log's stamps are the truth's times)

    def shown(message) -> set[tuple[int, str]]:
        return {(m.id, m.ns) for m in message.markers if "labels" not in m.ns}

    for t, message in sent[:-1]:
        seen = {(int(r["id"]), r["kind"]) for r in rows
                if float(r["first_s"]) <= t * 1e-9 - start + 1e-6}
        assert shown(message) == seen
    final = sent[-1][1]
    assert shown(final) == {(int(r["id"]), r["kind"]) for r in rows}
    for m in final.markers:
        row = next(r for r in rows if int(r["id"]) == m.id)
        assert (m.pose.position.x, m.pose.position.y) == pytest.approx(
            (float(row["x"]), float(row["y"])), abs=1e-3)
        assert (m.color.r, m.color.g, m.color.b) == pytest.approx(
            tuple(c / 255 for c in CHANGE_RGB[row["kind"]]))


def test_a_mover_is_its_path_on_the_changes_topic(recorded):
    """/changes draws a moving event as map.png does, a thin line along its path (it was a
    disc at the path's centre)."""
    events = {e["id"]: e for e in json.loads((recorded / "summary.json").read_text())
              ["changes"]["events"]}
    final = [m for topic, _, _, m in read_all(recorded / "run.mcap") if topic == "/changes"][-1]
    lines = [m for m in final.markers if m.type == m.LINE_STRIP]
    assert lines and all(events[m.id]["kind"] == "moving" for m in lines)
    assert {m.id for m in lines} == {i for i, e in events.items() if len(e["path"]) >= 2}
    for m in lines:
        drawn = [(m.pose.position.x + p.x, m.pose.position.y + p.y) for p in m.points]
        assert np.allclose(drawn, events[m.id]["path"], atol=1e-6)


def test_mcap_reads_it_as_a_ros2_file(recorded):
    from mcap.reader import make_reader

    with open(recorded / "run.mcap", "rb") as f:
        reader = make_reader(f)
        header, summary = reader.get_header(), reader.get_summary()
        assert header.profile == "ros2" and header.library.startswith("dynslam ")
        assert summary is not None
        assert {s.encoding for s in summary.schemas.values()} == {"ros2msg"}
        assert {c.message_encoding for c in summary.channels.values()} == {"cdr"}
        latched = {c.topic for c in summary.channels.values()
                   if "durability: 1" in c.metadata["offered_qos_profiles"]}
        assert latched == {"/tf_static", "/map", "/dynamic_map", "/changes"}
        counts = {summary.channels[k].topic: v
                  for k, v in summary.statistics.channel_message_counts.items()}
        last: dict[int, int] = {}
        for _, channel, message in reader.iter_messages(log_time_order=False):
            assert message.log_time >= last.get(channel.id, 0)
            last[channel.id] = message.log_time
    totals = json.loads((recorded / "summary.json").read_text())["recording"]["messages"]
    assert counts == totals


def test_a_run_on_the_recording_is_the_same_run(recorded, cli, tmp_path):
    """A round trip through our own ROS reader: the recording's /scan and /tf give the
    scans of the log, bit for bit, and so the same trajectory."""
    logged, played = ([(s.stamp, s.ranges, s.angles, s.max_range, s.odom, s.laser)
                       for s in read_scans(path)] for path in (SAMPLE, recorded / "run.mcap"))
    assert len(logged) == len(played)
    for a, b in zip(logged, played, strict=True):
        no_return = (a[1] >= a[3], b[1] >= b[3])
        np.testing.assert_array_equal(*no_return)
        np.testing.assert_array_equal(a[1][~no_return[0]], b[1][~no_return[0]])
        assert (a[0], a[3], a[4], a[5]) == (b[0], b[3], b[4], b[5])
        np.testing.assert_array_equal(a[2], b[2])
    out = tmp_path / "again"
    assert cli("process", recorded / "run.mcap", "-o", out, "-q").exit_code == 0
    assert (out / "trajectory.tum").read_bytes() == (recorded / "trajectory.tum").read_bytes()


def test_recording_changes_no_other_output(recorded, cli, tmp_path):
    out = tmp_path / "plain"
    assert cli("process", SAMPLE, "-o", out, "-q").exit_code == 0
    for f in out.iterdir():
        if f.name != "summary.json":
            assert f.read_bytes() == (recorded / f.name).read_bytes(), f.name


def test_path_bytes_are_rosbags_serialization():
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    t = store.types
    rng = np.random.default_rng(5)
    for frame in ("map", "odom", "", "base_link", "ab"):
        for n in (0, 1, 2, 5):
            rows = np.column_stack((np.sort(rng.uniform(0, 1e4, n)), rng.normal(0, 50, (n, 2)),
                                    rng.uniform(-math.pi, math.pi, n)))

            def header(s, f=frame):
                sec, ns = divmod(round(s * 1e9), 10**9)  # (stamps below 10⁴ s)
                return t["std_msgs/msg/Header"](
                    stamp=t["builtin_interfaces/msg/Time"](sec=sec, nanosec=ns), frame_id=f)

            poses = [t["geometry_msgs/msg/PoseStamped"](header=header(s), pose=t[
                "geometry_msgs/msg/Pose"](position=t["geometry_msgs/msg/Point"](
                    x=x, y=y, z=0.0), orientation=t["geometry_msgs/msg/Quaternion"](
                    x=0.0, y=0.0, z=math.sin(th / 2), w=math.cos(th / 2))))
                for s, x, y, th in rows]
            msg = t["nav_msgs/msg/Path"](header=header(12.5), poses=poses)
            want = store.serialize_cdr(msg, "nav_msgs/msg/Path")
            assert path_cdr(12.5, frame, rows) == bytes(want), (frame, n)


def test_stored_classes_are_the_map_writers_classes():
    g = GridStack(0.1, 1.0, ("static",))
    angles = np.linspace(-math.pi, math.pi, 360, endpoint=False)
    for k in range(5):
        obs = g.observe(Pose2D(0.3 * k, 0.0, 0.0), np.full(360, 3.0), angles, 8.0, 0.01, 8.0)
        g.layers["static"][obs.free] -= steps(0.4 * (k + 1))
        g.layers["static"][obs.hit] += steps(0.9)
    classes = StoredClasses(0.25, 0.65)
    values, ox, oy = g.mapped("static", classes)
    snap = g.snapshot("static")
    expected = np.concatenate([occupancy_values(b, 0.25, 0.65) for _, b in snap.bands()])
    assert (ox, oy) == (snap.origin_x, snap.origin_y)
    np.testing.assert_array_equal(values, expected)
    assert {-1, 0, 100} <= set(np.unique(values))
    every = np.arange(-(1 << 15), 1 << 15).astype(np.int16)
    np.testing.assert_array_equal(classes(every),
                                  occupancy_values(probability(every), 0.25, 0.65))


def test_bad_record_names_are_refused(cli, tmp_path):
    for name in ("run.bag", "sub/run.bag", ".mcap", "sub/.mcap"):
        r = cli("process", SAMPLE, "-o", tmp_path / "out", "--record", name)
        assert r.exit_code == 2, name  # the option's value: a usage error naming it
        assert ("Invalid value for '--record': must be a file name or path ending in .mcap"
                in r.stderr), r.stderr
    assert list(tmp_path.iterdir()) == []


def test_a_failed_run_leaves_no_recording(cli, tmp_path):
    bad = tmp_path / "bad.log"
    bad.write_text(flaser() + flaser(t=2) + "FLASER 5 1 2 x\n")
    r = cli("process", bad, "-o", tmp_path / "out", "--record", "run.mcap")
    assert r.exit_code == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.log"]


def test_batch_records_every_log_and_the_config_key_works(cli, tmp_path):
    cfg = tmp_path / "rec.toml"
    cfg.write_text('[record]\nfile = "play.mcap"\nperiod_s = 30.0\n')
    logs = tmp_path / "logs"
    logs.mkdir()
    for name in ("a", "b"):
        (logs / f"{name}.log").write_text("".join(flaser(n=90, r=2.0 + 0.1 * i, t=i)
                                                   for i in range(1, 40)))
    r = cli("batch", logs, "-o", tmp_path / "out", "--config", cfg, "-q")
    assert r.exit_code == 0, r.output
    for name in ("a", "b"):
        summary = json.loads((tmp_path / "out" / name / "summary.json").read_text())
        assert summary["recording"]["file"] == "play.mcap"
        assert summary["recording"]["period_s"] == 30.0
        assert (tmp_path / "out" / name / "play.mcap").stat().st_size == \
            summary["recording"]["bytes"]


@pytest.mark.parametrize("stamp", [0.0, 0.6, 17.25, 1234567890.123456, 1699999999.999999,
                                   1699999999.9999999])
def test_stamps_read_back_as_written(stamp):
    from types import SimpleNamespace

    from dynslam_formats.recording import _stamp
    from dynslam_formats.ros import stamp_of

    sec, nanosec = _stamp(stamp)
    assert 0 <= nanosec < 10**9
    msg = SimpleNamespace(header=SimpleNamespace(stamp=SimpleNamespace(sec=sec,
                                                                       nanosec=nanosec)))
    assert stamp_of(msg) == stamp


def test_the_guard_keeps_scans_at_laser_scan_precision(tmp_path):
    """What makes the round trip exact, for any reader: float32 ranges, beams at a float32
    start and step, headings at float32 (wrapped first: an unwrapped one would lose bits)."""
    from dynslam_formats.guard import beam_geometry

    log = tmp_path / "a.log"
    log.write_text(flaser(n=7, r=1.234, pose=(1.0, 2.0, 7.0)) + "FLASER 3 1 1e300 2 "
                   "0 0 0 0 0 0 2 host 2\n")
    first, second = read_scans(log)
    assert np.array_equal(first.ranges, first.ranges.astype(np.float32))
    assert first.ranges[0] != 1.234 and abs(first.ranges[0] - 1.234) < 1e-6
    assert first.odom.theta == float(np.float32(7.0 - 2 * math.pi))
    start, step = beam_geometry(first.angles)
    assert (start, step) == (float(np.float32(start)), float(np.float32(step)))
    np.testing.assert_array_equal(first.angles, start + step * np.arange(7))
    assert first.max_range == float(np.float32(first.max_range))
    assert second.ranges[1] == math.inf  # beyond float32: a no-return, as it was


def test_mit_csail_plays_back_into_the_same_run(cli, datasets, tmp_path):
    """A real log whose laser mount (made of Carmen's two poses) varies from scan to scan in
    the last digits, and comes back to earlier values."""
    log = datasets / "carmen" / "mit-csail.clf"
    first, again = tmp_path / "first", tmp_path / "again"
    assert cli("process", log, "-o", first, "-q", "--record", "run.mcap").exit_code == 0
    assert cli("process", first / "run.mcap", "-o", again, "-q").exit_code == 0
    for name in ("trajectory.tum", "static.pgm", "dynamic.pgm", "landmarks.csv"):
        assert (first / name).read_bytes() == (again / name).read_bytes(), name


def test_a_log_without_odometry_plays_back_without_it(cli, datasets, tmp_path):
    """A laser-only bag: the recording's TF goes map → base_link (an odom → base_link
    would read back as odometry standing still, a different run)."""
    bag = datasets / "rosbag1" / "people-walking-rear.bag"
    first, again = tmp_path / "first", tmp_path / "again"
    assert cli("process", bag, "-o", first, "-q", "--record", "run.mcap").exit_code == 0
    links = {(tf.header.frame_id, tf.child_frame_id) for topic, _, _, msg in
             read_all(first / "run.mcap") if topic == "/tf" for tf in msg.transforms}
    assert links == {("map", "base_link")}
    r = cli("process", first / "run.mcap", "-o", again, "-q")
    assert r.exit_code == 0 and "no odometry" in r.stderr
    for name in ("trajectory.tum", "static.pgm", "dynamic.pgm"):
        assert (first / name).read_bytes() == (again / name).read_bytes(), name
    summary = json.loads((first / "summary.json").read_text())
    assert summary["recording"]["messages"]["/odometry_path"] == 0


def mount_links(path) -> dict[str, list]:
    """The base_link → laser transforms of a recording, by topic."""
    links: dict[str, list] = {"/tf_static": [], "/tf": []}
    for topic, _, _, msg in read_all(path):
        if topic in links:
            links[topic] += [(tf.transform.translation.x, tf.transform.translation.y)
                             for tf in msg.transforms if tf.child_frame_id == "laser"]
    return links


def test_a_mount_that_jitters_in_the_log_s_last_digits_goes_on_tf_static_only(cli, tmp_path):
    """Carmen's mount is the laser pose minus the robot pose, each printed to six decimals:
    it varies from scan to scan in the µm (fr079) or 1e-13 m (MIT). Such a mount is static;
    one that really moves (here by 0.1 m at the 30th scan) goes on /tf, once."""
    log = tmp_path / "mount.log"
    lines = []
    for i in range(1, 60):
        robot = (0.01 * i, 0.002 * i, 0.001 * i)
        forward = (0.1 if i < 30 else 0.2) + (1e-6 if i % 3 else 0.0)
        laser = (robot[0] + forward * math.cos(robot[2]),
                 robot[1] + forward * math.sin(robot[2]) - (1e-6 if i % 2 else 0.0), robot[2])
        ranges = " ".join(f"{2.0 + 0.01 * (i % 7):.3f}" for _ in range(90))
        poses = " ".join(f"{v:.6f}" for v in (*laser, *robot))
        lines.append(f"FLASER 90 {ranges} {poses} {i}.0 host {i}.0\n")
    log.write_text("".join(lines))
    mounts = {(round(s.laser.x, 9), round(s.laser.y, 9)) for s in read_scans(log)}
    assert len(mounts) == 2  # the run sees the two mounts the log means
    out, again = tmp_path / "out", tmp_path / "again"
    assert cli("process", log, "-o", out, "-q", "--record", "run.mcap").exit_code == 0
    links = mount_links(out / "run.mcap")
    assert [x for x, _ in links["/tf_static"]] == [pytest.approx(0.1, abs=1e-5)]
    assert [x for x, _ in links["/tf"]] == [pytest.approx(0.2, abs=1e-5)]
    assert cli("process", out / "run.mcap", "-o", again, "-q").exit_code == 0
    assert (again / "trajectory.tum").read_bytes() == (out / "trajectory.tum").read_bytes()


def test_mit_csail_s_mount_is_sent_once(cli, datasets, tmp_path):
    """MIT's mount varies by 5e-13 m: it was sent on /tf for 1 900 of 1 988 scans."""
    out = tmp_path / "out"
    assert cli("process", datasets / "carmen" / "mit-csail.clf", "-o", out, "-q",
               "--max-scans", "150", "--record", "run.mcap").exit_code == 0
    links = mount_links(out / "run.mcap")
    assert (len(links["/tf_static"]), len(links["/tf"])) == (1, 0)


def laser_scans(path) -> list:
    return [msg for topic, _, _, msg in read_all(path) if topic == "/scan"]


def test_scan_fields_are_the_log_s_where_it_says_them(cli, tmp_path):
    """A bag's LaserScan says its range_min, time_increment and scan_time: the recording
    sends them on (they were laser.min_range_m, 0 and 0), and its own playback keeps them.
    A Carmen log says none: range_min is laser.min_range_m, below which the run drops
    readings, and the times 0 (not known)."""
    sim = tmp_path / "sim"
    r = cli("simulate", "corridors", "-o", sim, "--duration", "4", "--format", "rosbag1")
    assert r.exit_code == 0, r.stderr
    cfg = tmp_path / "min.toml"
    cfg.write_text("[laser]\nmin_range_m = 0.05\n")
    out, again = tmp_path / "out", tmp_path / "again"
    assert cli("process", sim / "corridors.bag", "-o", out, "-q", "--config", cfg,
               "--record", "run.mcap").exit_code == 0
    assert cli("process", out / "run.mcap", "-o", again, "-q", "--config", cfg,
               "--record", "run.mcap").exit_code == 0
    for path in (out / "run.mcap", again / "run.mcap"):
        fields = {(m.range_min, m.time_increment, m.scan_time) for m in laser_scans(path)}
        assert fields == {(np.float32(0.02), 0.0, np.float32(0.1))}, path  # simlogs' values
    log = tmp_path / "a.log"
    log.write_text("".join(flaser(n=90, t=i) for i in range(1, 20)))
    assert cli("process", log, "-o", tmp_path / "c", "-q", "--config", cfg,
               "--record", "run.mcap").exit_code == 0
    fields = {(m.range_min, m.time_increment, m.scan_time)
              for m in laser_scans(tmp_path / "c" / "run.mcap")}
    assert fields == {(np.float32(0.05), 0.0, 0.0)}


def test_people_bag_s_range_min_and_timing_are_recorded(cli, datasets, tmp_path):
    out = tmp_path / "out"
    assert cli("process", datasets / "rosbag1" / "people-walking-rear.bag", "-o", out, "-q",
               "--max-scans", "20", "--record", "run.mcap").exit_code == 0
    scan = laser_scans(out / "run.mcap")[0]
    assert scan.range_min == np.float32(0.03)
    assert scan.time_increment == np.float32(6.510417e-05)
    assert scan.scan_time == np.float32(0.13333334)
