"""make bench: the real pipeline, end to end, on real and simulated logs.

For each log: several runs of ``dynslam process`` as a user runs it (a fresh process, so
start-up counts); reports the median wall time, data duration ÷ wall time (× real time), the
median peak RSS (of the whole run's main process, writing included, and of the read-ahead
process beside it), the grid's bytes per seen cell, and the
median per-scan time of the first, middle and last 10% of scans (from summary.json), and the 4 h
hall's wall time over the 1 h hall's (the same world driven 4× as long). Also
``dynslam --help`` start-up. Writes bench/results.json and prints a table.

    python bench/run.py [--runs 3] [--quick]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
DATA = ROOT.parent / "shared" / "datasets" / "carmen"
CACHE = ROOT / "bench" / "cache"
DYNSLAM = [sys.executable, "-m", "dynslam_cli"]


def logs(quick: bool) -> dict[str, Path]:
    out = {"mit-csail.clf": DATA / "mit-csail.clf",
           "csail-robotlaser1.log": DATA / "csail-robotlaser1.log",
           "freiburg-079-corrected.log.gz": DATA / "radish-corrected" /
           "freiburg-079-corrected.log.gz",
           "freiburg-campus (outdoor, 1.75 km)": DATA / "radish-corrected" /
           "freiburg-campus-corrected.log.gz"}
    lengths = {"5 min": 300} if quick else {"1 h": 3600, "4 h": 14400}
    for name, seconds in lengths.items():  # the same hall, driven longer
        hall = CACHE / f"hall-{name.replace(' ', '')}" / "hall.log"
        if not hall.exists():
            subprocess.run([*DYNSLAM, "simulate", "hall", "-o", str(hall.parent), "--duration",
                            str(seconds), "--seed", "7", "--force"], check=True,
                           capture_output=True)
        out[f"simulated hall, {name}"] = hall
    return {k: v for k, v in out.items() if v.exists()}


LONG_LOG_RUNS = 3  # runs of logs longer than a minute's work (the 4 h hall)


def one_run(log: Path, out: Path) -> dict:
    start = time.perf_counter()
    proc = subprocess.Popen([*DYNSLAM, "process", str(log), "-o", str(out), "--force", "-q"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    _, status, usage = os.wait4(proc.pid, 0)  # the whole run's peak, writing included
    proc.returncode = os.waitstatus_to_exitcode(status)
    if proc.returncode:
        raise SystemExit(f"dynslam process {log} failed ({proc.returncode})")
    wall = time.perf_counter() - start
    summary = json.loads((out / "summary.json").read_text())
    return {"wall_s": wall, "data_s": summary["data_duration_s"],
            "rss_mb": round(usage.ru_maxrss / 1024, 1),
            "bytes_per_seen_cell": summary["map"].get("bytes_per_seen_cell"),
            "read_ahead_rss_mb": summary.get("peak_rss_mb_read_ahead") or 0.0,
            **summary["scan_time_ms"]}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--quick", action="store_true", help="a 5-minute simulated log")
    args = ap.parse_args()
    CACHE.mkdir(parents=True, exist_ok=True)
    results = {}
    with tempfile.TemporaryDirectory() as tmp:
        for name, log in logs(args.quick).items():
            n = min(args.runs, LONG_LOG_RUNS) if name.endswith("4 h") else args.runs
            runs = [one_run(log, Path(tmp) / "out") for _ in range(n)]
            med = {k: statistics.median(r[k] for r in runs if r[k] is not None)
                   for k in ("wall_s", "rss_mb", "read_ahead_rss_mb", "first_10pct_median",
                             "middle_10pct_median", "last_10pct_median")}
            data = runs[0]["data_s"]
            results[name] = {"runs": runs, "median_wall_s": round(med["wall_s"], 3),
                             "x_real_time": round(data / med["wall_s"], 1) if data else None,
                             "median_peak_rss_mb": med["rss_mb"],
                             "median_peak_rss_mb_read_ahead": med["read_ahead_rss_mb"],
                             "bytes_per_seen_cell": runs[0]["bytes_per_seen_cell"],
                             "scan_ms_first_10pct": med["first_10pct_median"],
                             "scan_ms_middle_10pct": med["middle_10pct_median"],
                             "scan_ms_last_10pct": med["last_10pct_median"],
                             "last_over_first": round(med["last_10pct_median"]
                                                      / med["first_10pct_median"], 2)}
    if "simulated hall, 4 h" in results:  # does the cost follow the log's length?
        results["4 h over 1 h"] = {"wall_ratio": round(
            results["simulated hall, 4 h"]["median_wall_s"]
            / results["simulated hall, 1 h"]["median_wall_s"], 2)}
    helps = []
    for _ in range(5):
        start = time.perf_counter()
        subprocess.run([*DYNSLAM, "--help"], check=True, capture_output=True)
        helps.append(time.perf_counter() - start)
    results["dynslam --help"] = {"median_wall_s": round(statistics.median(helps), 3)}
    (ROOT / "bench" / "results.json").write_text(json.dumps(results, indent=2) + "\n")
    print(f"{'log':<34} {'wall s':>8} {'× real':>8} {'RSS MB':>8} {'+ahead':>7} "
          f"{'B/cell':>7} {'first ms':>9} {'mid ms':>7} {'last ms':>8} {'last/first':>10}")
    for name, r in results.items():
        if "x_real_time" in r:
            real = "—" if r["x_real_time"] is None else r["x_real_time"]  # (no clock)
            print(f"{name:<34} {r['median_wall_s']:>8} {real:>8} "
                  f"{r['median_peak_rss_mb']:>8} {r['median_peak_rss_mb_read_ahead']:>7} "
                  f"{r['bytes_per_seen_cell']:>7} {r['scan_ms_first_10pct']:>9} "
                  f"{r['scan_ms_middle_10pct']:>7} {r['scan_ms_last_10pct']:>8} "
                  f"{r['last_over_first']:>10}")
    if "4 h over 1 h" in results:
        print(f"{'4 h hall over 1 h hall, wall':<34} {results['4 h over 1 h']['wall_ratio']:>8}")
    print(f"{'dynslam --help':<34} {results['dynslam --help']['median_wall_s']:>8}")


if __name__ == "__main__":
    main()
