"""The landmark map as CSV: ``id,x,y,kind,class,observations,cov_xx,cov_xy,cov_yy`` (metres,
map frame; the covariance of the position estimate in m²)."""

from __future__ import annotations

import csv
from collections.abc import Iterable
from typing import TextIO

from dynslam_cli.result import Landmark

HEADER = ("id", "x", "y", "kind", "class", "observations", "cov_xx", "cov_xy", "cov_yy")


def write_landmarks(out: TextIO, landmarks: Iterable[Landmark]) -> None:
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(HEADER)
    for lm in landmarks:
        writer.writerow((lm.id, f"{lm.x:.4f}", f"{lm.y:.4f}", lm.kind, lm.cls, lm.observations,
                         f"{lm.cov_xx:.6g}", f"{lm.cov_xy:.6g}", f"{lm.cov_yy:.6g}"))


def read_landmarks(inp: TextIO) -> list[Landmark]:
    reader = csv.DictReader(inp)
    return [Landmark(id=int(r["id"]), x=float(r["x"]), y=float(r["y"]), kind=r["kind"],
                     cls=r["class"], observations=int(r["observations"]),
                     cov_xx=float(r.get("cov_xx") or 0), cov_xy=float(r.get("cov_xy") or 0),
                     cov_yy=float(r.get("cov_yy") or 0)) for r in reader]
