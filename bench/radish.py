"""Localization on real logs the tool was not tuned on: the 13 Radish "-corrected" logs.

Their FLASER poses are SLAM-corrected key frames; used as the truth, with a drifting wheel
odometry of our own put in their place (``drift_log``: the noise model of
dynslam_cli.simulate, with this file's levels and seeds), each log is run through
``dynslam process`` as a user runs it and scored by ATE (RMSE of positions after SE(2)
alignment, matched scan by scan in log order: some logs have all-zero time stamps).
Level ``perfect`` is the log as it is (its corrected poses as the odometry).

    python bench/radish.py [--levels perfect,moderate,harsh] [--logs intel,aces] [--jobs 2]
                           [--seed 0] [--front-end] [--out bench/radish.json]

Prints a table (odometry ATE → dynslam ATE per log and level, and the relative error over
10 m of path: translation % and rotation °) and writes the rows as JSON. ``--front-end``
runs without the pose graph: the drift of the scan matcher and the EKF alone, which the
relative error measures (the ATE of a run without loop closures says little).
"""

from __future__ import annotations

import argparse
import gzip
import hashlib
import json
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from dynslam_cli.evaluate import aligned_rmse  # noqa: E402
from dynslam_cli.geometry import compose, relative  # noqa: E402
from dynslam_cli.simulate import OdometryNoise, noisy_increment  # noqa: E402
from dynslam_cli.types import Pose2D  # noqa: E402
from dynslam_formats.tum import read_tum  # noqa: E402

DATA = ROOT.parent / "shared" / "datasets" / "carmen" / "radish-corrected"
CACHE = ROOT / "bench" / "cache" / "radish"
DYNSLAM = [sys.executable, "-m", "dynslam_cli"]

LEVELS: dict[str, OdometryNoise | None] = {
    "perfect": None,
    "moderate": OdometryNoise(scale_error=0.01, heading_bias_deg_per_m=0.1,
                              rotation_scale_error=0.01, sigma_m_per_sqrt_m=0.03,
                              sigma_deg_per_sqrt_rad=1.5, lateral_sigma_m_per_sqrt_m=0.01),
    "harsh": OdometryNoise(scale_error=0.03, heading_bias_deg_per_m=0.3,
                           rotation_scale_error=0.03, sigma_m_per_sqrt_m=0.06,
                           sigma_deg_per_sqrt_rad=3.0, lateral_sigma_m_per_sqrt_m=0.02),
}


def radish_logs() -> dict[str, Path]:
    return {p.name.removesuffix("-corrected.log.gz"): p
            for p in sorted(DATA.glob("*-corrected.log.gz"))}


def flaser_poses(tokens: list[str]) -> tuple[int, Pose2D, Pose2D]:
    """(beam count, laser pose, robot pose) of a FLASER line's tokens."""
    n = int(tokens[1])
    v = [float(t) for t in tokens[2 + n:8 + n]]
    return n, Pose2D(*v[:3]), Pose2D(*v[3:])


def drift_log(src: Path, dst: Path, noise: OdometryNoise, seed: int) -> None:
    """Copy a corrected Carmen log with each FLASER pose replaced by a drifting odometry
    (the corrected key-frame motion through ``noise``); the laser keeps its mounting. ODOM
    and NEFF lines are dropped (FLASER carries the odometry)."""
    rng = np.random.default_rng(seed)
    prev: Pose2D | None = None
    odom = Pose2D()
    tmp = dst.with_suffix(".tmp")
    with gzip.open(src, "rt") as f, open(tmp, "w") as out:
        for line in f:
            tokens = line.split()
            if not tokens or tokens[0] in ("ODOM", "NEFF"):
                continue
            if tokens[0] != "FLASER":
                out.write(line)
                continue
            n, laser, robot = flaser_poses(tokens)
            odom = robot if prev is None else compose(
                odom, noisy_increment(relative(prev, robot), noise, rng))
            prev = robot
            new_laser = compose(odom, relative(robot, laser))
            pose = [f"{v:.6f}" for p in (new_laser, odom) for v in (p.x, p.y, p.theta)]
            out.write(" ".join([*tokens[:2 + n], *pose, *tokens[8 + n:]]) + "\n")
    tmp.replace(dst)


def poses(path: Path) -> np.ndarray:
    """Robot poses (N×3: x, y, θ) of a Carmen log's FLASER lines (gzipped or not)."""
    opener = gzip.open if path.suffix == ".gz" else open
    with opener(path, "rt") as f:
        return np.array([[p.x, p.y, p.theta] for p in (flaser_poses(t)[2] for t in
                         (line.split() for line in f) if t and t[0] == "FLASER")])


def positions(path: Path) -> np.ndarray:
    """Robot positions (N×2) of a Carmen log's FLASER lines."""
    return poses(path)[:, :2]


SEGMENT_M = 10.0


def relative_error(est: np.ndarray, ref: np.ndarray, segment: float = SEGMENT_M
                   ) -> tuple[float, float]:
    """Mean relative pose error over every stretch of ``segment`` metres of the true path
    (from each pose to the first one that far along): translation as % of the stretch,
    rotation in degrees. Poses N×3, matched in order."""
    path = np.concatenate(([0.0], np.cumsum(np.hypot(*np.diff(ref[:, :2], axis=0).T))))
    start = np.arange(len(ref))
    end = np.searchsorted(path, path + segment)
    ok = end < len(ref)
    start, end = start[ok], end[ok]
    if not len(start):
        return float("nan"), float("nan")

    def rel(p: np.ndarray) -> np.ndarray:
        a, b = p[start], p[end]
        c, s = np.cos(a[:, 2]), np.sin(a[:, 2])
        dx, dy = b[:, 0] - a[:, 0], b[:, 1] - a[:, 1]
        return np.column_stack((c * dx + s * dy, -s * dx + c * dy, b[:, 2] - a[:, 2]))

    e, t = rel(est), rel(ref)
    d_th = np.remainder(e[:, 2] - t[:, 2] + np.pi, 2 * np.pi) - np.pi
    trans = np.hypot(e[:, 0] - t[:, 0], e[:, 1] - t[:, 1])
    return (float(np.mean(trans) / segment * 100.0), float(np.degrees(np.mean(np.abs(d_th)))))


def ate(est: np.ndarray, ref: np.ndarray) -> float:
    """ATE RMSE (m) of positions matched in order, after SE(2) alignment."""
    if len(est) != len(ref):
        raise ValueError(f"{len(est)} poses against {len(ref)} truth poses")
    return aligned_rmse(est, ref)


def prepared(name: str, level: str, seed: int) -> Path:
    """The log to run for (name, level): the original, or a cached drifted copy."""
    src = radish_logs()[name]
    noise = LEVELS[level]
    if noise is None:
        return src
    CACHE.mkdir(parents=True, exist_ok=True)
    model = hashlib.sha1(repr(noise).encode()).hexdigest()[:8]  # a changed level: a new file
    dst = CACHE / f"{name}-{level}-{model}-seed{seed}.log"
    if not dst.exists():
        drift_log(src, dst, noise, seed + sum(map(ord, name)))
    return dst


def one(name: str, level: str, seed: int, config: str | None = None) -> dict:
    log = prepared(name, level, seed)
    truth = poses(radish_logs()[name])
    with tempfile.TemporaryDirectory() as d:
        out = Path(d) / "out"
        start = time.perf_counter()
        run = subprocess.run([*DYNSLAM, "process", str(log), "-o", str(out), "-q",
                              "--no-read-ahead", *(["--config", config] if config else [])],
                             capture_output=True, text=True)
        wall = time.perf_counter() - start
        if run.returncode:
            return {"log": name, "level": level, "error": run.stderr.strip()[-300:]}
        est = read_tum(out / "trajectory.tum")[:, 1:4]
        summary = json.loads((out / "summary.json").read_text())
    ate_m = ate(est[:, :2], truth[:, :2])
    rpe_pct, rpe_deg = relative_error(est, truth)
    return {"log": name, "level": level, "seed": seed, "scans": len(truth),
            "odometry_ate_m": round(ate(positions(log), truth[:, :2]), 4),
            "ate_m": round(ate_m, 4), "rpe_pct": round(rpe_pct, 3), "rpe_deg": round(rpe_deg, 3),
            "wall_s": round(wall, 2),
            "peak_rss_mb": summary["peak_rss_mb"],
            "localization": summary["localization"]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--levels", default=",".join(LEVELS))
    ap.add_argument("--logs", default=",".join(radish_logs()))
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--config", help="a dynslam config file (TOML) for every run")
    ap.add_argument("--front-end", action="store_true",
                    help="run without the pose graph (the front end's drift alone)")
    ap.add_argument("--out", default=str(ROOT / "bench" / "radish.json"))
    args = ap.parse_args()
    if not DATA.exists():
        sys.exit(f"no data: {DATA}")
    if args.front_end and args.config:
        sys.exit("--front-end and --config: give one (put [loop] enabled = false in the file)")
    work = [(n, lv) for n in args.logs.split(",") for lv in args.levels.split(",")]
    with tempfile.TemporaryDirectory() as d:
        config = args.config
        if args.front_end:
            config = str(Path(d) / "front-end.toml")
            Path(config).write_text("[loop]\nenabled = false\n")
        with ThreadPoolExecutor(args.jobs) as pool:  # each run is its own process
            rows = list(pool.map(lambda w: one(*w, args.seed, config), work))
    print(f"{'log':20s} {'level':9s} {'odometry':>9s} {'dynslam':>9s} "
          f"{'RPE %':>6s} {'RPE °':>6s} {'wall s':>7s}")
    for r in rows:
        if "error" in r:
            print(f"{r['log']:20s} {r['level']:9s} ERROR {r['error']}")
            continue
        print(f"{r['log']:20s} {r['level']:9s} {r['odometry_ate_m']:9.3f} {r['ate_m']:9.3f} "
              f"{r['rpe_pct']:6.2f} {r['rpe_deg']:6.2f} {r['wall_s']:7.2f}")
    for level in args.levels.split(","):
        ok = [r["ate_m"] for r in rows if r["level"] == level and "ate_m" in r]
        if ok:
            rpe = [r["rpe_deg"] for r in rows if r["level"] == level and "ate_m" in r]
            print(f"{level}: median ATE {np.median(ok):.3f} m, max {max(ok):.3f} m, "
                  f"{sum(a <= (0.05 if level == 'perfect' else 0.15) for a in ok)}/{len(ok)} "
                  f"within the issue's bound; median RPE {np.median(rpe):.2f}° per "
                  f"{SEGMENT_M:g} m")
    Path(args.out).write_text(json.dumps(rows, indent=1, sort_keys=True) + "\n")


if __name__ == "__main__":
    main()
