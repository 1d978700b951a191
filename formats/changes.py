"""Change events as CSV: ``id,kind,first_s,last_s,x,y,size_m2,scans,landmarks`` (stamps of
the log in seconds; centroid in metres, map frame; landmark ids separated by spaces)."""

from __future__ import annotations

import csv
from collections.abc import Iterable
from typing import TextIO

from dynslam_cli.mapping.changes import ChangeEvent

HEADER = ("id", "kind", "first_s", "last_s", "x", "y", "size_m2", "scans", "landmarks")


def write_changes(out: TextIO, events: Iterable[ChangeEvent]) -> None:
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(HEADER)
    for e in events:
        writer.writerow((e.id, e.kind, f"{e.first_s:.3f}", f"{e.last_s:.3f}", f"{e.x:.3f}",
                         f"{e.y:.3f}", f"{e.size_m2:.3f}", e.scans,
                         " ".join(str(i) for i in e.landmarks)))


def read_changes(inp: TextIO) -> list[ChangeEvent]:
    return [ChangeEvent(int(r["id"]), r["kind"], float(r["first_s"]), float(r["last_s"]),
                        float(r["x"]), float(r["y"]), float(r["size_m2"]), int(r["scans"]),
                        tuple(int(i) for i in r["landmarks"].split()))
            for r in csv.DictReader(inp)]
