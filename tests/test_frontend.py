"""The front end (reading, scan matching, corners) in a second process gives exactly what it
gives in this one, errors included, and never leaves its process behind."""

from __future__ import annotations

import os
import signal

import numpy as np
import pytest

from dynslam_cli.config import Config
from dynslam_cli.errors import InputError
from dynslam_cli.localization.frontend import ScanMeasurer
from dynslam_cli.readahead import ForkedFrontEnd, FrontEnd, can_fork
from dynslam_formats import ReaderOptions, open_log

from .conftest import SAMPLES, flaser

pytestmark = pytest.mark.skipif(not can_fork(), reason="this system cannot fork")


def parts(config: Config) -> tuple:
    """What a front end takes from a configuration: its measurer."""
    return (ScanMeasurer.configured(config.ekf, config.match, config.corners),)


def drain(kind: type, path: str) -> tuple[list, object, Exception | None]:
    """(scans with their motions, the reader's counts, the error that ended the log)."""
    source, _, reader = open_log(path, ReaderOptions())
    front = kind(reader, source, *parts(Config()))
    got, error = [], None
    try:
        for scan in front.scans():
            m = front.measurement(scan)
            cov = None if m.motion.cov is None else m.motion.cov.tobytes()
            got.append((scan.stamp, scan.ranges.tobytes(), scan.odom, m.motion.increment,
                        m.motion.source, cov, [(z.tobytes(), convex) for z, convex in m.corners]))
    except InputError as e:
        error = e
    finally:
        front.close()
        source.close()
    return got, front.stats.to_dict(), error


def test_forked_front_end_gives_the_same_scans_motions_and_counts():
    log = str(SAMPLES / "hall" / "hall.log")
    here, stats_here, _ = drain(FrontEnd, log)
    there, stats_there, _ = drain(ForkedFrontEnd, log)
    assert len(here) == 451
    assert there == here  # stamps, ranges bit for bit, odometry, motions, corners
    assert stats_there == stats_here
    assert "matched" in {source for *_, source, _, _ in here}  # the matcher ran
    assert sum(len(corners) for *_, corners in here) > 100  # and the corner detector


def test_error_midway_comes_after_the_scans_before_it(tmp_path):
    lines = [flaser(n=90, r=2.0 + 0.01 * k, t=1.0 + 0.1 * k) for k in range(40)]
    lines[25] = lines[25].replace("FLASER 90 2.250", "FLASER 90 x")  # line 26: not a number
    log = tmp_path / "bad.log"
    log.write_text("".join(lines))
    here, _, error_here = drain(FrontEnd, str(log))
    there, _, error_there = drain(ForkedFrontEnd, str(log))
    assert len(here) == 25 and there == here
    assert isinstance(error_there, InputError)
    assert str(error_there) == str(error_here)
    assert error_there.line == 26


def test_a_front_end_process_that_dies_is_a_clear_error():
    source, _, reader = open_log(str(SAMPLES / "hall" / "hall.log"), ReaderOptions())
    front = ForkedFrontEnd(reader, source, *parts(Config()))
    os.kill(front._pid, signal.SIGKILL)
    with pytest.raises(RuntimeError, match="front-end process ended unexpectedly"):
        for _ in front.scans():
            pass
    front.close()
    source.close()


def test_close_stops_the_child_mid_log():
    source, _, reader = open_log(str(SAMPLES / "hall" / "hall.log"), ReaderOptions())
    front = ForkedFrontEnd(reader, source, *parts(Config()))
    next(iter(front.scans()))
    front.close()
    source.close()
    with pytest.raises(ChildProcessError):  # reaped: nothing left running or a zombie
        os.waitpid(front._pid, os.WNOHANG)


def test_process_with_and_without_read_ahead_writes_the_same_files(cli, tmp_path):
    log = SAMPLES / "corridors" / "corridors.log"
    outs = []
    for flag in ([], ["--no-read-ahead"]):
        out = tmp_path / ("one" if flag else "two")
        r = cli("process", log, "-o", out, "-q", *flag)
        assert r.exit_code == 0, r.stderr
        outs.append(out)
    for name in ("static.pgm", "dynamic.pgm", "map.png", "landmarks.csv", "trajectory.tum"):
        assert (outs[0] / name).read_bytes() == (outs[1] / name).read_bytes(), name
    traj = np.loadtxt(outs[0] / "trajectory.tum")
    assert len(traj) > 100


def test_the_progress_bar_starts_no_thread():
    # a second thread would keep 'dynslam process' on a terminal from reading ahead
    import io
    import threading

    from dynslam_cli.cli import _progress_bar

    before = threading.active_count()
    with _progress_bar()(total=3, file=io.StringIO()) as bar:
        bar.update(1)
        assert threading.active_count() == before


def test_the_child_reads_ahead_while_this_process_is_busy(tmp_path):
    """Batches are taken off the pipe as they come: a log of 4 MB of scans is read to its
    end while this process takes none of them (a pipe holds 1 MiB), and closing leaves no
    thread behind (the next log of a batch can read ahead too)."""
    import threading
    import time

    log = tmp_path / "long.log"
    log.write_text("".join(flaser(n=720, r=3.0, pose=(0.001 * k, 0.0, 0.0), t=1.0 + 0.1 * k)
                           for k in range(700)))
    threads = threading.active_count()
    source, _, reader = open_log(str(log), ReaderOptions())
    front = ForkedFrontEnd(reader, source, ScanMeasurer(None, Config().ekf.noise, None))
    try:
        deadline = time.monotonic() + 20.0
        while _state(front._pid) != "Z":  # until the child has sent all and ended
            assert time.monotonic() < deadline, "the child waits on a full pipe"
            time.sleep(0.05)
        assert sum(1 for _ in front.scans()) == 700
    finally:
        front.close()
        source.close()
    assert threading.active_count() == threads


def _state(pid: int) -> str:
    """A process's state letter (Linux): R, S, ... or Z once it has ended, not yet reaped."""
    with open(f"/proc/{pid}/stat") as f:
        return f.read().rsplit(")", 1)[1].split()[0]
