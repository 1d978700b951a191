"""Kümmerle et al. (2009) ``.relations`` files: ``t1 t2 x y z roll pitch yaw`` a line."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from dynslam_cli.errors import InputError
from dynslam_formats.source import read_text_lines


def read_relations(path: Path | str) -> np.ndarray:
    """N×8 array; blank and ``#`` lines skipped; anything else malformed is an error."""
    name = str(path)
    lines = read_text_lines(path)
    rows = []
    for lineno, line in enumerate(lines, 1):
        fields = line.split()
        if not fields or fields[0].startswith("#"):
            continue
        if len(fields) != 8:
            raise InputError(name, f"a relation has 8 fields (t1 t2 x y z roll pitch yaw), "
                             f"found {len(fields)}", lineno)
        try:
            rows.append([float(f) for f in fields])
        except ValueError:
            raise InputError(name, "relation fields must be numbers", lineno) from None
    if not rows:
        raise InputError(name, "no relations in file")
    return np.array(rows, dtype=np.float64)
