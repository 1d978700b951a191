"""The landmark map as CSV: ``id,x,y,kind,class,observations`` (metres, map frame)."""

from __future__ import annotations

import csv
from collections.abc import Iterable
from typing import TextIO

from dynslam_cli.pipeline import Landmark

HEADER = ("id", "x", "y", "kind", "class", "observations")


def write_landmarks(out: TextIO, landmarks: Iterable[Landmark]) -> None:
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(HEADER)
    for lm in landmarks:
        writer.writerow((lm.id, f"{lm.x:.4f}", f"{lm.y:.4f}", lm.kind, lm.cls, lm.observations))


def read_landmarks(inp: TextIO) -> list[Landmark]:
    reader = csv.DictReader(inp)
    return [Landmark(id=int(r["id"]), x=float(r["x"]), y=float(r["y"]), kind=r["kind"],
                     cls=r["class"], observations=int(r["observations"])) for r in reader]
