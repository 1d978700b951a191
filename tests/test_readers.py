"""Player and ROS readers, the reader table and plugins, dynslam info, round trips."""

from __future__ import annotations

import dataclasses
import itertools
import json
import math
from importlib.metadata import EntryPoint
from pathlib import Path

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
    assert d["laser_mount"] == [[0.0, 0.0, 0.0]]


@pytest.mark.parametrize("fmt", FORMATS)
def test_beam_step_spreads_every_formats_beams_from_the_first(simulated, cli, fmt):
    """A log that states its beams' spacing wrong (a converter's fov/(n-1) for a laser's
    fov/n) is read with the spacing a user gives, whatever its format; the first beam stays."""
    from dynslam_formats import ReaderOptions, open_log

    r = cli("info", simulated[fmt], "--json", "--beam-step", "0.5")
    assert r.exit_code == 0, r.stderr
    assert json.loads(r.stdout)["fov_deg"] == [90.0]  # 181 beams half a degree apart
    source, _, reader = open_log(simulated[fmt], ReaderOptions(beam_step_deg=0.5))
    try:
        scan = next(iter(reader.scans()))
    finally:
        source.close()
    np.testing.assert_allclose(np.diff(scan.angles), np.radians(0.5), atol=1e-6)
    assert scan.angles[0] == pytest.approx(-np.pi / 2, abs=1e-6)


@pytest.mark.parametrize("fmt", ["carmen", "rosbag1"])
def test_scan_latency_takes_each_scans_odometry_that_much_earlier(simulated, fmt):
    """A laser whose scans reach the log 30 ms after they were seen: each scan's odometry is
    read 30 ms before its stamp, between the scan before's and its own (the first scan's
    as it is); the stamps, the beams and the number of scans stay."""
    from dynslam_cli.geometry import interpolate
    from dynslam_formats import ReaderOptions, open_log

    def scans(options):
        source, _, reader = open_log(simulated[fmt], options)
        try:
            return list(reader.scans())
        finally:
            source.close()

    plain, late = scans(ReaderOptions()), scans(ReaderOptions(scan_latency_s=0.03))
    assert [s.stamp for s in late] == [s.stamp for s in plain]
    assert late[0].odom == plain[0].odom
    for before, scan, shifted in zip(plain, plain[1:], late[1:], strict=False):
        np.testing.assert_array_equal(shifted.ranges, scan.ranges)
        f = 1 - 0.03 / (scan.stamp - before.stamp)  # 0.7 of the way at 10 scans a second
        want = interpolate(before.odom, scan.odom, f)
        assert (shifted.odom.x, shifted.odom.y) == pytest.approx((want.x, want.y), abs=1e-9)
        assert shifted.odom.theta == pytest.approx(want.theta, abs=1e-9)
    moved = [math.hypot(a.odom.x - b.odom.x, a.odom.y - b.odom.y)
             for a, b in zip(late, plain, strict=True)]
    assert max(moved) > 0.005  # the robot moves: a real shift, not the same poses


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


def test_legacy_bag_one_line_error(datasets, cli, tmp_path):
    r = cli("process", datasets / "rosbag1/legacy-rosrecord-v1.2.bag", "-o", tmp_path / "o")
    assert r.exit_code == 1
    assert len(r.stderr.strip().splitlines()) == 1 and "pre-2.0 ROS bag" in r.stderr
    assert not (tmp_path / "o").exists()


def test_bag_whose_index_rosbags_rejects_is_read_chunk_by_chunk(datasets, cli, tmp_path):
    """Issue 38 item 7: the early writer's index of handheld-hokuyo-old-index.bag made it
    unreadable; its chunks read fine one after another."""
    r = cli("process", datasets / "rosbag1/handheld-hokuyo-old-index.bag", "-o",
            tmp_path / "o", "-q")
    assert r.exit_code == 0, r.stderr
    assert len(read_tum(tmp_path / "o/trajectory.tum")) == 360
    warnings = json.loads((tmp_path / "o/summary.json").read_text())["reader"]["warnings"]
    assert warnings["bag index not usable (AssertionError): its chunks were read one after "
                    "another ('rosbag reindex' would rebuild the index)"] == 1
    assert not any(k.startswith("unreadable from byte") for k in warnings)


def small_chunks_bag(src: Path, dst: Path) -> Path:
    """``src`` (a ROS 1 bag) rewritten in chunks of about 16 kB, as a long recording has
    many: cut short, it keeps whole chunks."""
    from rosbags.rosbag1 import Reader, Writer

    writer = Writer(dst)
    writer.chunk_threshold = 16384
    with Reader(src) as r, writer as w:
        conns = {c.id: w.add_connection(c.topic, c.msgtype, msgdef=c.msgdef.data,
                                        md5sum=c.digest) for c in r.connections}
        for c, t, raw in r.messages():
            w.write(conns[c.id], t, raw)
    return dst


def small_chunks_mcap(src: Path, dst: Path) -> Path:
    """``src`` (an MCAP file, any profile) rewritten in chunks of about 16 kB."""
    from mcap.reader import make_reader
    from mcap.writer import Writer

    with open(src, "rb") as f, open(dst, "wb") as g:
        reader = make_reader(f)
        w = Writer(g, chunk_size=16384)
        w.start(profile=reader.get_header().profile, library="test")
        schemas: dict[int, int] = {}
        channels: dict[int, int] = {}
        for schema, channel, m in reader.iter_messages():
            if channel.id not in channels:
                if schema.id not in schemas:
                    schemas[schema.id] = w.register_schema(schema.name, schema.encoding,
                                                           schema.data)
                channels[channel.id] = w.register_channel(channel.topic,
                                                          channel.message_encoding,
                                                          schemas[schema.id])
            w.add_message(channels[channel.id], log_time=m.log_time,
                          publish_time=m.publish_time, sequence=m.sequence, data=m.data)
        w.finish()
    return dst


def cut_short(path: Path, share: float) -> Path:
    """``path`` cut after ``share`` of its bytes, as a recorder that crashed leaves it."""
    data = path.read_bytes()
    cut = path.with_name("cut-" + path.name)
    cut.write_bytes(data[: int(len(data) * share)])
    return cut


def damaged_logs(simulated: dict[str, str], tmp_path: Path) -> dict[str, Path]:
    """Each container cut at 60 %: a ROS 1 bag, a ROS 1 MCAP file, a rosbag2 MCAP file."""
    ros2_mcap = next(Path(simulated["rosbag2-mcap"]).glob("*.mcap"))
    return {
        "rosbag1": cut_short(small_chunks_bag(Path(simulated["rosbag1"]),
                                              tmp_path / "hall.bag"), 0.6),
        "mcap": cut_short(small_chunks_mcap(Path(simulated["mcap"]), tmp_path / "hall.mcap"),
                          0.6),
        "rosbag2-mcap": cut_short(small_chunks_mcap(ros2_mcap, tmp_path / "ros2.mcap"), 0.6),
    }


@pytest.mark.parametrize("fmt", ["rosbag1", "mcap", "rosbag2-mcap"])
def test_container_cut_short_is_read_up_to_the_damage(simulated, cli, tmp_path, fmt):
    """Issue 38 item 7: a bag or MCAP file cut short (no index, no summary, a last chunk cut)
    was refused whole; the chunks before the cut are read, and where the damage starts is a
    counted warning. The scans read are the first ones of the whole log."""
    cut = damaged_logs(simulated, tmp_path)[fmt]
    r = cli("process", cut, "-o", tmp_path / "o", "-q", "--localization", "odometry")
    assert r.exit_code == 0, r.stderr
    traj = read_tum(tmp_path / "o/trajectory.tum")
    assert 150 < len(traj) < 401
    assert cli("process", simulated[fmt], "-o", tmp_path / "whole", "-q", "--localization",
               "odometry").exit_code == 0
    whole = read_tum(tmp_path / "whole/trajectory.tum")
    # (the last scan may have lost the odometry recorded after it: held, a counted warning)
    np.testing.assert_allclose(traj[:-1], whole[: len(traj) - 1], atol=1e-6)
    warnings = json.loads((tmp_path / "o/summary.json").read_text())["reader"]["warnings"]
    (damage,) = [k for k in warnings if k.startswith("unreadable from byte")]
    assert f" of {cut.stat().st_size} (" in damage and warnings[damage] == 1
    assert damage in r.stderr


def test_bag_of_a_crashed_recorder_without_index_is_read(simulated, cli, tmp_path):
    """A recorder that crashed leaves index_pos 0 in the bag header (and no index): rosbags
    says 'reindex before reading'; the chunks are read, and the file's end is not damage."""
    from rosbags.rosbag1.reader import Header, RecordType

    bag = small_chunks_bag(Path(simulated["rosbag1"]), tmp_path / "hall.bag")
    data = bytearray(bag.read_bytes())
    with open(bag, "rb") as f:
        f.readline()
        index_pos = Header.read(f, RecordType.BAGHEADER).get_uint64("index_pos")
    at = data.index(b"index_pos=") + len(b"index_pos=")
    data[at: at + 8] = bytes(8)
    crashed = tmp_path / "crashed.bag"
    crashed.write_bytes(bytes(data[:index_pos]))
    r = cli("process", crashed, "-o", tmp_path / "o", "-q")
    assert r.exit_code == 0, r.stderr
    assert len(read_tum(tmp_path / "o/trajectory.tum")) == 401
    warnings = json.loads((tmp_path / "o/summary.json").read_text())["reader"]["warnings"]
    assert any(k.startswith("bag index not usable (Bag is not indexed") for k in warnings)
    assert not any(k.startswith("unreadable from byte") for k in warnings)


def clock_stepped_back(src: Path, dst: Path, start_s: float, span_s: float, back_s: float
                       ) -> Path:
    """``src`` (a ROS 1 bag) as a converter writes a log whose clock stepped back by
    ``back_s`` seconds for ``span_s`` seconds from ``start_s`` into the log: the stamps of
    those messages (header and record time) moved back, the bag sorted by them; each
    message keeps its ``header.seq``."""
    import struct

    from rosbags.rosbag1 import Reader, Writer

    with Reader(src) as r:
        first = r.start_time
        conns = list(r.connections)
        moved = []
        for c, t, raw in r.messages():
            if start_s <= (t - first) * 1e-9 < start_s + span_s:
                t -= round(back_s * 1e9)
                sec, nsec = divmod(t, 10**9)
                raw = raw[:4] + struct.pack("<II", sec, nsec) + raw[12:]
            moved.append((t, c.id, raw))
    with Writer(dst) as w:
        out = {c.id: w.add_connection(c.topic, c.msgtype, msgdef=c.msgdef.data,
                                      md5sum=c.digest) for c in conns}
        for t, cid, raw in sorted(moved, key=lambda m: m[0]):
            w.write(out[cid], t, raw)
    return dst


def test_bag_sorted_by_a_clock_that_stepped_back_is_read_in_publication_order(
        simulated, cli, tmp_path):
    """A bag converted from a log whose clock stepped back (the benchmark's Intel bag) is
    sorted by the broken stamps: a second of scans and odometry comes in between the second
    before it. Read in the order the publishers numbered them (header.seq), each scan gets
    its own odometry: the same poses as from the bag that was in order (trajectory.tum
    sorts rows by stamp, so the two are compared as sets)."""
    scrambled = clock_stepped_back(Path(simulated["rosbag1"]), tmp_path / "back.bag",
                                   start_s=10.0, span_s=1.0, back_s=0.85)
    for name, bag in (("in_order", simulated["rosbag1"]), ("scrambled", scrambled)):
        r = cli("process", bag, "-o", tmp_path / name, "-q", "--localization", "odometry")
        assert r.exit_code == 0, r.stderr
    ref, got = (read_tum(tmp_path / name / "trajectory.tum") for name in
                ("in_order", "scrambled"))
    assert len(got) == len(ref)
    ref, got = (t[np.lexsort(t[:, 2:0:-1].T), 1:] for t in (ref, got))
    np.testing.assert_allclose(got, ref, atol=1e-6)
    warnings = json.loads((tmp_path / "scrambled/summary.json").read_text())["reader"][
        "warnings"]
    assert warnings["messages logged before ones their publisher sent earlier (ROS 1 "
                    "header.seq): read in the order they were sent"] > 0


@pytest.mark.parametrize(("fmt", "kind"), [
    ("rosbag1", "bag"), ("mcap", "MCAP file"), ("rosbag2-mcap", "MCAP file"),
    ("rosbag2", "ROS 2 bag (.db3)")])
def test_container_with_nothing_readable_is_one_line_naming_its_kind(simulated, cli,
                                                                      tmp_path, fmt, kind):
    """Cut in the middle of its only chunk nothing is readable: one line that names the
    file's kind (a truncated ros2 .mcap said 'cannot read this bag')."""
    log = Path(simulated[fmt])
    if log.is_dir():
        log = next(p for p in log.iterdir() if p.suffix in (".mcap", ".db3"))
    cut = cut_short(log, 0.5)
    r = cli("process", cut, "-o", tmp_path / "o")
    assert r.exit_code == 1, r.output
    assert r.stderr.startswith(f"dynslam: error: {cut}: cannot read this {kind}: ")
    assert r.stderr.count("\n") == 1 and "Traceback" not in r.stderr
    assert not (tmp_path / "o").exists()


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


def _mount_stated_ahead(log: Path, dst: Path, ahead_m: float) -> None:
    """``log`` (Carmen FLASER lines) rewritten to state its laser ``ahead_m`` in front of
    the robot's centre, where the simulated laser sits at the centre."""
    lines = []
    for line in log.read_text().splitlines():
        f = line.split()
        if f and f[0] == "FLASER":
            n = int(f[1])
            x, y, theta = map(float, f[n + 5:n + 8])
            f[n + 2:n + 5] = [f"{x + ahead_m * math.cos(theta):.6f}",
                              f"{y + ahead_m * math.sin(theta):.6f}", f"{theta:.6f}"]
        lines.append(" ".join(f))
    dst.write_text("\n".join(lines) + "\n")


def test_a_mount_stated_wrong_is_read_as_the_user_gives_it(simulated, cli, tmp_path):
    """A log that states its laser 30 cm ahead of where it sits (a converter's mount): read
    as it is, each turn swings the scans and the trajectory is off; with the mount given
    (``[laser] mount_*``) every scan is mounted as in the true log, and the run is the true
    log's, byte for byte. Each coordinate given replaces that one alone."""
    from dynslam_formats import ReaderOptions, open_log

    true_log = Path(simulated["carmen"])
    wrong = tmp_path / "wrong.log"
    _mount_stated_ahead(true_log, wrong, 0.3)
    source, _, reader = open_log(str(wrong), ReaderOptions(mount_x_m=0.0, mount_deg=90.0))
    try:
        mounts = {scan.laser for scan in reader.scans()}
    finally:
        source.close()
    assert len(mounts) == 1
    (mount,) = mounts
    assert (mount.x, mount.theta) == (0.0, pytest.approx(math.pi / 2))
    assert abs(mount.y) < 1e-5  # the log's own y (0, as the six decimals write it)
    assert json.loads(cli("info", wrong, "--json").stdout)["laser_mount"] == [[0.3, 0.0, 0.0]]

    fixed = tmp_path / "mount.toml"
    fixed.write_text("[laser]\nmount_x_m = 0.0\nmount_y_m = 0.0\nmount_deg = 0.0\n")
    truth = true_log.parent / "truth.json"
    runs, ate = {}, {}
    for name, log, extra in (("true", true_log, ()), ("wrong", wrong, ()),
                             ("fixed", wrong, ("--config", fixed))):
        r = cli("process", log, "-o", tmp_path / name, "-q", *extra)
        assert r.exit_code == 0, r.stderr
        runs[name] = (tmp_path / name / "trajectory.tum").read_bytes()
        r = cli("evaluate", tmp_path / name, "--truth", truth, "--json")
        ate[name] = json.loads(r.stdout)["truth"]["trajectory"]["ate_rmse_m"]
    assert runs["fixed"] == runs["true"]
    assert ate["wrong"] > 2 * ate["true"], ate


class _Scans:
    """A reader of given scans (what a log reader hands the guard's filters)."""

    def __init__(self, scans):
        from dynslam_formats.base import ReadStats

        self._scans, self.stats, self.format_name = scans, ReadStats(), "test"

    def scans(self):
        yield from self._scans


def _turning_in_a_room(delay_s: float, steps: int = 300):
    """A robot turning on the spot in a 10 m square room (0.6 rad/s, its turn rate
    changing), its laser sweeping 361 beams over 180°, the odd ones ``delay_s`` after the
    even ones; the scans, and the robot's heading when each scan's even beams were seen."""
    from dynslam_cli.types import Pose2D, Scan

    angles = np.radians(np.linspace(-90.0, 90.0, 361))
    scans, headings, heading = [], [], 0.0
    for k in range(steps):
        rate = 0.6 * math.sin(k / 20)
        seen = heading + np.where(np.arange(361) % 2 == 1, rate * delay_s, 0.0) + angles
        c, s = np.cos(seen), np.sin(seen)
        ranges = np.minimum(5.0 / np.maximum(np.abs(c), 1e-9), 5.0 / np.maximum(np.abs(s), 1e-9))
        scans.append(Scan(stamp=0.1 * k, ranges=ranges, angles=angles, max_range=20.0,
                          odom=Pose2D(0.0, 0.0, heading)))
        headings.append(heading)
        heading += 0.1 * rate
    return scans, headings


def _off_the_walls(scan, heading: float) -> np.ndarray:
    """How far each end point, at the robot's heading, lies off the room's walls (m)."""
    x = scan.ranges * np.cos(heading + scan.angles)
    y = scan.ranges * np.sin(heading + scan.angles)
    return np.minimum(np.abs(np.abs(x) - 5.0), np.abs(np.abs(y) - 5.0))


def test_an_interlaced_lasers_odd_beams_are_turned_back_onto_the_walls():
    """A laser whose odd beams are seen 13 ms after its even ones (a SICK LMS at half a
    degree), on a turning robot: the log's first turning scans tell the delay, said once,
    and each odd beam is turned by the robot's turn in that time, so every end point lies
    on the walls again; a laser that sweeps once is read as it is, and so are a log read
    with ``interlace_s = 0`` and one with too few turns to tell."""
    from dynslam_formats.guard import INTERLACED, Interlaced, odd_beam_delay

    scans, headings = _turning_in_a_room(0.0133)
    delay, turning = odd_beam_delay(scans)
    assert delay == pytest.approx(0.0133, rel=0.1) and turning > 200
    reader = _Scans(scans)
    deskewed = list(Interlaced(reader, None).scans())
    [warning] = reader.stats.warnings
    assert warning.startswith(INTERLACED.split("{")[0])
    raw = max(_off_the_walls(s, h).max() for s, h in zip(scans, headings, strict=True))
    fixed = max(_off_the_walls(s, h).max() for s, h in zip(deskewed, headings, strict=True))
    assert raw > 0.03 and fixed < raw / 10
    assert all(np.array_equal(a.ranges, b.ranges) for a, b in zip(scans, deskewed, strict=True))
    assert [s.angles is scans[0].angles for s in Interlaced(_Scans(scans), 0.0).scans()] == \
        [True] * len(scans)  # (given as 0: nothing turned)
    gap = dataclasses.replace(scans[50], ranges=np.delete(scans[50].ranges, 100),
                              angles=np.delete(scans[50].angles, 100))
    assert list(Interlaced(_Scans([scans[49], gap]), 0.0133).scans())[1] is gap  # (a beam
    # dropped: which beams are the odd pass's is not known)
    few, _ = _turning_in_a_room(0.0133, steps=30)  # (too few turns to tell)
    assert all(a is b for a, b in zip(Interlaced(_Scans(few), None).scans(), few, strict=True))
    once, _ = _turning_in_a_room(0.0)
    assert abs(odd_beam_delay(once)[0]) < 1e-4
    reader = _Scans(once)
    assert all(a is b for a, b in zip(Interlaced(reader, None).scans(), once, strict=True))
    assert not reader.stats.warnings


def test_the_scan_store_gives_back_each_scans_turned_odd_beams():
    """The maps rebuilt at the end read the scans the run saw: an interlaced laser's scans,
    their odd beams each turned its own way, come back from the store with those angles."""
    from dynslam_cli.scanstore import ScanStore
    from dynslam_formats.guard import Interlaced

    scans, _ = _turning_in_a_room(0.0133, steps=40)
    deskewed = list(Interlaced(_Scans(scans), 0.0133).scans())
    store = ScanStore()
    for scan in deskewed:
        store.add(scan)
    back = list(store.scans())
    assert len({round(float(s.angles[1] - s.angles[0]), 9) for s in back}) > 10
    for want, got in zip(deskewed, back, strict=True):
        np.testing.assert_allclose(got.angles, want.angles, rtol=0, atol=1e-12)


def test_the_benchmarks_interlaced_lasers_are_told_from_a_single_sweep(datasets):
    """MIT CSAIL's SICK sweeps its 361 beams in two passes (its odd beams' copy of a wall
    turns with the robot), Intel's 180 in one: the delay is found on the one, not on the
    other."""
    from dynslam_formats import ReaderOptions, open_log
    from dynslam_formats.guard import INTERLACE_PROBE_SCANS, odd_beam_delay

    def first_scans(path):
        source, _, reader = open_log(str(path), ReaderOptions())
        try:
            return list(itertools.islice(reader.scans(), INTERLACE_PROBE_SCANS))
        finally:
            source.close()

    mit, _ = odd_beam_delay(first_scans(datasets / "carmen/mit-csail.clf"))
    intel, _ = odd_beam_delay(first_scans(datasets / "carmen/kummerle/intel.clf.gz"))
    assert 0.005 < mit < 0.015 and abs(intel) < 0.001
