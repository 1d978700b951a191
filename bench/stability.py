"""Stability: the same benchmark log, perturbed below sensor precision, should give nearly
the same answer.

Writes ``--copies`` copies of each Carmen benchmark log (MIT CSAIL, Intel) with every range
moved by a uniform amount of at most ±1 mm and every pose coordinate (x, y) by at most
±10 µm (seeded: the copies are the same on every run), runs each through
``dynslam process`` as bench/relations.py does, and prints each log's relation errors:
min, median, max and the spread (max − min) as a share of the median.

    python bench/stability.py [--logs mit,intel] [--modes full] [--copies 5]
                              [--method icp|correlative] [--config FILE] [--out FILE.json]
"""

from __future__ import annotations

import argparse
import gzip
import json
import statistics
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from relations import DATA, LOGS, add_config_args, base_config, run

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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--logs", default="mit,intel")
    ap.add_argument("--modes", default="full")
    ap.add_argument("--copies", type=int, default=5)
    add_config_args(ap, "stability.json")
    args = ap.parse_args()
    if not DATA.is_dir():
        sys.exit(f"no data sets at {DATA}")
    config = base_config(args)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for name in args.logs.split(","):
            src = DATA / LOGS[name][0]
            if not src.name.endswith((".clf", ".clf.gz")):
                sys.exit(f"{name}: only Carmen logs are perturbed here")
            copies = []
            for seed in range(args.copies):
                copies.append(Path(tmp) / f"{name}-{seed}.clf")
                perturbed_copy(src, copies[-1], seed)
            for mode in args.modes.split(","):
                errors = [run(name, mode, config, Path(tmp), log)["trans_m"] for log in copies]
                median = statistics.median(errors)
                spread = (max(errors) - min(errors)) / median
                rows.append({"log": name, "mode": mode, "trans_m": errors, "spread": spread})
                print(f"{name:6} {mode:5} min {min(errors):.4f} median {median:.4f} max "
                      f"{max(errors):.4f} m  spread {100 * spread:.0f}% of the median  "
                      f"({', '.join(f'{e:.4f}' for e in errors)})", flush=True)
    args.out.write_text(json.dumps(rows, indent=1) + "\n")


if __name__ == "__main__":
    main()
