"""Stability: the same benchmark log, perturbed below sensor precision, should give nearly
the same answer.

Writes ``--copies`` copies of each Carmen benchmark log (MIT CSAIL, Intel) with every range
moved by a uniform amount of at most ±1 mm and every pose coordinate (x, y) by at most
±10 µm (seeded: the copies are the same on every run), runs each through
``dynslam process`` as bench/relations.py does, and prints each log's relation errors:
min, median, max and the spread (max − min) as a share of the median.

    python bench/stability.py [--logs mit,intel] [--modes full] [--copies 5]
                              [--radish intel:moderate,aces:moderate,seattle:harsh]
                              [--method icp|correlative] [--config FILE] [--out FILE.json]

``--radish NAME:LEVEL,...``: the same for Radish rows (bench/radish.py's log with its
drifting odometry of that level, seed 0), full runs scored by ATE against the corrected
poses; ``--logs ''`` runs those alone.
"""

from __future__ import annotations

import argparse
import gzip
import json
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from radish import ate, poses, prepared, radish_logs
from relations import DATA, DYNSLAM, LOGS, add_config_args, base_config, run

from dynslam_cli.config import to_toml
from dynslam_formats.tum import read_tum

RANGE_M = 1e-3
POSE_M = 1e-5


def perturbed_line(line: str, rng: np.random.Generator) -> str:
    """A Carmen FLASER or ODOM line with its ranges and pose coordinates moved (other lines
    as they are). FLASER n r₁…rₙ x y θ odom_x odom_y odom_θ …; ODOM x y θ …."""
    f = line.split()
    if not f:
        return line
    if f[0] == "FLASER":
        n = int(f[1])
        ranges = np.array(f[2:2 + n], dtype=float) + rng.uniform(-RANGE_M, RANGE_M, n)
        f[2:2 + n] = [f"{r:.4f}" for r in ranges]
        coords = [2 + n, 3 + n, 5 + n, 6 + n]
    elif f[0] == "ODOM":
        coords = [1, 2]
    else:
        return line
    for i in coords:
        f[i] = f"{float(f[i]) + rng.uniform(-POSE_M, POSE_M):.6f}"
    return " ".join(f) + "\n"


def perturbed_copy(src: Path, dst: Path, seed: int) -> None:
    rng = np.random.default_rng(seed)
    opener = gzip.open if src.suffix == ".gz" else open
    with opener(src, "rt") as fin, open(dst, "w") as fout:
        for line in fin:
            fout.write(perturbed_line(line, rng))


def radish_ate(log: Path, truth: np.ndarray, config_file: Path, out: Path) -> float:
    """ATE (m) of a full run of ``log`` (a copy of a Radish row) against the row's
    corrected positions ``truth``."""
    subprocess.run([*DYNSLAM, "process", str(log), "-o", str(out), "--force", "-q",
                    "--config", str(config_file)], check=True, stdout=subprocess.DEVNULL,
                   stderr=subprocess.DEVNULL)
    return ate(read_tum(out / "trajectory.tum")[:, 1:3], truth)


def report(rows: list[dict], name: str, mode: str, errors: list[float]) -> None:
    median = statistics.median(errors)
    spread = (max(errors) - min(errors)) / median
    rows.append({"log": name, "mode": mode, "trans_m": errors, "spread": spread})
    print(f"{name:6} {mode:5} min {min(errors):.4f} median {median:.4f} max "
          f"{max(errors):.4f} m  spread {100 * spread:.0f}% of the median  "
          f"({', '.join(f'{e:.4f}' for e in errors)})", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--logs", default="mit,intel")
    ap.add_argument("--modes", default="full")
    ap.add_argument("--copies", type=int, default=5)
    ap.add_argument("--radish", default="", help="Radish rows NAME:LEVEL,... (full runs, ATE)")
    add_config_args(ap, "stability.json")
    args = ap.parse_args()
    if not DATA.is_dir():
        sys.exit(f"no data sets at {DATA}")
    config = base_config(args)
    rows: list[dict] = []
    with tempfile.TemporaryDirectory() as tmp:
        config_file = Path(tmp) / "config.toml"
        config_file.write_text(to_toml(config))
        for row in filter(None, args.radish.split(",")):
            name, level = row.split(":")
            src, truth = prepared(name, level, 0), poses(radish_logs()[name])[:, :2]
            errors = []
            for seed in range(args.copies):
                copy = Path(tmp) / f"{name}-{level}-{seed}.log"
                perturbed_copy(src, copy, seed)
                errors.append(radish_ate(copy, truth, config_file, Path(tmp) / "out"))
            report(rows, f"{name} {level}", "full", errors)
        for name in filter(None, args.logs.split(",")):
            src = DATA / LOGS[name][0]  # (perturbed copies of the log; run with its settings)
            if not src.name.endswith((".clf", ".clf.gz")):
                sys.exit(f"{name}: only Carmen logs are perturbed here")
            copies = []
            for seed in range(args.copies):
                copies.append(Path(tmp) / f"{name}-{seed}.clf")
                perturbed_copy(src, copies[-1], seed)
            for mode in args.modes.split(","):
                report(rows, name, mode,
                       [run(name, mode, config, Path(tmp), log)["trans_m"] for log in copies])
    args.out.write_text(json.dumps(rows, indent=1) + "\n")


if __name__ == "__main__":
    main()
