"""Is the local scan matcher's covariance honest? The normalized estimation error squared
(NEES) of its increments on the built-in worlds, whose truth is exact, and on the Radish
corrected logs, whose poses are another SLAM's (good to a few millimetres from one scan to
the next, so their increments serve as truth there).

Each world is simulated with drifting odometry (each Radish log gets bench/radish.py's
drifting odometry of ``--level``), its scans are matched one after another as the front end
matches them, and every matched increment's error against the true increment is weighed by
the covariance the matcher gave it: eᵀ Σ⁻¹ e, whose mean is 3 (the degrees of freedom) for
an honest covariance, above for an overconfident one.

    python bench/calibration.py [--worlds office,hall] [--radish intel,aces]
                                [--level moderate] [--method icp|correlative]
                                [--config FILE] [--duration 300] [--rate 10]
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

from dynslam_cli.config import Config, load_config  # noqa: E402
from dynslam_cli.geometry import relative  # noqa: E402
from dynslam_cli.localization.scanmatch import ScanMatcher  # noqa: E402
from dynslam_cli.simulate import (  # noqa: E402
    WORLD_NAMES,
    LaserModel,
    OdometryNoise,
    build_world,
    simulate,
)
from dynslam_cli.types import Pose2D  # noqa: E402
from dynslam_formats import ReaderOptions, open_log  # noqa: E402
from dynslam_formats.simlogs import write_carmen  # noqa: E402


def world_nees(world: str, config: Config, duration: float, rate: float, tmp: Path) -> dict:
    """NEES on a built-in world simulated with drifting odometry."""
    steps, truth = simulate(build_world(world), duration, rate, 0,
                            noise=OdometryNoise().scaled(1.0))
    log = tmp / f"{world}.log"
    with open(log, "w") as f:
        write_carmen(f, steps, LaserModel(), "flaser", world)
    return {"world": world, **nees(log, [Pose2D(*p[1:4]) for p in truth.poses], config)}


def radish_nees(name: str, level: str, config: Config) -> dict:
    """NEES on a Radish log with bench/radish.py's drifting odometry of ``level`` (seed 0),
    against the corrected poses."""
    from radish import poses as radish_poses
    from radish import prepared, radish_logs

    truth = [Pose2D(*p) for p in radish_poses(radish_logs()[name])]
    return {"world": f"{name} ({level})", **nees(prepared(name, level, 0), truth, config)}


def nees(log: Path, poses: list[Pose2D], config: Config) -> dict:
    """The matcher's increments over ``log``, scored against the increments of ``poses``
    (one per scan)."""
    matcher = ScanMatcher(config.match, config.ekf.noise)
    source, _, reader = open_log(str(log), ReaderOptions(**config.laser.reader_options()))
    values, errors = [], []
    for k, scan in enumerate(reader.scans()):
        inc, _, cov = matcher.increment(scan)
        if k == 0 or cov is None:
            continue
        true = relative(poses[k - 1], poses[k])
        e = np.array([inc.x - true.x, inc.y - true.y,
                      math.remainder(inc.theta - true.theta, math.tau)])
        values.append(float(e @ np.linalg.solve(cov, e)))
        errors.append(e)
    source.close()
    v, err = np.array(values), np.array(errors)
    return {"method": config.match.method, "matched": len(v),
            "nees_mean": float(v.mean()), "nees_median": float(np.median(v)),
            "rms_mm": float(1000 * np.sqrt((err[:, :2] ** 2).sum(axis=1).mean())),
            "rms_deg": float(np.degrees(np.sqrt((err[:, 2] ** 2).mean())))}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--worlds", default=",".join(WORLD_NAMES))
    ap.add_argument("--radish", default="", help="Radish logs, comma-separated")
    ap.add_argument("--level", default="moderate", help="their odometry (bench/radish.py)")
    ap.add_argument("--method", choices=("icp", "correlative"), default="correlative")
    ap.add_argument("--config", type=Path, help="a TOML file the runs start from")
    ap.add_argument("--duration", type=float, default=300.0)
    ap.add_argument("--rate", type=float, default=10.0)
    args = ap.parse_args()
    print(f"{'world':12} {'method':12} {'matched':>7} {'NEES mean':>9} {'median':>7} "
          f"{'err mm':>7} {'err deg':>7}")
    config = load_config(args.config, {"match": {"method": args.method}})
    with tempfile.TemporaryDirectory() as d:
        runs = [lambda w=w: world_nees(w, config, args.duration, args.rate, Path(d))
                for w in args.worlds.split(",") if w]
        runs += [lambda n=n: radish_nees(n, args.level, config)
                 for n in args.radish.split(",") if n]
        for run in runs:
            r = run()
            print(f"{r['world']:12} {args.method:12} {r['matched']:7} {r['nees_mean']:9.2f} "
                  f"{r['nees_median']:7.2f} {r['rms_mm']:7.1f} {r['rms_deg']:7.3f}",
                  flush=True)


if __name__ == "__main__":
    main()
