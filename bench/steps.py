"""How the local SLAM errs step by step: each scan-to-scan increment of the trajectory against
the truth's, in the robot's frame, on the simulated worlds.

For each world and seed: ``dynslam simulate WORLD --odometry-noise 0`` (the odometry equals
the truth, unless ``--odometry-noise`` says otherwise), ``dynslam process`` with the pose
graph off (``--graph``: on), then per step the increment's error along the robot's heading
(forward), across it and in heading. An unbiased matcher's forward errors average zero; a
mean below zero is steps that come out short, which add up along the route (the office
world's long corridor: 0.15 mm of each 8 cm step at stop 67, 0.9 m over its 480 m) where a
random error of the same size would mostly cancel (the lag-1 autocorrelation says how much
each step undoes the last).

    python bench/steps.py [--worlds office,corridors] [--seeds 0,1,2] [--graph]
                          [--odometry-noise 0] [--config FILE.toml] [--json OUT]
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from dynslam_cli.config import Config, load_config, to_toml  # noqa: E402
from dynslam_cli.geometry import wrap_angles  # noqa: E402
from dynslam_cli.simulate import WORLD_NAMES  # noqa: E402
from formats.tum import read_tum  # noqa: E402


def dynslam(*args: str) -> None:
    subprocess.run([sys.executable, "-m", "dynslam_cli", *args], check=True,
                   capture_output=True, text=True)


def increments(poses: np.ndarray) -> np.ndarray:
    """Each step's motion (forward, left, turn) in the frame of the pose it starts from;
    ``poses`` N×3 (x, y, θ)."""
    d = np.diff(poses[:, :2], axis=0)
    c, s = np.cos(poses[:-1, 2]), np.sin(poses[:-1, 2])
    return np.column_stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1],
                            wrap_angles(np.diff(poses[:, 2]))])


def step_errors(trajectory: np.ndarray, truth: np.ndarray) -> dict[str, float]:
    """The trajectory's increments (rows stamp, x, y, θ) against the truth's at the same
    stamps: mean forward error (m per step, and as a share of the true step), its lag-1
    autocorrelation, the mean absolute translation and heading errors."""
    at = {round(float(t), 4): k for k, t in enumerate(truth[:, 0])}
    rows = [at[round(float(t), 4)] for t in trajectory[:, 0]]
    true = increments(truth[rows, 1:4])
    err = increments(trajectory[:, 1:4]) - true
    err[:, 2] = wrap_angles(err[:, 2])
    forward = err[:, 0]
    return {"steps": len(err),
            "forward_mm": 1000 * float(forward.mean()),
            "forward_share": float(forward.sum() / max(np.abs(true[:, 0]).sum(), 1e-12)),
            "forward_lag1": float(np.corrcoef(forward[:-1], forward[1:])[0, 1]),
            "abs_translation_mm": 1000 * float(np.hypot(err[:, 0], err[:, 1]).mean()),
            "abs_heading_deg": math.degrees(float(np.abs(err[:, 2]).mean()))}


def run(world: str, seed: int, noise: float, config: Config, folder: Path) -> dict:
    sim, out, toml = folder / "sim", folder / "out", folder / "config.toml"
    dynslam("simulate", world, "-o", str(sim), "--seed", str(seed), "--odometry-noise",
            str(noise))
    toml.write_text(to_toml(config))
    dynslam("process", str(sim / f"{world}.log"), "-o", str(out), "-q", "--config", str(toml))
    truth = np.asarray(json.loads((sim / "truth.json").read_text())["poses"], dtype=float)
    report = subprocess.run([sys.executable, "-m", "dynslam_cli", "evaluate", str(out),
                             "--truth", str(sim / "truth.json"), "--json"],
                            check=True, capture_output=True, text=True)
    ate = json.loads(report.stdout)["truth"]["trajectory"]["ate_rmse_m"]
    return {"world": world, "seed": seed, "ate_m": ate,
            **step_errors(read_tum(out / "trajectory.tum"), truth)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--worlds", default=",".join(WORLD_NAMES))
    ap.add_argument("--seeds", default="0")
    ap.add_argument("--odometry-noise", type=float, default=0.0)
    ap.add_argument("--graph", action="store_true", help="pose graph on (default: off)")
    ap.add_argument("--config", type=Path, help="a TOML file for every run")
    ap.add_argument("--json", type=Path, help="also write the rows here")
    args = ap.parse_args()
    config = load_config(args.config)
    config = replace(config, loop=replace(config.loop, enabled=args.graph))
    print("world      seed   ATE m   forward mm/step  (share)   lag-1   |step| mm  |turn| deg")
    rows = []
    for world in args.worlds.split(","):
        for seed in (int(s) for s in args.seeds.split(",")):
            with tempfile.TemporaryDirectory() as d:
                row = run(world, seed, args.odometry_noise, config, Path(d))
            rows.append(row)
            print(f"{world:<10} {seed:>4} {row['ate_m']:7.4f} {row['forward_mm']:+12.3f}"
                  f"     ({100 * row['forward_share']:+.3f}%) {row['forward_lag1']:+7.2f}"
                  f" {row['abs_translation_mm']:9.2f} {row['abs_heading_deg']:10.4f}",
                  flush=True)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1) + "\n")


if __name__ == "__main__":
    main()
