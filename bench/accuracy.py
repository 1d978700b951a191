"""Accuracy table: every built-in world, true vs drifting odometry; the full method (S/D),
the ordinary grid (--no-dynamic) and odometry-only localization (--localization odometry);
with the change events (changes.csv) scored.

Runs the real chain (simulate → Carmen log → reader → pipeline), takes map snapshots at every
relocation (paper Table 4, event by event) and scores with dynslam_cli.evaluate. Prints a
table and writes bench/accuracy.json.

    python bench/accuracy.py [--duration 600] [--rate 10] [--worlds corridors,arena]
                             [--modes S/D,ordinary,odometry] [--odometry true,drift]
                             [--method icp|correlative] [--config FILE]

``--config`` is the TOML file every run starts from (default: the built-in defaults);
``--method`` sets its local scan matcher (``[match] method``).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from relations import add_config_args, base_config  # noqa: E402

from dynslam_cli.config import Config  # noqa: E402
from dynslam_cli.evaluate import (  # noqa: E402
    MapThresholds,
    score_changes,
    score_closures,
    score_events,
    score_run,
)
from dynslam_cli.job import snapshots_at  # noqa: E402
from dynslam_cli.simulate import (  # noqa: E402
    WORLD_NAMES,
    LaserModel,
    OdometryNoise,
    build_world,
    simulate,
)
from dynslam_formats import ReaderOptions, open_log  # noqa: E402
from dynslam_formats.simlogs import write_carmen  # noqa: E402
from dynslam_formats.truth import write_truth  # noqa: E402

MODES = {
    "S/D": lambda c: c,
    "ordinary": lambda c: replace(c, dynamic=replace(c.dynamic, enabled=False)),
    "odometry": lambda c: replace(c, ekf=replace(c.ekf, localization="odometry")),
}


def one(world: str, noise: float, mode: str, duration: float, rate: float, tmp: Path,
        base: Config) -> dict:
    log, truth_path = tmp / f"{world}-{noise}.log", tmp / f"{world}-{noise}.json"
    if not log.exists():
        steps, truth = simulate(build_world(world), duration, rate, 0,
                                noise=OdometryNoise().scaled(noise))
        with open(log, "w") as f:
            write_carmen(f, steps, LaserModel(), "flaser", world)
        write_truth(truth_path, truth)
    truth = json.loads(truth_path.read_text())
    config = MODES[mode](base)
    source, _, reader = open_log(str(log), ReaderOptions())
    start = time.perf_counter()
    result, snaps = snapshots_at(reader.scans(), config, [e["time"] for e in truth["events"]])
    wall = time.perf_counter() - start
    source.close()
    th = MapThresholds(config.map.free_threshold, config.map.occupied_threshold)
    final = score_run(result.static, result.dynamic, result.trajectory, result.landmarks,
                      truth, th)
    events = score_events(snaps, truth, th)
    changes = score_changes(result.changes, result.trajectory, truth)
    closures = score_closures(result.closures, result.trajectory, truth)
    return {"world": world, "odometry_noise": noise, "mode": mode, "wall_s": round(wall, 2),
            **final, "events": events, "changes": changes, "closures": closures}


def fmt(v: object) -> str:
    if v is None:
        return "n/a"
    return f"{v:.4f}" if isinstance(v, float) else str(v)


def changes(c: dict) -> tuple[str, str, str]:
    """changes.csv's scores: right/reported and found/true of appeared and vacated; moving
    events in the walkers' loops / reported (and appeared on walkers, if any)."""
    def kind(k: str) -> str:
        return f"{c[k]['right']}/{c[k]['reported']} {c[k]['found']}/{c[k]['true']}"
    m = c["moving"]
    stray = f" ({m['appeared_on_walkers']} appeared on walkers)" if m["appeared_on_walkers"] else ""
    return kind("appeared"), kind("vacated"), f"{m['on_walkers']}/{m['reported']}{stray}"


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--duration", type=float, default=600.0)
    ap.add_argument("--rate", type=float, default=10.0)
    ap.add_argument("--worlds", default=",".join(WORLD_NAMES))
    ap.add_argument("--modes", default=",".join(MODES))
    ap.add_argument("--odometry", default="true,drift",
                    help="the simulator's odometry: true (exact), drift (its default noise)")
    add_config_args(ap, "accuracy.json")
    args = ap.parse_args()
    base = base_config(args)
    rows = []
    with tempfile.TemporaryDirectory() as d:
        for world in args.worlds.split(","):
            for noise in [{"true": 0.0, "drift": 1.0}[o] for o in args.odometry.split(",")]:
                for mode in args.modes.split(","):
                    rows.append(one(world, noise, mode, args.duration, args.rate, Path(d),
                                    base))
    head = ("world", "odom", "mode", "ATE m", "odo ATE", "S prec", "S recall", "ghost",
            "D prec", "moved", "det.static", "vacated", "ch. appeared", "ch. vacated",
            "ch. moving", "closures")
    print(" | ".join(head))
    for r in rows:
        s, dm, ev = r["static_map"], r["dynamic_map"], r["events"]
        mv, vc = ev["moved_objects_detected"], ev["vacated_places_cleared"]
        print(" | ".join((r["world"], "drift" if r["odometry_noise"] else "true", r["mode"],
                          fmt(r["trajectory"]["ate_rmse_m"]),
                          fmt(r["trajectory"]["odometry_ate_rmse_m"]), fmt(s["precision"]),
                          fmt(s["recall"]), fmt(s["ghost_rate"]), fmt(dm["precision"]),
                          f"{mv['detected']}/{mv['of']}", str(mv["detected_static"]),
                          f"{vc['cleared']}/{vc['of']}", *changes(r["changes"]),
                          f"{r['closures']['right']}/{r['closures']['reported']}")))
    args.out.write_text(json.dumps(rows, indent=1, sort_keys=True) + "\n")


if __name__ == "__main__":
    main()
