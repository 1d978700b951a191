"""Bad input and faults end cleanly: a counted skip or one line and exit 1; no crash signal,
no hang, no traceback, nothing half-written left behind (issue: hardening)."""

from __future__ import annotations

import errno
import json
import os
import shutil
import signal
import subprocess
import sys
import time

import pytest

from tests.conftest import SAMPLES, flaser

SAMPLE = SAMPLES / "hall" / "hall.log"
R181 = " ".join(["2.0"] * 181)


def carmen_log(bad: str, fixed: str, good: int = 4) -> str:
    """One bad laser line, then ``good`` scans of the same kind (``fixed``, stamped later)
    with odometry."""
    lines = [bad + "\n"]
    for t in range(2, 2 + good):
        lines.append(f"ODOM 0 0 0 0 0 0 {t}.0 h {t}.0\n")
        lines.append(fixed.replace(" 1.0 h 1.0", f" {t}.0 h {t}.0") + "\n")
    return "".join(lines)


RAW = f"RAWLASER1 0 -1.5708 3.1416 0.0175 8.0 0.01 0 181 {R181} 0 1.0 h 1.0"
ROBOT = (f"ROBOTLASER1 0 -1.5708 3.1416 0.0175 8.0 0.01 0 181 {R181} 0 0 0 0 0 0 0 0 0 0 0 0 "
         "1.0 h 1.0")
FL = "FLASER 3 1 1 1 0 0 0 0 0 0 1.0 h 1.0"


@pytest.mark.parametrize(("bad", "fixed", "reason"), [
    (RAW.replace("0.0175", "nan"), RAW, "beam angles are not finite"),
    (RAW.replace("-1.5708", "inf"), RAW, "beam angles are not finite"),
    (ROBOT.replace("0.0175", "nan"), ROBOT, "beam angles are not finite"),
    (ROBOT.replace("-1.5708", "-inf"), ROBOT, "beam angles are not finite"),
    (RAW.replace("0.0175", "0.0"), RAW, "beam angles do not make a sweep"),
    (RAW.replace(" 8.0 ", " nan "), RAW, "max range is not a positive number"),
    (FL.replace(" 0 0 0 0 0 0 ", " 1e300 0 0 1e300 0 0 "), FL, "pose is not finite"),
    (FL.replace(" 0 0 0 0 0 0 ", " nan 0 0 nan 0 0 "), FL, "pose is"),  # (the reader's)
])
def test_non_finite_geometry_is_a_counted_skip(cli, tmp_path, bad, fixed, reason):
    log = tmp_path / "bad.log"
    log.write_text(carmen_log(bad, fixed))
    r = cli("process", log, "-o", tmp_path / "out", "-q")
    assert r.exit_code == 0, r.stderr
    summary = json.loads((tmp_path / "out/summary.json").read_text())
    assert summary["scans_processed"] == 4
    skipped = summary["reader"]["skipped"]
    assert sum(skipped.values()) == 1 and any(reason in k for k in skipped), skipped
    assert "Traceback" not in r.stderr and "RuntimeWarning" not in r.stderr


def test_a_log_whose_every_scan_is_skipped_is_an_error(cli, tmp_path):
    log = tmp_path / "bad.log"
    log.write_text(RAW.replace("0.0175", "nan") + "\n")
    r = cli("process", log, "-o", tmp_path / "out", "-q")
    assert r.exit_code == 1 and r.stderr.count("\n") == 1
    assert "no usable scans: all 1 were skipped (beam angles are not finite" in r.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.log"]


def test_too_many_beams_is_a_counted_skip_not_a_stall(cli, tmp_path):
    log = tmp_path / "wide.log"
    wide = flaser(100_000, t=1.0).strip()
    log.write_text(carmen_log(wide, flaser(181, t=1.0).strip()))
    start = time.perf_counter()
    r = cli("process", log, "-o", tmp_path / "out", "-q")
    assert r.exit_code == 0 and time.perf_counter() - start < 30
    skipped = json.loads((tmp_path / "out/summary.json").read_text())["reader"]["skipped"]
    assert any("more than 20000 beams" in k for k in skipped)


def test_a_map_beyond_its_bound_is_one_line(cli, tmp_path):
    text = SAMPLE.read_text().splitlines(keepends=True)
    n, out = 0, []
    for line in text:  # odometry jumps 100 km a third of the way in
        f = line.split()
        if f and f[0] in ("ODOM", "FLASER"):
            n += f[0] == "ODOM"
            if n > 150:
                for i in ([1] if f[0] == "ODOM" else [2 + int(f[1]), 5 + int(f[1])]):
                    f[i] = str(float(f[i]) + 1e5)
                line = " ".join(f) + "\n"
        out.append(line)
    log = tmp_path / "jump.log"
    log.write_text("".join(out))
    r = cli("process", log, "-o", tmp_path / "out", "--localization", "odometry", "-q")
    assert r.exit_code == 1
    assert r.stderr.count("\n") == 1 and "map.max_extent_m = 2000 m" in r.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["jump.log"]
    r = cli("process", SAMPLE, "-o", tmp_path / "fine", "--resolution", "1e-6", "-q")
    assert r.exit_code == 2  # the option's value: a usage error naming it
    assert "Invalid value for '--resolution': must be in [0.005, 10] m" in r.stderr


def test_output_into_a_dangling_symlink_is_refused(cli, tmp_path):
    (tmp_path / "link").symlink_to(tmp_path / "nowhere")
    r = cli("process", SAMPLE, "-o", tmp_path / "link", "-q")
    assert r.exit_code == 1 and "is a symbolic link" in r.stderr
    assert not (tmp_path / "nowhere").exists()


def test_full_disk_is_one_line_and_removes_what_it_made(cli, tmp_path, monkeypatch):
    import dynslam_formats.outdir

    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(dynslam_formats.outdir, "write_tum", full)
    r = cli("process", SAMPLE, "-o", tmp_path / "a/b/out", "-q")
    assert r.exit_code == 1
    assert r.stderr == f"dynslam: error: {tmp_path / 'a/b/out'}: cannot write the output: " \
                       "No space left on device\n"
    assert list(tmp_path.iterdir()) == []  # not even the parents it created


def test_stale_partial_folders_of_a_killed_run_are_cleaned(cli, tmp_path):
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    stale = tmp_path / ".out.abc123.partial"
    stale.mkdir()
    (stale / ".dynslam-run").write_text(f"{dead.pid} {os.uname().nodename}\n")
    (stale / "static.pgm").write_bytes(b"P5 half")
    legacy = tmp_path / ".out.def456.partial"  # from before owner files: output files only
    legacy.mkdir()
    (legacy / "map.png").write_bytes(b"")
    live = tmp_path / ".out.live99.partial"  # a run that is still writing: not touched
    live.mkdir()
    (live / ".dynslam-run").write_text(f"{os.getpid()} {os.uname().nodename}\n")
    foreign = tmp_path / ".out.xyz789.partial"  # holds something not ours: not touched
    foreign.mkdir()
    (foreign / "thesis.tex").write_text("precious")
    r = cli("process", SAMPLE, "-o", tmp_path / "out", "-q")
    assert r.exit_code == 0
    assert "removed 2 temporary folder(s)" in r.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        ".out.live99.partial", ".out.xyz789.partial", "out"]
    assert not (tmp_path / "out/.dynslam-run").exists()


@pytest.mark.parametrize("delay", [0.15, 0.4])
def test_ctrl_c_while_starting_exits_130_without_traceback(tmp_path, delay):
    proc = subprocess.Popen([sys.executable, "-m", "dynslam_cli", "process", "-", "-o",
                             str(tmp_path / "out"), "-q"], stdin=subprocess.PIPE,
                            stderr=subprocess.PIPE,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    time.sleep(delay)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    assert b"Traceback" not in err and b"Aborted" not in err
    assert list(tmp_path.iterdir()) == []


def test_endless_line_is_an_error_not_a_memory_error(cli, tmp_path):
    log = tmp_path / "digits.log"
    log.write_bytes(b"7" * 5_000_000)
    r = cli("process", log, "--format", "carmen", "-o", tmp_path / "out", "-q")
    assert r.exit_code == 1 and r.stderr.count("\n") == 1
    assert "a line longer than 4000000 characters" in r.stderr
    r = cli("process", "/dev/zero", "--format", "carmen", "-o", tmp_path / "out", "-q")
    assert r.exit_code == 1 and r.stderr.count("\n") == 1  # (binary: said at once)
    assert "not a text log: binary data (NUL bytes) near the start" in r.stderr


def test_garbage_is_not_echoed_raw():
    from dynslam_cli.errors import InputError

    e = InputError("x.log", "FLASER field 3 ('\x1b[2J\x00ok') is not a number" + "x" * 500, 3)
    assert str(e).isprintable() and "\\x1b" in str(e) and len(str(e)) < 320


GOOD_PLAYER = "11.0 1 6665 laser 00 001 001 0 -1.57 1.57 1.57 8 3 1 0 1 0 1 0\n"


@pytest.mark.parametrize(("record", "message"), [
    ("laser xx 001 001 0 -1.57 1.57 0.0175 8 1 2.0 0", "laser index 'xx' is not a whole"),
    ("laser 00 001 003 7", "scanangle needs id, max range and count"),
    ("laser 00 004 001 0.1", "laser geometry needs px py pyaw"),
    ("laser 00 001 001 0 -1.57 1.57 0.0175 8 nan", "beam count nan is not a whole number"),
    ("laser 00 001 001 0 -1.57 1.57 0.0175 8 -3", "beam count -3 is not a whole number"),
    ("laser 00 0x1 001 0 -1.57 1.57 0.0175 8 1 2.0 0", "type '0x1' is not a whole number"),
])
def test_player_records_that_do_not_fit_are_one_line(cli, tmp_path, record, message):
    log = tmp_path / "p.log"
    log.write_text(f"## File version 0.3.0\n10.0 1 6665 {record}\n{GOOD_PLAYER}")
    r = cli("process", log, "-o", tmp_path / "out", "-q")
    assert r.exit_code == 1 and r.stderr.count("\n") == 1, r.stderr
    assert f"p.log:2: {message}" in r.stderr


@pytest.mark.parametrize("version", ["9.9.9", "abc"])
def test_unknown_player_version_is_an_error(cli, tmp_path, version):
    log = tmp_path / "p.log"
    log.write_text(f"## File version {version}\n{GOOD_PLAYER}")
    r = cli("process", log, "--format", "player", "-o", tmp_path / "out", "-q")
    assert r.exit_code == 1 and f"unknown Player file version '{version}'" in r.stderr


def test_player_counts_what_it_leaves_out(cli, tmp_path):
    log = tmp_path / "p.log"
    log.write_text("## File version 0.3.0\n"
                   "nan 1 6665 laser 00 001 001 0 -1.57 1.57 1.57 8 3 1 0 1 0 1 0\n"
                   "10.5 1 6665 laser 00 004 002 1 2 3\n" + GOOD_PLAYER
                   + GOOD_PLAYER.replace("11.0", "12.0"))
    r = cli("process", log, "-o", tmp_path / "out", "-q")
    assert r.exit_code == 0, r.stderr
    reader = json.loads((tmp_path / "out/summary.json").read_text())["reader"]
    assert reader["skipped"] == {"time stamp is not a finite number": 1}
    assert reader["warnings"]["laser type 4 subtype 2 ignored"] == 1


def test_laserscan_whose_count_contradicts_its_angles_is_skipped():
    from types import SimpleNamespace

    from dynslam_formats.ros import span_agrees

    def scan(n, lo=-1.5, hi=1.5, inc=None):
        return SimpleNamespace(angle_min=lo, angle_max=hi,
                               angle_increment=(hi - lo) / 180 if inc is None else inc,
                               ranges=[1.0] * n)

    assert span_agrees(scan(181)) and span_agrees(scan(180)) and span_agrees(scan(182))
    assert not span_agrees(scan(90)) and not span_agrees(scan(361))
    assert span_agrees(scan(181, lo=1.5, hi=-1.5))  # a sweep the other way
    assert span_agrees(scan(181, inc=float("nan")))  # (the common guard skips it)


@pytest.mark.parametrize("delay", [0.05, 0.15, 0.4, 1.0])
def test_sigterm_at_any_moment_ends_143_and_leaves_nothing(tmp_path, delay):
    """Before the work starts the default action ends the process (the shell sees 143);
    from then on the handler cleans up and exits 143 itself."""
    proc = subprocess.Popen([sys.executable, "-m", "dynslam_cli", "process", "-", "-o",
                             str(tmp_path / "out"), "-q"], stdin=subprocess.PIPE,
                            stderr=subprocess.PIPE)
    assert proc.stdin is not None
    proc.stdin.write("".join(flaser(t=i) for i in range(1, 300)).encode())
    proc.stdin.flush()
    time.sleep(delay)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode in (143, -signal.SIGTERM), err
    assert b"Traceback" not in err
    assert list(tmp_path.iterdir()) == []


def _as_unprivileged(tmp_path):
    """A folder and a command prefix to run the CLI where permissions hold: as is for a
    normal user; as ``nobody`` (with setpriv, in a folder it may enter) when the tests run
    as root, who may read anything."""
    if os.geteuid() != 0:
        return tmp_path, [sys.executable]
    if shutil.which("setpriv") is None:
        pytest.skip("running as root without setpriv to drop the privileges")
    base = tmp_path / "shared"
    base.mkdir()
    for p in base.parents:  # nobody must reach it (pytest's tmp folders are 700)
        os.chmod(p, os.stat(p).st_mode | 0o011)
    os.chmod(base, 0o777)
    prefix = ["setpriv", "--reuid=65534", "--regid=65534", "--clear-groups", sys.executable]
    if subprocess.run([*prefix, "-c", "import dynslam_cli"], capture_output=True).returncode:
        pytest.skip("the unprivileged user cannot run dynslam from here")
    return base, prefix


@pytest.mark.parametrize("command", ["process", "info", "batch"])
def test_an_unreadable_log_or_folder_is_one_line_with_the_reason(tmp_path, command):
    base, python = _as_unprivileged(tmp_path)
    closed = base / "closed"
    closed.mkdir()
    log = closed / "hall.log"
    log.write_bytes(SAMPLE.read_bytes())
    os.chmod(closed, 0)
    target = closed if command == "batch" else log
    out = ["-o", str(base / "out"), "-q"] if command != "info" else []
    r = subprocess.run([*python, "-m", "dynslam_cli", command, str(target), *out],
                       capture_output=True, text=True)
    os.chmod(closed, 0o755)
    assert r.returncode == 1, r.stderr
    assert r.stderr.count("\n") == 1 and "Permission denied" in r.stderr, r.stderr
    assert "does not exist" not in r.stderr and not (base / "out").exists()


def test_an_output_folder_it_may_not_write_is_one_line(tmp_path):
    base, python = _as_unprivileged(tmp_path)
    locked = base / "locked"
    locked.mkdir(mode=0o555)
    for command in ("process", "batch"):
        r = subprocess.run([*python, "-m", "dynslam_cli", command, str(SAMPLE), "-o",
                            str(locked / "out"), "-q"], capture_output=True, text=True)
        assert r.returncode == 1 and r.stderr.count("\n") == 1, r.stderr
        assert "Permission denied" in r.stderr and "Traceback" not in r.stderr
    assert list(locked.iterdir()) == []


def test_mcap_channel_naming_a_missing_schema_is_one_line(cli, tmp_path):
    """Found by the coverage-guided campaign (bench/fuzz.py): a damaged summary whose channel
    refers to a schema the file does not hold was a KeyError traceback."""
    from mcap.writer import Writer

    log = tmp_path / "damaged.mcap"
    with open(log, "wb") as f:
        w = Writer(f)
        w.start()
        channel = w.register_channel(topic="/scan", message_encoding="ros1", schema_id=7)
        w.add_message(channel, log_time=1, data=b"xx", publish_time=1)
        w.finish()
    r = cli("process", log, "-o", tmp_path / "out", "-q")
    assert r.exit_code == 1 and r.stderr.count("\n") == 1, r.stderr
    assert "channel /scan names schema 7, which the file does not hold" in r.stderr
    assert not (tmp_path / "out").exists()


def test_an_odometry_jump_of_56_km_and_back_does_not_stall(tmp_path):
    """Found by the coverage-guided campaign (bench/fuzz.py; the damaged MCAP it made is
    kept as it was): odometry jumps 56 km and back, the local map spans the jump, and its
    point index's buckets covered 56 km at 0.25 m: a search of 520 s."""
    from pathlib import Path

    log = Path(__file__).parent / "data" / "fuzz-odometry-jump-56km.mcap"
    start = time.perf_counter()
    r = subprocess.run([sys.executable, "-m", "dynslam_cli", "process", str(log), "-o",
                        str(tmp_path / "out"), "-q"], capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 1 and "map.max_extent_m" in r.stderr, r.stderr  # the map's bound
    assert time.perf_counter() - start < 60  # (was 520 s; about 1 s now)


INVALID_SCANS = {  # how a LaserScan can hold no valid reading: (ranges, range_min, range_max)
    "all NaN": (float("nan"), 0.02, 20.0),
    "all negative": (-1.0, 0.02, 20.0),
    "all beyond range_max": (25.0, 0.02, 20.0),
    "range_min above range_max": (5.0, 30.0, 20.0),
}


def invalid_scans_log(tmp_path, fmt: str, kind: str, every: int, monkeypatch) -> str:
    """A short simulated hall in ``fmt`` whose every ``every``-th LaserScan holds no valid
    reading, in the way ``kind`` says."""
    import dataclasses

    import numpy as np

    from dynslam_cli.simulate import LaserModel, build_world, simulate
    from dynslam_formats import simlogs

    value, range_min, range_max = INVALID_SCANS[kind]
    made = getattr(simlogs._messages, "original", simlogs._messages)
    count = iter(range(10 ** 6))

    def messages(ts, step, laser, n):
        scan, odom, ns = made(ts, step, laser, n)
        if next(count) % every == 0:
            scan = dataclasses.replace(scan, ranges=np.full(len(scan.ranges), value, np.float32),
                                       range_min=range_min, range_max=range_max)
        return scan, odom, ns

    messages.original = made
    monkeypatch.setattr(simlogs, "_messages", messages)
    steps, _ = simulate(build_world("hall"), 3.0, 10.0, 0)
    tmp_path.mkdir()
    path = tmp_path / {"rosbag1": "log.bag", "rosbag2": "log2", "rosbag2-mcap": "log2m",
                       "mcap": "log.mcap"}[fmt]
    simlogs.write_simulated(fmt, path, steps, LaserModel())
    return str(path)


@pytest.mark.parametrize("fmt", ["rosbag1", "rosbag2", "rosbag2-mcap", "mcap"])
@pytest.mark.parametrize("kind", sorted(INVALID_SCANS))
def test_laserscans_without_a_valid_reading_are_skipped_or_one_line(cli, tmp_path, fmt, kind,
                                                                     monkeypatch):
    """No valid reading in any scan: one line, exit 1. In some scans: those are counted
    skips, the rest is processed (once an IndexError from the change events)."""
    every = invalid_scans_log(tmp_path / "all", fmt, kind, 1, monkeypatch)
    r = cli("process", every, "-o", tmp_path / "all_out", "-q")
    assert r.exit_code == 1 and r.stderr.count("\n") == 1, r.stderr
    assert "no usable scans" in r.stderr and "no valid reading" in r.stderr
    some = invalid_scans_log(tmp_path / "some", fmt, kind, 3, monkeypatch)
    r = cli("process", some, "-o", tmp_path / "some_out", "-q")
    assert r.exit_code == 0, r.stderr
    summary = json.loads((tmp_path / "some_out" / "summary.json").read_text())
    assert summary["scans_processed"] == 20
    assert sum(v for k, v in summary["reader"]["skipped"].items()
               if "no valid reading" in k) == 11


def test_a_log_of_scans_that_see_nothing_in_range_is_processed(cli, tmp_path):
    """Every beam a no-return (an open field): valid, if empty, maps; no traceback from the
    change events over nothing."""
    log = tmp_path / "open.log"
    far = " ".join(["80.0"] * 181)
    log.write_text("".join(f"FLASER 181 {far} {0.1 * k} 0 0 {0.1 * k} 0 0 {k} h {k}\n"
                           for k in range(12)))
    r = cli("process", log, "-o", tmp_path / "out", "-q")
    assert r.exit_code == 0, r.stderr
    assert json.loads((tmp_path / "out" / "summary.json").read_text())["scans_processed"] == 12
