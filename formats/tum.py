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
from dynslam_formats.base import read_text_lines


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
