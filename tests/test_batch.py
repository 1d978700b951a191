"""dynslam batch: local processes, Dask (in-process cluster and real scheduler/worker
processes), resumability, failures, manifests, unique names."""

from __future__ import annotations

import csv
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from dynslam_formats.outdir import OUTPUT_FILES


@pytest.fixture(scope="module")
def logs(tmp_path_factory) -> Path:
    """Four small simulated logs (two share a stem, in different folders), their truths,
    and one bad log."""
    from click.testing import CliRunner

    from dynslam_cli.cli import main

    root = tmp_path_factory.mktemp("logs")
    for world, seed, sub in (("hall", 1, "a"), ("arena", 2, "a"), ("hall", 3, "b"),
                             ("crowd", 4, "b")):
        r = CliRunner().invoke(main, ["simulate", world, "-o", str(root / f"sim{seed}"),
                                      "--duration", "20", "--seed", str(seed)])
        assert r.exit_code == 0, r.output
        (root / sub).mkdir(exist_ok=True)
        shutil.copy(root / f"sim{seed}" / f"{world}.log", root / sub / f"{world}.log")
    (root / "b" / "broken.log").write_text("FLASER 3 1 2\n")
    return root


def read_rows(outroot: Path) -> dict[str, dict[str, str]]:
    with open(outroot / "batch.csv") as f:
        return {Path(r["log"]).parent.name + "/" + Path(r["log"]).name: r
                for r in csv.DictReader(f)}


def test_local_batch_resumes_and_reports_failures(logs, cli, tmp_path):
    out = tmp_path / "out"
    r = cli("batch", logs / "a", logs / "b", "-o", out, "--jobs", "2", "-q")
    assert r.exit_code == 1  # one log is bad
    rows = read_rows(out)
    assert {k: v["status"] for k, v in rows.items()} == {
        "a/hall.log": "done", "a/arena.log": "done", "b/hall.log": "done",
        "b/crowd.log": "done", "b/broken.log": "failed"}
    assert "broken.log:1: FLASER has 3 fields" in rows["b/broken.log"]["error"]
    folders = sorted(p.name for p in out.iterdir() if p.is_dir())
    assert len(folders) == 4 and "arena" in folders and "crowd" in folders
    assert sum(f.startswith("hall-") for f in folders) == 2  # same stem, unique names
    for f in folders:
        assert sorted(p.name for p in (out / f).iterdir()) == sorted(OUTPUT_FILES)
    assert float(rows["a/hall.log"]["x_real_time"]) > 0
    assert json.loads((out / "batch.json").read_text())[0]["log"]

    # rerun: nothing to do for the complete ones (the bad one is tried again), and their
    # figures stay in the summary
    first = read_rows(out)
    r = cli("batch", logs / "a", logs / "b", "-o", out, "--jobs", "2")
    assert "0 done, 4 skipped, 1 failed" in r.stderr
    again = read_rows(out)
    assert again["a/hall.log"]["status"] == "skipped"
    for key in ("format", "scans", "data_duration_s", "wall_time_s", "x_real_time"):
        assert again["a/hall.log"][key] == first["a/hall.log"][key] != "", key
    # delete one output: only that one is redone
    shutil.rmtree(out / "arena")
    r = cli("batch", logs / "a", logs / "b", "-o", out, "--jobs", "1")
    assert "1 done, 3 skipped, 1 failed" in r.stderr
    assert read_rows(out)["a/arena.log"]["status"] == "done"


def test_batch_summary_follows_the_umask(logs, cli, tmp_path):
    old = os.umask(0o022)
    try:
        assert cli("batch", logs / "a" / "hall.log", "-o", tmp_path / "out", "-q").exit_code == 0
    finally:
        os.umask(old)
    for name in ("batch.csv", "batch.json"):
        assert (tmp_path / "out" / name).stat().st_mode & 0o777 == 0o644, name
    assert (tmp_path / "out" / "hall").stat().st_mode & 0o777 == 0o755


def test_all_complete_says_nothing_to_do(logs, cli, tmp_path):
    out = tmp_path / "out"
    assert cli("batch", logs / "a", "-o", out, "-q").exit_code == 0
    r = cli("batch", logs / "a", "-o", out)
    assert r.exit_code == 0 and "nothing to do" in r.stderr


def test_manifest_with_truth_scores(logs, cli, tmp_path):
    manifest = tmp_path / "runs.csv"
    manifest.write_text("log,config,truth,relations\n"
                        f"{logs / 'a/hall.log'},,{logs / 'sim1/truth.json'},\n")
    cfg = tmp_path / "coarse.toml"
    cfg.write_text("[map]\nresolution_m = 0.1\n")
    toml = tmp_path / "runs.toml"
    toml.write_text(f'[[log]]\npath = "{logs / "a/arena.log"}"\nconfig = "coarse.toml"\n')
    out = tmp_path / "out"
    r = cli("batch", "--manifest", manifest, "-o", out, "-q")
    assert r.exit_code == 0, r.stderr
    row = read_rows(out)["a/hall.log"]
    assert 0 <= float(row["ate_rmse_m"]) < float(row["odometry_ate_rmse_m"])
    assert cli("batch", "--manifest", manifest, "-o", out, "-q").exit_code == 0  # resumed:
    assert read_rows(out)["a/hall.log"]["ate_rmse_m"] == row["ate_rmse_m"]  # scores kept
    r = cli("batch", "--manifest", toml, "-o", out / "t", "-q")
    assert r.exit_code == 0, r.stderr
    assert "resolution: 0.100000" in (out / "t/arena/static.yaml").read_text()


def test_dask_local_cluster(logs, tmp_path):
    distributed = pytest.importorskip("dask.distributed")
    from dynslam_cli.batch import expand_logs, run_batch, run_dask

    rows = [{"log": p, "config": None, "truth": None, "relations": None}
            for p in expand_logs([str(logs / "a")])]
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=False,
                                  dashboard_address=None) as cluster, \
            distributed.Client(cluster) as client:
        results = run_batch(rows, tmp_path / "out", False, {}, {}, None,
                            lambda jobs: run_dask(jobs, client))
    assert sorted(r["status"] for r in results) == ["done", "done"]
    assert (tmp_path / "out/hall/summary.json").exists()


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_dask_scheduler_and_worker_processes(logs, tmp_path):
    pytest.importorskip("dask.distributed")
    bindir = Path(sys.executable).parent
    port = _free_port()
    address = f"tcp://127.0.0.1:{port}"
    procs = [subprocess.Popen([str(bindir / "dask"), "scheduler", "--host", "127.0.0.1",
                               "--port", str(port), "--no-dashboard"],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)]
    try:
        deadline = time.time() + 30
        while time.time() < deadline:
            with socket.socket() as s:
                if s.connect_ex(("127.0.0.1", port)) == 0:
                    break
            time.sleep(0.2)
        # The worker runs in another folder, the batch names relative paths: they must
        # reach the worker resolved (issue 38, item 3).
        (tmp_path / "worker").mkdir()
        procs.append(subprocess.Popen([str(bindir / "dask"), "worker", address, "--nworkers",
                                       "1", "--nthreads", "1", "--no-dashboard"],
                                      cwd=tmp_path / "worker",
                                      stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        shutil.copytree(logs / "b", tmp_path / "b")
        proc = subprocess.run([str(bindir / "dynslam"), "batch", "b", "-o", "out",
                               "--scheduler", address, "-q"], cwd=tmp_path,
                              capture_output=True, text=True, timeout=300)
        assert proc.returncode == 1, proc.stderr  # broken.log fails, the others finish
        rows = read_rows(tmp_path / "out")
        assert [rows[k]["status"] for k in sorted(rows)] == ["failed", "done", "done"]
        assert (tmp_path / "out/crowd/summary.json").is_file()
        assert not (tmp_path / "worker" / "out").exists()
    finally:
        for p in reversed(procs):
            p.terminate()
            p.wait(timeout=30)


def test_unreachable_scheduler_is_a_clear_error(logs, cli, tmp_path):
    pytest.importorskip("dask.distributed")
    r = cli("batch", logs / "a", "-o", tmp_path / "o", "--scheduler",
            f"tcp://127.0.0.1:{_free_port()}")
    assert r.exit_code == 1 and "cannot reach the Dask scheduler" in r.stderr


def test_a_scheduler_address_without_its_port_is_one_line(logs, cli, tmp_path):
    """Dask's ValueError for tcp://HOST (no port) was a traceback (issue 38, item 8)."""
    pytest.importorskip("dask.distributed")
    r = cli("batch", logs / "a", "-o", tmp_path / "o", "--scheduler", "tcp://localhost")
    assert r.exit_code == 1
    assert "--scheduler tcp://localhost" in r.stderr and "tcp://HOST:PORT" in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1


def test_a_rerun_with_other_options_redoes_the_stale_outputs(logs, cli, tmp_path):
    """A finished output counts only for the input, options and configuration it was made
    with; it used to be kept, 'nothing to do', at the old resolution (issue 38, item 1)."""
    out, log = tmp_path / "out", logs / "a" / "hall.log"
    assert cli("batch", log, "-o", out, "-q").exit_code == 0
    r = cli("batch", log, "-o", out, "--resolution", "0.1")
    assert r.exit_code == 0 and "1 done, 0 skipped" in r.stderr
    assert "redone" in r.stderr and "map.resolution_m" in r.stderr
    assert "resolution: 0.100000" in (out / "hall/static.yaml").read_text()
    assert "nothing to do" in cli("batch", log, "-o", out, "--resolution", "0.1").stderr
    coarse = tmp_path / "coarse.toml"
    coarse.write_text("[map]\nresolution_m = 0.2\n")
    r = cli("batch", log, "-o", out, "--config", coarse)
    assert "1 done" in r.stderr and "map.resolution_m" in r.stderr
    r = cli("batch", log, "-o", out, "--config", coarse, "--max-scans", "40")
    assert "1 done" in r.stderr and "options.max_scans" in r.stderr
    assert json.loads((out / "hall/summary.json").read_text())["scans_processed"] == 40


def test_a_sweep_gets_one_folder_per_manifest_row(logs, cli, tmp_path):
    """One log twice in a manifest, once with a configuration: two folders (they collided
    in one, failing with --jobs 2 and with --jobs 1; issue 38, item 2). A row repeating
    another is run once."""
    (tmp_path / "r01.toml").write_text("[map]\nresolution_m = 0.1\n")
    log = logs / "a" / "hall.log"
    manifest = tmp_path / "sweep.csv"
    manifest.write_text(f"log,config\n{log},\n{log},r01.toml\n{log},r01.toml\n")
    for jobs in ("2", "1"):
        out = tmp_path / f"sweep{jobs}"
        r = cli("batch", "--manifest", manifest, "-o", out, "--jobs", jobs, "-q")
        assert r.exit_code == 0, r.stderr
        folders = sorted(p for p in out.iterdir() if p.is_dir())
        assert len(folders) == 2
        resolutions = sorted(json.loads((f / "summary.json").read_text())["map"]
                             ["resolution_m"] for f in folders)
        assert resolutions == [0.05, 0.1]
        assert len(json.loads((out / "batch.json").read_text())) == 2


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT])
def test_a_stopped_batch_stops_promptly_and_keeps_what_finished(signum, tmp_path):
    """SIGTERM or Ctrl-C: the running logs end, the rest are not started, the finished
    outputs stay and batch.csv lists them; exit 143 or 130. It took 50 s, said 'no output
    written' and wrote no batch.csv (issue 38, item 4)."""
    from click.testing import CliRunner

    from dynslam_cli.cli import main

    for seed in range(6):
        r = CliRunner().invoke(main, ["simulate", "hall", "-o", str(tmp_path / f"s{seed}"),
                                      "--duration", "60" if seed == 0 else "400",
                                      "--seed", str(seed)])
        assert r.exit_code == 0, r.output
        shutil.copy(tmp_path / f"s{seed}" / "hall.log", tmp_path / f"log{seed}.log")
    out = tmp_path / "out"
    # As a terminal's foreground job: a background job of a shell script (CI started with
    # '&') inherits SIGINT ignored, and dynslam rightly keeps ignoring it.
    proc = subprocess.Popen([sys.executable, "-m", "dynslam_cli", "batch",
                             *sorted(str(p) for p in tmp_path.glob("log*.log")), "-o", str(out),
                             "--jobs", "2", "-q"], stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    deadline = time.time() + 120
    while not (out / "log0" / "summary.json").exists():  # the short log is done
        assert time.time() < deadline and proc.poll() is None
        time.sleep(0.1)
    time.sleep(0.5)
    os.kill(proc.pid, signum)
    stopped = time.time()
    _, err = proc.communicate(timeout=60)
    assert time.time() - stopped < 10
    assert proc.returncode == (143 if signum == signal.SIGTERM else 130), err
    assert "outputs are kept" in err and "Traceback" not in err
    rows = read_rows(out)
    assert rows[f"{tmp_path.name}/log0.log"]["status"] == "done"
    assert all(r["status"] == "done" for r in rows.values())
    assert sorted(p.name for p in out.iterdir()) == sorted(
        ["batch.csv", "batch.json", *(Path(r["output"]).name for r in rows.values())])
