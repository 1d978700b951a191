"""The Carmen reader: every record type, the beam-angle rule, quirks and bad input."""

from __future__ import annotations

import gzip
import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from dynslam_cli.errors import InputError
from dynslam_formats import ReaderOptions, open_log
from dynslam_formats.carmen import carmen_beam_angles
from tests.conftest import flaser


def read(path: Path | str, **options):
    source, entry, reader = open_log(str(path), ReaderOptions(**options))
    try:
        return entry.name, list(reader.scans()), reader.stats
    finally:
        source.close()


def write(tmp_path: Path, text: str, name: str = "log.clf") -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


def test_flaser_uses_second_pose_triple_and_mounting_offset(tmp_path):
    line = ("FLASER 3 1.0 2.0 3.0 1.2 2.0 0.5 1.0 2.0 0.5 10.5 host 10.6\n")
    _, scans, stats = read(write(tmp_path, "# CARMEN Logfile\n" + line))
    (s,) = scans
    assert (s.odom.x, s.odom.y, s.odom.theta) == (1.0, 2.0, 0.5)
    assert math.hypot(s.laser.x, s.laser.y) == pytest.approx(0.2)
    assert s.stamp == 10.5 and s.max_range == 80.0
    assert list(s.ranges) == [1.0, 2.0, 3.0]
    assert stats.records["#comment"] == 1


@pytest.mark.parametrize(("n", "step_deg"), [(180, 1.0), (181, 1.0), (360, 0.5), (361, 0.5),
                                             (91, 2.0)])
def test_carmen_beam_rule(n, step_deg):
    start, step = carmen_beam_angles(n)
    assert start == pytest.approx(-math.pi / 2)
    assert step == pytest.approx(math.radians(step_deg))


def test_flaser_angles_from_param_and_override(tmp_path):
    text = ("PARAM laser_front_laser_fov 100 nohost 0\nPARAM laser_front_laser_max_range 8 x 0\n"
            + flaser(n=11))
    _, (s,), _ = read(write(tmp_path, text))
    assert s.angles[0] == pytest.approx(math.radians(-50))
    assert s.angles[-1] == pytest.approx(math.radians(50))
    assert s.max_range == 8.0
    _, (s,), _ = read(write(tmp_path, flaser(n=11)), fov_deg=200.0)
    assert s.angles[-1] - s.angles[0] == pytest.approx(math.radians(200))


@pytest.mark.parametrize(("fov", "res", "n", "span_deg"), [
    ("3.14159", "0.5", 361, 180.0),  # radians (csail-corrected): 361 beams at 0.5° span π
    ("180", "0.5", 361, 180.0),  # degrees, as CARMEN writes it
    ("3.14159", None, 181, 180.0),  # radians, no resolution: under 6.3° is no laser
    ("6", "0.5", 13, 6.0),  # degrees: 13 beams at 0.5° span 6°, not 6 rad
])
def test_flaser_fov_param_in_degrees_or_radians(tmp_path, fov, res, n, span_deg):
    text = f"PARAM laser_front_laser_fov {fov} nohost 0\n"
    if res is not None:
        text += f"PARAM laser_front_laser_resolution {res} nohost 0\n"
    _, (s,), stats = read(write(tmp_path, text + flaser(n=n)))
    assert math.degrees(s.angles[-1] - s.angles[0]) == pytest.approx(span_deg, abs=1e-3)
    said = any("read as radians" in w for w in stats.warnings)
    assert said == (span_deg != float(fov))


def flaser_with(ranges: str, t: float = 1.0) -> str:
    return f"FLASER {len(ranges.split())} {ranges} 0 0 0 0 0 0 {t} host {t}\n"


def test_readings_beyond_param_max_range_contradict_it(tmp_path):
    """edmonton: PARAM max 10 m, real readings to 46 m, no returns at 51.15 m."""
    text = "PARAM robot_front_laser_max 10 nohost 0\n"
    text += flaser_with("5 46 51.15 51.1", t=1) + flaser_with("5 6 7 8", t=2)
    _, scans, stats = read(write(tmp_path, text))
    for s in scans:  # 46 m is a reading; 51.1 and 51.15 are no returns
        assert 46 < s.max_range <= 51.1
    assert sum("beyond the PARAM max range" in w for w in stats.warnings) == 1
    _, (s,), stats = read(write(tmp_path, "PARAM robot_front_laser_max 10 x 0\n"
                                + flaser_with("5 9")))
    assert s.max_range == 10.0 and not stats.warnings  # no contradiction: the PARAM


def test_config_max_range_reaches_every_consumer(tmp_path):
    from dynslam_cli.config import Config, LaserConfig
    from dynslam_cli.localization.frontend import ScanMeasurer
    from dynslam_cli.readahead import FrontEnd
    path = write(tmp_path, flaser_with("1 2 3 9", t=1) + flaser(n=4, t=2))
    config = Config(laser=LaserConfig(max_range_m=5.0))
    source, _, reader = open_log(str(path), ReaderOptions(**config.laser.reader_options()))
    front = FrontEnd(reader, source,
                     ScanMeasurer.configured(config.ekf, config.match, config.corners))
    scans = list(front.scans())
    assert [s.max_range for s in scans] == [5.0, 5.0]  # what the matcher and the maps see
    source.close()


def test_rlaser_is_the_rear_laser(tmp_path):
    text = flaser() + flaser(t=2).replace("FLASER", "RLASER")
    _, scans, _stats = read(write(tmp_path, text), laser="rear")
    assert [s.stamp for s in scans] == [2.0]
    _, scans, _ = read(write(tmp_path, text))
    assert [s.stamp for s in scans] == [1.0]


def test_robotlaser1_angles_and_offset(tmp_path):
    ranges = "1 2 3 4"
    line = (f"ROBOTLASER1 0 -0.3 0.6 0.2 30.0 0.01 0 4 {ranges} 2 9 9 "
            "1.1 0 0.2 1.0 0 0.2 0 0 0 0 0 5.0 host 5.0\n")
    _, (s,), _ = read(write(tmp_path, line, "x.log"))
    np.testing.assert_allclose(s.angles, [-0.3, -0.1, 0.1, 0.3])
    assert s.max_range == 30.0
    assert s.odom.x == 1.0 and s.odom.theta == pytest.approx(0.2)
    assert math.hypot(s.laser.x, s.laser.y) == pytest.approx(0.1)
    assert s.laser.theta == pytest.approx(0)


def test_rawlaser_odometry_interpolated_from_odom(tmp_path):
    text = ("ODOM 0 0 0 0 0 0 1.0 h 1.0\n"
            "RAWLASER1 0 -1.5 3.0 1.5 20 0.01 0 3 1 2 3 0 1.5 h 1.5\n"
            "ODOM 2 4 1.0 0 0 0 2.0 h 2.0\n"
            "RAWLASER1 0 -1.5 3.0 1.5 20 0.01 0 3 1 2 3 0 3.0 h 3.0\n")
    _, scans, stats = read(write(tmp_path, text))
    assert [(s.odom.x, s.odom.y, s.odom.theta) for s in scans] == [
        pytest.approx((1.0, 2.0, 0.5)), pytest.approx((2.0, 4.0, 1.0))]
    assert stats.warnings["scan after the last odometry record: odometry held"] == 1


def test_laser3_without_pose_uses_odom(tmp_path):
    text = "ODOM 1 1 0 0 0 0 1.0 h 1.0\nLASER3 3 1 2 3 1.0 h 1.0\nODOM 1 1 0 0 0 0 2 h 2\n"
    _, (s,), _ = read(write(tmp_path, text), laser="3")
    assert (s.odom.x, s.odom.y) == (1.0, 1.0)


def test_unknown_and_unused_records_counted(tmp_path):
    text = "FOO 1 2 3\nTRUEPOS 0 0 0 0 0 0 1 h 1\nNEFF 30\n" + flaser()
    _, scans, stats = read(write(tmp_path, text))
    assert len(scans) == 1
    assert stats.records["FOO"] == 1 and stats.records["TRUEPOS"] == 1
    assert stats.warnings["unknown record type FOO (ignored)"] == 1


def test_duplicate_laser_kind_skipped(tmp_path):
    robot = ("ROBOTLASER1 0 -0.3 0.6 0.2 30.0 0.01 0 4 1 2 3 4 0 "
             "0 0 0 0 0 0 0 0 0 0 0 2.0 host 2.0\n")
    _, scans, stats = read(write(tmp_path, flaser() + robot))
    assert len(scans) == 1
    assert sum(stats.skipped.values()) == 1


def test_gzip_by_suffix_and_by_magic(tmp_path):
    data = gzip.compress((flaser() + flaser(t=2)).encode())
    (tmp_path / "a.log.gz").write_bytes(data)
    (tmp_path / "b.clf").write_bytes(data)
    assert len(read(tmp_path / "a.log.gz")[1]) == 2
    assert len(read(tmp_path / "b.clf")[1]) == 2


GOOD_LINES = "".join(flaser(n=181, t=i) for i in range(1, 200))


def test_truncated_gzip_reads_what_is_readable(tmp_path):
    """Issue 38 item 7: a .log.gz cut short (a robot that crashed while logging) was refused
    whole; its readable lines are read, and where the compressed data end is a warning."""
    data = gzip.compress(GOOD_LINES.encode(), mtime=0)
    cut = data[: len(data) // 2]
    (tmp_path / "a.log.gz").write_bytes(cut)
    _, scans, stats = read(tmp_path / "a.log.gz")
    (reason,) = stats.warnings
    assert reason.startswith(f"compressed data ends at byte {len(cut)} before its end")
    line = stats.first_line[reason]
    assert len(scans) == line - 1 > 50  # every line before the cut one
    assert stats.skipped == {"damaged last line (log cut off while written)": 1}
    assert stats.first_line["damaged last line (log cut off while written)"] == line


def test_gzip_damaged_midway_reads_up_to_the_damage(tmp_path):
    """A second gzip member that is not one (a bad copy): the first member's lines are
    read, and the damage is placed where it starts (after the zero padding)."""
    first = gzip.compress(GOOD_LINES.encode(), mtime=0)
    (tmp_path / "a.log.gz").write_bytes(first + b"\0\0" + b"not gzip at all" * 10)
    _, scans, stats = read(tmp_path / "a.log.gz")
    assert len(scans) == 199
    (reason,) = stats.warnings
    assert reason.startswith(f"compressed data damaged between bytes {len(first) + 2} and ")
    assert "incorrect header check" in reason and stats.first_line[reason] == 200


def test_gzip_members_and_zero_padding_read_as_one_log(tmp_path):
    data = gzip.compress(flaser().encode()) + gzip.compress(flaser(t=2).encode()) + b"\0" * 9
    (tmp_path / "a.log.gz").write_bytes(data)
    _, scans, stats = read(tmp_path / "a.log.gz")
    assert len(scans) == 2 and not stats.warnings and not stats.skipped


def test_truncated_gzip_is_processed_with_one_warning_line(tmp_path):
    """What the user sees: the run ends 0 with the damage on stderr and in summary.json."""
    data = gzip.compress(GOOD_LINES.encode(), mtime=0)
    (tmp_path / "a.log.gz").write_bytes(data[: len(data) // 2])
    proc = subprocess.run([sys.executable, "-m", "dynslam_cli", "process",
                           str(tmp_path / "a.log.gz"), "-o", str(tmp_path / "out"), "-q"],
                          capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    warned = [x for x in proc.stderr.splitlines() if "compressed data ends at byte" in x]
    assert len(warned) == 1 and warned[0].startswith("dynslam: warning: ")
    summary = json.loads((tmp_path / "out/summary.json").read_text())
    assert any(k.startswith("compressed data ends") for k in summary["reader"]["warnings"])


def test_gzip_without_stats_keeps_the_error(tmp_path):
    """A plugin reading ``text_lines`` without stats still hears of the damage."""
    from dynslam_formats.source import Source, text_lines

    data = gzip.compress(GOOD_LINES.encode(), mtime=0)
    (tmp_path / "a.log.gz").write_bytes(data[: len(data) // 2])
    source = Source(str(tmp_path / "a.log.gz"))
    try:
        with pytest.raises(InputError, match="compressed data ends at byte"):
            list(text_lines(source))
    finally:
        source.close()


def test_stdin_is_read(tmp_path):
    out = tmp_path / "out"
    proc = subprocess.run([sys.executable, "-m", "dynslam_cli", "process", "-", "-o", str(out),
                           "-q"], input=(flaser() + flaser(t=2)).encode(), capture_output=True)
    assert proc.returncode == 0, proc.stderr
    assert len((out / "trajectory.tum").read_text().splitlines()) == 2


@pytest.mark.parametrize(("text", "line", "message"), [
    ("FLASER 5 1 2 3\n", 1, "FLASER has 4 fields, expected 15"),
    (flaser() + "FLASER 5 1 2 x 4 5 0 0 0 0 0 0 1 h 1\n", 2, r"field 4 \('x'\) is not a number"),
    (flaser(n=4).replace("FLASER 4", "FLASER 6"), 1, "has 14 fields, expected 16 for 6 beams"),
    ("ODOM 1 2\n" + flaser(), 1, "ODOM has 2 fields"),
    ("FLASER -3 1 2\n", 1, "beam count -3 is negative"),
    ("FLASER five 1 2\n", 1, "should be a beam count"),
])
def test_malformed_lines_are_errors_with_file_and_line(tmp_path, text, line, message):
    p = write(tmp_path, text)
    with pytest.raises(InputError, match=message) as info:
        read(p)
    assert info.value.line == line
    assert str(info.value).startswith(f"{p}:{line}: ")


def test_bad_ranges_counted_not_fatal(tmp_path):
    text = flaser(n=4).replace("2.000 2.000 2.000 2.000", "nan -1 inf 2.0")
    _, (s,), stats = read(write(tmp_path, text))
    assert np.isnan(s.ranges[0]) and np.isnan(s.ranges[1]) and np.isposinf(s.ranges[2])
    assert stats.warnings["invalid ranges (NaN or negative): beam dropped"] == 2
    assert stats.warnings["+inf ranges: no return"] == 1


def test_nonfinite_pose_skips_scan(tmp_path):
    _, scans, stats = read(write(tmp_path, flaser(pose=(math.nan, 0, 0)) + flaser(t=2)))
    assert len(scans) == 1 and stats.skipped["pose is NaN or infinite"] == 1


def test_odometry_clock_stepping_back_restarts_interpolation(tmp_path):
    """Records written in the order they were made, stamped by a clock that stepped back
    by a second: the scans after the step are paired with the odometry after it."""
    text = ("ODOM 0 0 0 0 0 0 1.0 h 1.0\n"
            "RAWLASER1 0 -1.5 3.0 1.5 20 0.01 0 3 1 2 3 0 1.5 h 1.5\n"
            "ODOM 2 0 0 0 0 0 2.0 h 2.0\n"
            "ODOM 3 0 0 0 0 0 1.1 h 1.1\n"
            "RAWLASER1 0 -1.5 3.0 1.5 20 0.01 0 3 1 2 3 0 1.35 h 1.35\n"
            "ODOM 4 0 0 0 0 0 1.6 h 1.6\n")
    _, scans, stats = read(write(tmp_path, text))
    assert [s.odom.x for s in scans] == [pytest.approx(1.0), pytest.approx(3.5)]
    assert stats.warnings["odometry time stamp goes backwards (interpolation starts again "
                          "from that record)"] == 1


def test_time_going_backwards_is_kept_and_counted(tmp_path):
    _, scans, stats = read(write(tmp_path, flaser(t=5) + flaser(t=3) + flaser(t=3)))
    assert [s.stamp for s in scans] == [5, 3, 3]
    assert stats.warnings["time stamp does not increase (scan kept in file order)"] == 2


def test_damaged_last_line_is_skipped(tmp_path):
    _, scans, stats = read(write(tmp_path, flaser() + flaser(t=2)[:40]))
    assert len(scans) == 1
    assert stats.skipped["damaged last line (log cut off while written)"] == 1


def test_empty_log_and_no_laser_are_errors(tmp_path):
    with pytest.raises(InputError, match="empty log"):
        read(write(tmp_path, ""))
    with pytest.raises(InputError, match="no FLASER/RAWLASER1/ROBOTLASER1 records"):
        read(write(tmp_path, "ODOM 0 0 0 0 0 0 1 h 1\n"))


def test_unknown_format_is_an_error(tmp_path):
    with pytest.raises(InputError, match="cannot tell the log format"):
        read(write(tmp_path, "hello world\n", "x.txt"))


# -- the real logs --------------------------------------------------------------------------
def test_mit_csail(datasets):
    fmt, scans, stats = read(datasets / "carmen/mit-csail.clf")
    assert fmt == "carmen" and len(scans) == 1988
    assert len(scans[0].ranges) == 361
    assert scans[0].angles[1] - scans[0].angles[0] == pytest.approx(math.radians(0.5))
    assert not stats.skipped


def test_csail_robotlaser1(datasets):
    _, scans, _ = read(datasets / "carmen/csail-robotlaser1.log")
    assert len(scans) == 686
    assert scans[0].angles[0] == pytest.approx(-1.570796)
    assert scans[0].max_range == 80.0


def test_zaragoza_nan_readings_and_zero_stamps(datasets):
    _, scans, stats = read(datasets / "carmen/zaragoza-laserazosSM3.log")
    assert len(scans) == 778
    assert stats.warnings["invalid ranges (NaN or negative): beam dropped"] > 0


def test_zaragoza_truncated_fields_clear_error(datasets):
    path = datasets / "carmen/zaragoza-laserazosSM3-truncated-fields.log"
    with pytest.raises(InputError, match="timestamp and host fields are missing") as info:
        read(path)
    assert info.value.line == 1


@pytest.mark.parametrize("name", ["belgioioso", "csail", "freiburg-campus", "orebro",
                                  "infinite-corridor", "intel", "fhw"])
def test_radish_quirks_never_crash(datasets, name):
    _, scans, stats = read(datasets / f"carmen/radish-corrected/{name}-corrected.log.gz")
    assert len(scans) == stats.records["FLASER"]
