"""Two sessions of every built-in world: the second placed in the first's map (``--prior``,
no start pose) and scored against the fixtures moved in between.

For each world: ``dynslam simulate WORLD --sessions 2``, the first session processed alone,
the second with ``--prior`` on the first's output, then ``dynslam evaluate`` of the second:
its trajectory's error in the first's frame (no alignment) and the between-session events
(``removed_since_prior``, ``added_since_prior``) within 0.3 m of the true changes. A world
whose second session is refused (ambiguous or poor placement) prints the tool's message.

    python bench/sessions.py [--worlds hall,office] [--odometry-noise 1] [--duration 600]
        [--seed 0] [--config FILE.toml] [--json OUT]

``--config`` is given to both sessions' ``dynslam process`` (e.g. ``[prior] max_travel_m``).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from dynslam_cli.simulate import WORLD_NAMES


def dynslam(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "dynslam_cli", *args], capture_output=True,
                          text=True)


def two_sessions(world: str, folder: Path, noise: float, duration: float, seed: int,
                 config: list[str]) -> dict:
    sim = folder / "sim"
    made = dynslam("simulate", world, "-o", str(sim), "--sessions", "2", "--duration",
                   str(duration), "--odometry-noise", str(noise), "--seed", str(seed))
    if made.returncode:
        return {"world": world, "error": made.stderr.strip()}
    logs = made.stdout.split()
    first, second = folder / "day1", folder / "day2"
    dynslam("process", logs[0], "-o", str(first), "-q", *config)
    start = time.perf_counter()
    run = dynslam("process", logs[1], "-o", str(second), "-q", "--prior", str(first), *config)
    seconds = time.perf_counter() - start
    if run.returncode:
        return {"world": world, "error": run.stderr.strip()}
    report = json.loads(dynslam("evaluate", str(second), "--truth",
                                str(sim / "session2" / "truth.json"), "--json").stdout)
    summary = json.loads((second / "summary.json").read_text())
    return {"world": world, "seconds": round(seconds, 2),
            "placement": summary["localization"]["prior"], **report["truth"]["sessions"]}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--worlds", default=",".join(WORLD_NAMES))
    ap.add_argument("--odometry-noise", type=float, default=1.0)
    ap.add_argument("--duration", type=float, default=600)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--config", type=Path, help="A config file for both sessions' runs.")
    ap.add_argument("--json", type=Path, help="Also write the rows here.")
    args = ap.parse_args()
    rows = []
    print("world      ATE prior frame  removed P/R (n)   added P/R (n)")
    for world in args.worlds.split(","):
        with tempfile.TemporaryDirectory() as d:
            row = two_sessions(world, Path(d), args.odometry_noise, args.duration, args.seed,
                               ["--config", str(args.config.resolve())] if args.config else [])
        rows.append(row)
        if "error" in row:
            print(f"{world:<10} {row['error']}", flush=True)
            continue
        cells = [f"{row[k]['precision'] or 0:.2f}/{row[k]['recall'] or 0:.2f} "
                 f"({row[k]['right']}/{row[k]['reported']}, {row[k]['found']}/{row[k]['true']})"
                 for k in ("removed_since_prior", "added_since_prior")]
        print(f"{world:<10} {row['ate_in_prior_frame_m']:.4f} m       {cells[0]:<17} {cells[1]}",
              flush=True)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1) + "\n")


if __name__ == "__main__":
    main()
