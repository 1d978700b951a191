"""The command line as a user meets it: outputs, exit codes, messages, atomicity."""

from __future__ import annotations

import csv
import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from dynslam_formats.outdir import OUTPUT_FILES
from dynslam_formats.tum import read_tum
from tests.conftest import SAMPLES, flaser

SAMPLE = SAMPLES / "hall" / "hall.log"


def contract_ok(folder) -> None:
    assert sorted(p.name for p in folder.iterdir()) == sorted(OUTPUT_FILES)


def test_process_sample_writes_whole_contract(cli, tmp_path):
    out = tmp_path / "out"
    r = cli("process", SAMPLE, "-o", out, "-q")
    assert r.exit_code == 0, r.output
    assert r.stdout.strip() == str(out)
    contract_ok(out)
    summary = json.loads((out / "summary.json").read_text())
    n = summary["scans_processed"]
    assert n == summary["reader"]["scans"] == len(read_tum(out / "trajectory.tum")) > 100
    assert summary["input"]["format"] == "carmen"
    assert summary["config"]["map"]["resolution_m"] == 0.05
    assert (out / "landmarks.csv").read_text().startswith("id,x,y,kind,class,observations")


def test_same_input_gives_byte_identical_outputs(cli, tmp_path):
    for name in ("a", "b"):
        assert cli("process", SAMPLE, "-o", tmp_path / name, "-q").exit_code == 0
    for f in OUTPUT_FILES:
        if f != "summary.json":
            assert (tmp_path / "a" / f).read_bytes() == (tmp_path / "b" / f).read_bytes(), f
    a, b = (json.loads((tmp_path / n / "summary.json").read_text()) for n in "ab")
    for timing in ("wall_time_s", "peak_rss_mb", "peak_rss_mb_read_ahead", "scan_time_ms"):
        a.pop(timing), b.pop(timing)
    assert a == b


def test_existing_output_refused_unless_force(cli, tmp_path):
    out = tmp_path / "out"
    assert cli("process", SAMPLE, "-o", out, "-q").exit_code == 0
    (out / "note.txt").write_text("mine")
    r = cli("process", SAMPLE, "-o", out)
    assert r.exit_code == 1
    assert "exists; use --force" in r.stderr
    assert (out / "note.txt").exists()
    assert cli("process", SAMPLE, "-o", out, "--force", "-q").exit_code == 0
    contract_ok(out)


def test_failed_run_leaves_nothing_behind(cli, tmp_path):
    bad = tmp_path / "bad.log"
    bad.write_text(flaser() + "FLASER 5 1 2 x\n" + flaser(t=3))
    r = cli("process", bad, "-o", tmp_path / "out")
    assert r.exit_code == 1
    assert r.stderr.strip() == (f"dynslam: error: {bad}:2: FLASER has 4 fields, expected 15 "
                                "for 5 beams + laser pose + robot pose")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.log"]


def test_failure_while_writing_removes_partial_folder(cli, tmp_path, monkeypatch):
    import dynslam_formats.outdir

    def broken(*args, **kwargs):
        raise OSError("disk full")

    monkeypatch.setattr(dynslam_formats.outdir, "write_tum", broken)
    r = cli("process", SAMPLE, "-o", tmp_path / "out", "-q")
    assert r.exit_code == 1 and r.stderr.count("\n") == 1 and "disk full" in r.stderr
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(("signum", "code", "message"), [
    (signal.SIGINT, 130, b"interrupted; no output written"),  # Ctrl-C
    (signal.SIGTERM, 143, b"terminated; no output written"),  # a CI job's time limit
])
def test_a_stopped_run_leaves_nothing(tmp_path, signum, code, message):
    # A real signal while a log streams in on stdin (the writer keeps the pipe open): no
    # output folder, no temporary twin of it, no read-ahead process left running.
    # (A shell's background job inherits SIGINT ignored: give the child the default back.)
    proc = subprocess.Popen([sys.executable, "-m", "dynslam_cli", "process", "-", "-o",
                             str(tmp_path / "out"), "-q"], stdin=subprocess.PIPE,
                            stderr=subprocess.PIPE,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    assert proc.stdin is not None
    proc.stdin.write("".join(flaser(t=i) for i in range(1, 500)).encode())
    proc.stdin.flush()
    time.sleep(2.0)
    proc.send_signal(signum)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == code, err
    assert message in err
    assert b"Traceback" not in err
    assert list(tmp_path.iterdir()) == []


def test_bad_config_exit_1(cli, tmp_path):
    cfg = tmp_path / "c.toml"
    cfg.write_text("[map]\nsize = 3\n")
    r = cli("process", SAMPLE, "-o", tmp_path / "o", "--config", cfg)
    assert r.exit_code == 1 and "unknown key(s) size" in r.stderr
    assert "Traceback" not in r.output


def test_usage_errors_exit_2(cli, tmp_path):
    assert cli("process", SAMPLE, "--resolution", "fine").exit_code == 2


@pytest.mark.parametrize("command", ["process", "info"])
def test_missing_log_is_bad_input_exit_1(cli, tmp_path, command):
    """Bad input is exit 1 with one line naming the file and the real reason, not a usage
    error; nothing is written."""
    r = cli(command, tmp_path / "missing.log", *(["-o", tmp_path / "o"] if command == "process"
                                                  else []))
    assert r.exit_code == 1
    assert r.stderr.strip().splitlines() == [
        f"dynslam: error: {tmp_path / 'missing.log'}: cannot open: No such file or directory"]
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("args", [
    ["process", SAMPLE, "--config", "{missing}"],
    ["batch", SAMPLE, "-o", "{out}", "--config", "{missing}"],
    ["batch", "--manifest", "{missing}", "-o", "{out}"],
    ["evaluate", "{missing}", "--relations", "{missing}"],
    ["evaluate", "{out}", "--truth", "{missing}"],
])
def test_missing_input_files_are_bad_input_exit_1(cli, tmp_path, args):
    missing, out = tmp_path / "missing.toml", tmp_path / "out"
    out.mkdir()
    r = cli(*[str(a).format(missing=missing, out=out) for a in args])
    assert r.exit_code == 1, r.output
    (line,) = r.stderr.strip().splitlines()
    assert line.startswith("dynslam: error: ") and (str(missing) in line or str(out) in line)
    assert "Traceback" not in r.output


def test_force_replaces_only_dynslam_output(cli, tmp_path):
    """--force never deletes a folder dynslam did not write."""
    mine = tmp_path / "notmine"
    mine.mkdir()
    (mine / "precious.txt").write_text("keep me")
    r = cli("process", SAMPLE, "-o", mine, "--force")
    assert r.exit_code == 1 and "not a folder dynslam wrote" in r.stderr
    assert (mine / "precious.txt").read_text() == "keep me"
    out = tmp_path / "out"
    assert cli("process", SAMPLE, "-o", out).exit_code == 0
    assert cli("process", SAMPLE, "-o", out, "--force").exit_code == 0  # its own: replaced
    assert sorted(p.name for p in tmp_path.iterdir()) == ["notmine", "out"]  # no leftovers


def test_refuses_the_current_folder_and_the_input_s_folder(cli, tmp_path, monkeypatch):
    work, data = tmp_path / "work", tmp_path / "data"
    work.mkdir()
    data.mkdir()
    log = data / "hall.log"
    log.write_bytes(SAMPLE.read_bytes())
    monkeypatch.chdir(work)
    for target in (".", "..", "/"):
        r = cli("process", log, "-o", target, "--force")
        assert r.exit_code == 1 and "current folder" in r.stderr, target
    r = cli("process", log, "-o", data, "--force")
    assert r.exit_code == 1 and "holds the input log" in r.stderr
    assert [p.name for p in data.iterdir()] == ["hall.log"]
    assert list(work.iterdir()) == []


def test_help_teaches_with_examples(cli):
    r = cli("process", "--help")
    assert r.exit_code == 0 and "Examples:" in r.stdout and "--resolution" in r.stdout
    assert cli("--version").stdout.startswith("dynslam, version ")


@pytest.mark.parametrize("fmt", ["carmen", "player"])
def test_a_binary_file_read_as_a_text_log_is_one_line_without_its_bytes(cli, tmp_path, fmt):
    """--format carmen on a program or image echoed its bytes as 'records found: \\x00...'."""
    blob = tmp_path / "blob.dat"
    blob.write_bytes(b"\x7fELF\x02\x01\x01\x00" + bytes(range(256)) * 20)
    r = cli("process", blob, "--format", fmt, "-o", tmp_path / "o")
    assert r.exit_code == 1
    assert r.stderr == (f"dynslam: error: {blob}: not a text log: binary data (NUL bytes) "
                        "near the start\n")


def test_bz2_and_xz_logs_are_read_as_gz_logs_are(cli, tmp_path, monkeypatch):
    """They were 'cannot tell the log format ...; name it with --format'."""
    import bz2
    import gzip
    import lzma

    monkeypatch.chdir(tmp_path)
    text = SAMPLE.read_bytes()
    assert cli("process", SAMPLE, "-o", "plain", "-q", "--max-scans", "30").exit_code == 0
    want = (tmp_path / "plain" / "trajectory.tum").read_bytes()
    for suffix, compress, name in ((".gz", gzip.compress, "gzip"),
                                   (".bz2", lambda b: bz2.compress(b, 1), "bzip2"),
                                   (".xz", lzma.compress, "xz")):
        log = tmp_path / f"hall.log{suffix}"
        log.write_bytes(compress(text))
        r = cli("process", log, "-q", "--max-scans", "30", "--force")
        assert r.exit_code == 0, (suffix, r.stderr)
        assert r.stdout.strip() == "hall_dynslam"  # (the compression's suffix goes too)
        assert (tmp_path / "hall_dynslam" / "trajectory.tum").read_bytes() == want, suffix
        r = cli("process", "-", "-o", f"stdin{suffix}", "-q", "--max-scans", "30",
                input=compress(text))  # (known by its magic bytes)
        assert r.exit_code == 0, (suffix, r.stderr)
        assert (tmp_path / f"stdin{suffix}" / "trajectory.tum").read_bytes() == want, suffix
        cut = tmp_path / f"cut.log{suffix}"  # read up to the damage, which is said
        whole = compress(text)
        cut.write_bytes(whole[:len(whole) * 6 // 10])  # (bzip2 -1: 100 kB blocks)
        r = cli("process", cut, "-q", "--force")
        assert r.exit_code == 0, (suffix, r.stderr)
        assert "compressed data" in r.stderr and "read up to there" in r.stderr, suffix
        scans = json.loads((tmp_path / "cut_dynslam/summary.json").read_text())[
            "scans_processed"]
        assert 10 < scans < 450, (suffix, scans)  # (the sample has 450)
        cut.write_bytes(whole[:12])  # nothing readable
        r = cli("info", cut)
        assert r.exit_code == 1 and len(r.stderr.splitlines()) == 1, (suffix, r.stderr)
        assert "damaged or" in r.stderr, (suffix, r.stderr)
        fake = tmp_path / f"fake.log{suffix}"
        fake.write_text("FLASER 1 2\n")
        assert f"not a valid {name} file" in cli("info", fake).stderr


def test_topic_options_on_a_text_log_are_a_counted_warning(cli, tmp_path):
    """--topic on a Carmen or Player log was silently ignored. Readers count what does not
    apply to them (record types, interfaces) and go on; so does a batch whose --topic suits
    its bags but not its text logs."""
    sim = tmp_path / "sim"
    assert cli("simulate", "corridors", "-o", sim, "--duration", "3", "--format",
               "player").exit_code == 0
    for log, kind in ((SAMPLE, "Carmen"), (sim / "corridors.player.log", "Player")):
        out = tmp_path / kind
        r = cli("process", log, "-o", out, "-q", "--max-scans", "10", "--topic", "/scan")
        assert r.exit_code == 0, r.stderr
        reason = f"--topic applies to ROS logs only: ignored for a {kind} log"
        assert f"dynslam: warning: {log}: {reason} (×1)" in r.stderr.splitlines()
        assert json.loads((out / "summary.json").read_text())["reader"]["warnings"] == {
            reason: 1}
    r = cli("info", SAMPLE, "--odom-topic", "/odom", "--json")
    assert json.loads(r.stdout)["warnings"] == {
        "--odom-topic applies to ROS logs only: ignored for a Carmen log": 1}


def test_an_output_that_is_a_file_is_refused_as_such(cli, tmp_path):
    """simulate -o FILE said 'output folder exists; use --force', and --force then said
    it is not a folder."""
    taken = tmp_path / "taken"
    taken.write_text("mine")
    for args in (["simulate", "corridors", "--duration", "2"], ["process", SAMPLE]):
        for force in ([], ["--force"]):
            r = cli(*args, "-o", taken, *force)
            assert r.exit_code == 1
            assert r.stderr == (f"dynslam: error: {taken}: exists and is not a folder; name a "
                                "folder with -o\n")
    assert taken.read_text() == "mine"


def test_top_level_help_names_every_format(cli):
    """It named Carmen/Radish/Freiburg logs only."""
    text = " ".join(cli("--help").stdout.split())
    for name in ("Carmen", "Player", "ROS 1 bags", "ROS 2 bags", "MCAP", ".gz, .bz2, .xz"):
        assert name in text, name


def test_resolution_option_changes_map(cli, tmp_path):
    assert cli("process", SAMPLE, "-o", tmp_path / "o", "--resolution", "0.2", "-q").exit_code == 0
    assert "resolution: 0.200000" in (tmp_path / "o" / "static.yaml").read_text()


def test_default_output_name(cli, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    log = tmp_path / "run.log.gz"
    import gzip

    log.write_bytes(gzip.compress((flaser() + flaser(t=2)).encode()))
    r = cli("process", log, "-q")
    assert r.exit_code == 0 and r.stdout.strip() == "run_dynslam"
    contract_ok(tmp_path / "run_dynslam")


@pytest.mark.parametrize(("name", "poses"), [
    ("mit-csail.clf", 1988), ("csail-robotlaser1.log", 686),
    # (issue 39: one row per corner on freiburg-079 at the default resolution; it had 20
    # pairs closer than 5 cm)
    ("radish-corrected/freiburg-079-corrected.log.gz", 4791)])
def test_real_logs_end_to_end(cli, datasets, tmp_path, name, poses):
    r = cli("process", datasets / "carmen" / name, "-o", tmp_path / "o", "-q")
    assert r.exit_code == 0, r.stderr
    contract_ok(tmp_path / "o")
    assert len(read_tum(tmp_path / "o" / "trajectory.tum")) == poses
    assert corners_seen_twice(tmp_path / "o") == []


def corners_seen_twice(folder) -> list[tuple[str, str]]:
    """Pairs of landmarks.csv rows of the same kind closer than 5 cm: one corner, two rows
    (a landmark the EKF let go of and confirmed anew)."""
    with open(folder / "landmarks.csv") as f:
        rows = list(csv.DictReader(f))
    return [(a["id"], b["id"]) for k, a in enumerate(rows) for b in rows[k + 1:]
            if a["kind"] == b["kind"] and math.hypot(float(a["x"]) - float(b["x"]),
                                                     float(a["y"]) - float(b["y"])) < 0.05]


def test_every_radish_log_processes(cli, datasets, tmp_path):
    """The 13 Radish logs run as a user reprocesses a data set, `dynslam batch` with two
    workers (the suite's longest test: the logs two at a time), each to the output
    contract, one landmark row per corner and no object larger than the config's bound."""
    logs = sorted((datasets / "carmen" / "radish-corrected").glob("*.log.gz"))
    assert len(logs) == 13
    r = cli("batch", *logs, "-o", tmp_path, "-q", "--resolution", "0.1", "--jobs", "2")
    assert r.exit_code == 0, r.stderr
    rows = json.loads((tmp_path / "batch.json").read_text())
    assert sorted(Path(row["log"]) for row in rows) == logs
    for row in rows:
        out = Path(row["output"])
        assert row["status"] == "done", row
        contract_ok(out)
        assert corners_seen_twice(out) == [], row["log"]
        with open(out / "changes.csv") as f:
            sizes = [float(e["size_m2"]) for e in csv.DictReader(f) if e["kind"] != "moving"]
        assert max(sizes, default=0.0) <= 4.0, row["log"]  # [changes] max_object_m2


def test_truncated_fields_log_exit_1_one_line(cli, datasets, tmp_path):
    r = cli("process", datasets / "carmen/zaragoza-laserazosSM3-truncated-fields.log", "-o",
            tmp_path / "o")
    assert r.exit_code == 1
    assert len(r.stderr.strip().splitlines()) == 1
    assert "zaragoza-laserazosSM3-truncated-fields.log:1: FLASER" in r.stderr


def test_a_formats_py_in_the_users_folder_does_not_shadow_ours(tmp_path):
    """The readers install as dynslam_formats: a user's own formats.py cannot collide."""
    (tmp_path / "formats.py").write_text("raise ImportError('the user formats.py')\n")
    r = subprocess.run([sys.executable, "-m", "dynslam_cli", "process", str(SAMPLE), "-o",
                        "out", "-q"], cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "out" / "summary.json").is_file()


def test_part_of_a_log(cli, tmp_path):
    r = cli("process", SAMPLE, "-o", tmp_path / "w", "--start", "10", "--end", "30", "-q")
    assert r.exit_code == 0, r.stderr
    traj = read_tum(tmp_path / "w/trajectory.tum")
    assert traj[0, 0] == pytest.approx(10.0) and traj[-1, 0] == pytest.approx(30.0)
    summary = json.loads((tmp_path / "w/summary.json").read_text())
    assert summary["input"]["options"]["start_s"] == 10.0
    r = cli("process", SAMPLE, "-o", tmp_path / "n", "--max-scans", "7", "-q")
    assert len(read_tum(tmp_path / "n/trajectory.tum")) == 7
    r = cli("process", SAMPLE, "-o", tmp_path / "x", "--start", "30", "--end", "10")
    assert r.exit_code == 2 and "--end 10 is not after --start 30" in r.stderr
    assert not (tmp_path / "x").exists()


def test_batch_takes_the_reader_options(cli, tmp_path):
    r = cli("batch", SAMPLE, "-o", tmp_path / "b", "--format", "carmen", "--laser", "front",
            "--flaser-fov", "180", "--max-scans", "20", "--snapshots", "1", "-q")
    assert r.exit_code == 0, r.stderr
    assert len(read_tum(tmp_path / "b/hall/trajectory.tum")) == 20
    assert (tmp_path / "b/hall/snapshots/evolution.gif").is_file()
    summary = json.loads((tmp_path / "b/hall/summary.json").read_text())
    assert summary["input"]["options"]["format"] == "carmen"
    assert summary["config"]["laser"]["fov_deg"] == 180.0
    r = cli("batch", SAMPLE, "-o", tmp_path / "c", "--format", "nonsense", "-q")
    assert r.exit_code == 1 and "unknown format 'nonsense'" in r.stderr


def test_info_says_none_instead_of_empty_headings(cli):
    r = cli("info", SAMPLE)
    assert r.exit_code == 0
    lines = r.stdout.splitlines()
    assert any(line.split() == ["skipped", "none"] for line in lines)
    assert any(line.split() == ["warnings", "none"] for line in lines)


def test_progress_tells_scans_and_the_final_phases(tmp_path):
    from dynslam_cli.config import Config
    from dynslam_cli.job import process_log
    from dynslam_formats import ReaderOptions

    progress, phases = [], []
    process_log(str(SAMPLE), tmp_path / "o", False, ReaderOptions(), Config(),
                on_progress=lambda done, total, scans: progress.append((done, total, scans)),
                on_phase=lambda what, done, total: phases.append((what, done, total)))
    assert progress[-1][2] > 400 and progress[-1][0] <= progress[-1][1]
    assert [p[0] for p in phases][:2] == ["optimizing the pose graph", "rebuilding the maps"]
    assert phases[-1][0] == "writing the outputs"
    rebuild = [p for p in phases if p[0] == "rebuilding the maps"]
    assert rebuild[0][2] == len(read_tum(tmp_path / "o/trajectory.tum"))


def test_every_option_of_every_command_has_help(cli):
    import click

    from dynslam_cli.cli import main

    for name, command in main.commands.items():
        for param in command.params:
            if isinstance(param, click.Option) and param.name != "help":
                assert param.help, f"{name} {param.opts} has no help"
    assert "cov_xx,cov_xy,cov_yy" in cli("process", "--help").stdout


def test_a_window_past_the_logs_end_is_an_error_that_says_its_span(cli, tmp_path):
    """--start beyond the last scan once wrote a 0×0 static.pgm and exited 0."""
    r = cli("process", SAMPLE, "-o", tmp_path / "late", "--start", "500")
    assert r.exit_code == 1
    assert "no scans from 500 s into the log (its scans span 90.0 s)" in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "late").exists()


def test_an_option_out_of_range_is_a_usage_error_naming_it(cli, tmp_path):
    """--resolution 0.001 passed click's own check and failed later as a configuration key
    (exit 1, 'map.resolution_m'); the same value from a TOML file stays that file's error."""
    for command in ("process", "batch"):
        r = cli(command, SAMPLE, "-o", tmp_path / command, "--resolution", "0.001")
        assert r.exit_code == 2, r.stderr
        assert "Invalid value for '--resolution': must be in [0.005, 10] m" in r.stderr
        assert not (tmp_path / command).exists()
    bad = tmp_path / "bad.toml"
    bad.write_text("[map]\nresolution_m = 0.001\n")
    r = cli("process", SAMPLE, "-o", tmp_path / "f", "--config", bad)
    assert r.exit_code == 1 and "map.resolution_m must be in [0.005, 10] m" in r.stderr


def test_a_log_without_time_gets_numbered_stamps_and_no_rate(cli, tmp_path):
    """Every stamp 0 (freiburg-campus, orebro, zaragoza): trajectory.tum had every stamp
    0.0, evo refused it, and batch printed absurd rates (issue 38, item 6)."""
    log = tmp_path / "zero.log"
    log.write_text("".join(flaser(n=90, r=2.0 + 0.01 * i, t=0.0) for i in range(30)))
    r = cli("process", log, "-o", tmp_path / "out")
    assert r.exit_code == 0, r.stderr
    assert r.stderr.count("time stamps carry no time") == 1 and "data without time" in r.stderr
    stamps = [float(line.split()[0])
              for line in (tmp_path / "out/trajectory.tum").read_text().splitlines()]
    assert stamps == [float(i) for i in range(30)]
    assert json.loads((tmp_path / "out/summary.json").read_text())["data_duration_s"] is None
    r = cli("batch", log, "-o", tmp_path / "b", "-q")
    assert r.exit_code == 0, r.stderr
    with open(tmp_path / "b/batch.csv") as f:
        row = next(csv.DictReader(f))
    assert row["x_real_time"] == "" and row["data_duration_s"] == ""


def test_a_log_without_time_is_timed_by_its_scans_and_keeps_its_change_events(cli, tmp_path):
    """The corrected Radish freiburg-campus stamps every scan 0: its change events (whose
    rules are in seconds) all fell at one instant and it got none, silently (issue 39).
    Timed by the scan order at the rate the user states, the hall sample without its stamps
    gives the events of the hall with them; said once."""
    zero = tmp_path / "zero.log"
    with open(SAMPLES / "hall" / "hall.log") as f, open(zero, "w") as out:
        for line in f:
            fields = line.split()
            if fields and fields[0] in ("FLASER", "ODOM"):
                fields[-3] = fields[-1] = "0.000000"
            out.write(" ".join(fields) + "\n")
    (tmp_path / "rate.toml").write_text("[laser]\nstopped_clock_period_s = 0.2\n")
    r = cli("process", zero, "-o", tmp_path / "zero", "--config", tmp_path / "rate.toml")
    assert r.exit_code == 0, r.stderr
    assert r.stderr.count("timed by their order, 0.2 s apart") == 1
    r = cli("process", SAMPLES / "hall" / "hall.log", "-o", tmp_path / "timed", "-q")
    assert r.exit_code == 0, r.stderr
    timed = (tmp_path / "timed/changes.csv").read_text()
    assert len(timed.splitlines()) > 3  # (the hall's walkers)
    assert (tmp_path / "zero/changes.csv").read_text() == timed
    summary = json.loads((tmp_path / "zero/summary.json").read_text())
    assert summary["data_duration_s"] is None  # (no time the log gave)
    assert any("timed by their order" in w for w in summary["reader"]["warnings"])


def test_record_takes_a_path_written_atomically(cli, tmp_path, monkeypatch):
    """--record ~/runs/today.mcap: a recording where the user says, made like the outputs
    (all or nothing, an existing one replaced only with --force and only if dynslam wrote
    it); it was refused as 'must be a file name' (issue 38, item 12)."""
    from mcap.reader import make_reader

    monkeypatch.chdir(tmp_path)
    log = SAMPLES / "hall" / "hall.log"
    r = cli("process", log, "-o", "out", "-q", "--record", "runs/today/hall.mcap",
            "--max-scans", "30")
    assert r.exit_code == 0, r.stderr
    rec = tmp_path / "runs/today/hall.mcap"
    with open(rec, "rb") as f:
        assert sum(1 for _ in make_reader(f).iter_messages(topics=["/scan"])) == 30
    assert os.listdir(rec.parent) == ["hall.mcap"]  # no temporary file left
    summary = json.loads((tmp_path / "out/summary.json").read_text())
    assert summary["recording"]["file"] == str(rec)
    assert not any(p.suffix == ".mcap" for p in (tmp_path / "out").iterdir())
    again = ("process", log, "-o", "out2", "-q", "--record", "runs/today/hall.mcap",
             "--max-scans", "20")
    r = cli(*again)
    assert r.exit_code == 1 and "exists; use --force" in r.stderr
    assert cli(*again, "--force").exit_code == 0
    with open(rec, "rb") as f:
        assert sum(1 for _ in make_reader(f).iter_messages(topics=["/scan"])) == 20
    (tmp_path / "notes.mcap").write_text("mine")
    r = cli("process", log, "-o", "out3", "--record", "notes.mcap", "--force")
    assert r.exit_code == 0  # a bare name: in the output folder, as before
    r = cli("process", log, "-o", "out4", "--record", "./notes.mcap", "--force")
    assert r.exit_code == 1 and "not a recording dynslam wrote" in r.stderr
    assert (tmp_path / "notes.mcap").read_text() == "mine"
    bad = tmp_path / "bad.log"
    bad.write_text(flaser() + flaser(t=2) + "FLASER 5 1 2 x\n")
    r = cli("process", bad, "-o", "out5", "--record", "new/place/run.mcap")
    assert r.exit_code == 1 and not (tmp_path / "new").exists()  # nothing half-written
    r = cli("batch", log, "-o", "b", "--record", "runs/x.mcap")
    assert r.exit_code == 2 and "in batch, a file name" in r.stderr
