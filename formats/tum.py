"""Trajectories in TUM format, as evo reads them.

One pose a line, ``timestamp tx ty tz qx qy qz qw``: exactly 8 fields separated by single
spaces, no trailing space; ``#`` lines are comments. Planar poses: tz = qx = qy = 0,
qz = sin(θ/2), qw = cos(θ/2).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import TextIO

import numpy as np

from dynslam_cli.errors import InputError
from dynslam_formats.source import read_text_lines

STAMP_STEP_S = 1e-6  # the TUM lines' precision: a repeated stamp moves up by this much


def clock_stopped(stamps: np.ndarray) -> bool:
    """Whether a log's scan stamps carry no time: fewer distinct values than half the scans
    (the corrected Radish logs stamp every scan 0, or one value; infinite-corridor's clock
    sticks at 2³²)."""
    return len(stamps) > 1 and 2 * len(np.unique(stamps)) < len(stamps)


def evo_ready(trajectory: np.ndarray) -> np.ndarray:
    """An N×4 trajectory (stamp, x, y, theta) as evo reads it: stamps ascending without
    repeats. Rows are sorted by stamp (stable: scans a log wrote late go to their time),
    and a stamp equal to the one before moves up by STAMP_STEP_S. When the clock stopped
    (:func:`clock_stopped`) the stamps are the scan numbers 0, 1, 2, … (s) in log order."""
    out = np.array(trajectory, dtype=np.float64)
    if clock_stopped(out[:, 0]):
        out[:, 0] = np.arange(len(out), dtype=np.float64)
        return out
    out = out[np.argsort(out[:, 0], kind="stable")]
    repeats = np.flatnonzero(np.diff(out[:, 0]) <= 0)
    for i in range(repeats[0] + 1 if len(repeats) else len(out), len(out)):
        out[i, 0] = max(out[i, 0], out[i - 1, 0] + STAMP_STEP_S)
    return out


def write_tum(out: TextIO, trajectory: np.ndarray) -> None:
    """Write an N×4 array (stamp, x, y, theta) as TUM lines."""
    for stamp, x, y, theta in trajectory:
        h = 0.5 * theta
        out.write(f"{stamp:.6f} {x:.6f} {y:.6f} 0 0 0 {math.sin(h):.9f} {math.cos(h):.9f}\n")


def read_tum(path: Path | str) -> np.ndarray:
    """Read a TUM file into an N×4 array (stamp, x, y, yaw); strict about the layout."""
    rows = []
    name = str(path)
    lines = read_text_lines(path)
    for lineno, line in enumerate(lines, 1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        fields = line.split(" ")
        if len(fields) != 8:
            raise InputError(name, "TUM lines must have 8 entries separated by single spaces "
                             f"and no trailing delimiter (found {len(fields)})", lineno)
        try:
            t, x, y, _z, qx, qy, qz, qw = (float(v) for v in fields)
        except ValueError:
            raise InputError(name, "TUM entries must be numbers", lineno) from None
        yaw = math.atan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))
        rows.append((t, x, y, yaw))
    if not rows:
        raise InputError(name, "no poses in trajectory file")
    return np.array(rows, dtype=np.float64)
