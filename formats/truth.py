"""``truth.json`` of a simulated run, and writing a simulated run as a log."""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Iterable
from pathlib import Path
from typing import Any, TextIO

from dynslam_cli.errors import InputError
from dynslam_cli.simulate import LaserModel, SimStep, Truth
from formats.carmen import format_flaser, format_odom, format_param, format_robotlaser1

RECORDS = ("flaser", "robotlaser1")


def write_carmen(out: TextIO, steps: Iterable[SimStep], laser: LaserModel, record: str,
                 world: str) -> int:
    """Write the simulated steps as a Carmen log; returns the number of scans."""
    fov = math.radians(laser.fov_deg)
    step = fov / max(laser.beams - 1, 1)
    out.write("# CARMEN Logfile\n# written by dynslam simulate, world " + world + "\n")
    out.write(format_param("laser_front_laser_fov", f"{laser.fov_deg:g}"))
    out.write(format_param("laser_front_laser_resolution", f"{math.degrees(step):.9g}"))
    out.write(format_param("laser_front_laser_max_range", f"{laser.max_range_m:g}"))
    n = 0
    for s in steps:
        out.write(format_odom(s.stamp, s.odom))
        if record == "flaser":
            out.write(format_flaser(s.stamp, s.ranges, s.odom))
        else:
            out.write(format_robotlaser1(s.stamp, s.ranges, -fov / 2, step, laser.max_range_m,
                                         s.odom))
        n += 1
    return n


def _rounded(rows: list[tuple[float, ...]], digits: int = 5) -> list[list[float]]:
    return [[round(v, digits) for v in row] for row in rows]


def write_truth(path: Path, truth: Truth) -> None:
    data: dict[str, Any] = {
        "world": truth.world,
        "seed": truth.seed,
        "laser": dataclasses.asdict(truth.laser),
        "walls": truth.walls,
        "static_corners": [list(c) for c in truth.corners],
        "poses": _rounded(truth.poses),
        "odometry": _rounded(truth.odometry),
        "objects": truth.objects,
        "events": truth.events,
        "hits": truth.hits,
    }
    path.write_text(json.dumps(data, separators=(",", ":")) + "\n", encoding="utf-8")


def read_truth(path: Path) -> dict[str, Any]:
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except OSError as e:
        raise InputError(str(path), f"cannot read: {e.strerror}") from None
    except json.JSONDecodeError as e:
        raise InputError(str(path), f"not valid JSON: {e.msg}", e.lineno) from None
    missing = [k for k in ("walls", "poses", "odometry", "objects", "events", "hits")
               if k not in data]
    if missing:
        raise InputError(str(path), f"not a dynslam truth file (missing {', '.join(missing)})")
    return data
