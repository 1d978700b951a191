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
                                [--level moderate] [--benchmark mit,intel,fr079]
                                [--method icp|correlative]
                                [--config FILE] [--duration 300] [--rate 10]
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

from dynslam_cli.config import Config, load_config  # noqa: E402
from dynslam_cli.geometry import compose, compound_covariance, relative  # noqa: E402
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
from dynslam_formats.relations import read_relations  # noqa: E402
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


def benchmark_nees(name: str, config: Config, max_dt: float = 5.0) -> dict:
    """NEES on a raw benchmark log (bench/relations.py's, its real odometry) against its
    ground-truth relations no longer than ``max_dt`` seconds: the matched increments between
    the relation's two scans composed, their covariances with them (to first order); a
    relation across a scan the matcher did not match is left out."""
    from relations import DATA, LOGS

    path, rel, laser = LOGS[name]
    config = replace(config, laser=replace(config.laser, **laser))
    matched = matched_increments(DATA / path, config)
    stamps = np.array([stamp for stamp, _, _ in matched])
    steps = [(inc, cov) for _, inc, cov in matched]
    values, errors = [], []
    for t1, t2, x, y, _, _, _, yaw in read_relations(DATA / "relations" / f"{rel}.relations"):
        i, j = (int(np.argmin(np.abs(stamps - t))) for t in (t1, t2))
        if (t2 - t1 > max_dt or j <= i or abs(stamps[i] - t1) > 0.1 or abs(stamps[j] - t2) > 0.1
                or any(cov is None for _, cov in steps[i + 1:j + 1])):
            continue
        pose, cov = Pose2D(), np.zeros((3, 3))
        for inc, inc_cov in steps[i + 1:j + 1]:
            cov = compound_covariance(pose, cov, inc, inc_cov)
            pose = compose(pose, inc)
        e = np.array([pose.x - x, pose.y - y, math.remainder(pose.theta - yaw, math.tau)])
        values.append(float(e @ np.linalg.solve(cov, e)))
        errors.append(e)
    return {"world": f"{name} (relations)", **_scores(values, errors, config)}


def matched_increments(log: Path, config: Config
                       ) -> list[tuple[float, Pose2D, np.ndarray | None]]:
    """Each scan of ``log`` as the front end matches them one after another: its stamp,
    its increment and the increment's covariance (None where it was not matched)."""
    matcher = ScanMatcher(config.match, config.ekf.noise)
    source, _, reader = open_log(str(log), ReaderOptions(**config.laser.reader_options()))
    out = []
    try:
        for scan in reader.scans():
            inc, _, cov = matcher.increment(scan)
            out.append((scan.stamp, inc, cov))
    finally:
        source.close()
    return out


def nees(log: Path, poses: list[Pose2D], config: Config) -> dict:
    """The matcher's increments over ``log``, scored against the increments of ``poses``
    (one per scan)."""
    values, errors = [], []
    for k, (_, inc, cov) in enumerate(matched_increments(log, config)):
        if k == 0 or cov is None:
            continue
        true = relative(poses[k - 1], poses[k])
        e = np.array([inc.x - true.x, inc.y - true.y,
                      math.remainder(inc.theta - true.theta, math.tau)])
        values.append(float(e @ np.linalg.solve(cov, e)))
        errors.append(e)
    return _scores(values, errors, config)


def _scores(values: list[float], errors: list[np.ndarray], config: Config) -> dict:
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
    ap.add_argument("--benchmark", default="",
                    help="raw benchmark logs (bench/relations.py's: mit, intel, fr079, ...), "
                         "scored by their relations up to 5 s long")
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
        runs += [lambda n=n: benchmark_nees(n, config) for n in args.benchmark.split(",") if n]
        for run in runs:
            r = run()
            print(f"{r['world']:12} {args.method:12} {r['matched']:7} {r['nees_mean']:9.2f} "
                  f"{r['nees_median']:7.2f} {r['rms_mm']:7.1f} {r['rms_deg']:7.3f}",
                  flush=True)


if __name__ == "__main__":
    main()
