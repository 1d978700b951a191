"""``truth.json`` of a simulated run: written by ``dynslam simulate``, read by ``evaluate``."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

from dynslam_cli.errors import InputError
from dynslam_cli.simulate import Truth


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
        "stamp_offset_s": truth.stamp_offset_s,
    }
    if truth.session > 1 or truth.fixtures:
        data |= {"session": truth.session, "fixtures": truth.fixtures,
                 "prior_changes": truth.prior_changes}
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
