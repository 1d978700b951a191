"""The paper's noted weakness (Sec. 5.1): small objects close to walls.

A 0.6 m box is moved among four spots at a given gap from the arena walls (odometry = truth,
odometry localization, 600 s at 10 Hz); prints Table-4 style detection per gap. The
neighbourhood rule (±0.1 m) counts hits that close to a wall as the wall, so part of such a
box turns static: "detected_static" counts those moves.

    python bench/near_walls.py [--neighbourhood M] [--surface M] [--drift F]

``--neighbourhood`` sets ``[dynamic] neighbourhood_m`` (default 0.1), ``--surface``
``[dynamic] surface_m`` (default 0: off; 0.03 finds 10/10 at every gap, with true odometry
and with ``--drift 1``, where the local SLAM localizes the robot on a drifting odometry).
A neighbourhood of 0 m, measured at 8974df9 (this bench, then ``bench/accuracy.py --modes
S/D`` with the same value), finds 10/10 moves at a 0.05 and a 0.10 m gap, but with true
odometry D's precision falls from 1.00 to 0.08 in the corridors world (0.23 arena, 0.13
hall, 0.51 crowd, 0.03 office) and the corridors report 359 false moving tracks: end
points of walls fall a cell off them even with an exact pose. 0.05 m finds 2/10 and 3/10.
So the neighbourhood cannot simply shrink where the pose is sure; what a wall's end points
do cell by cell must be told from an object 5 cm in front of it another way: the surfaces.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from dynslam_cli.config import Config
from dynslam_cli.evaluate import MapThresholds, score_events
from dynslam_cli.job import snapshots_at
from dynslam_cli.localization.cornerslam import EkfConfig
from dynslam_cli.sections import DynamicConfig, LoopConfig
from dynslam_cli.simulate import (
    Box,
    LaserModel,
    OdometryNoise,
    build_world,
    simulate,
)
from dynslam_formats import ReaderOptions, open_log
from dynslam_formats.simlogs import write_carmen
from dynslam_formats.truth import write_truth

HALF = 0.3


def detection_at_gap(gap: float, folder: Path, neighbourhood_m: float = 0.1,
                     surface_m: float = 0.0, drift: float = 0.0) -> dict:
    """Table-4 detection of the box's moves at ``gap`` from the walls; with ``drift`` above
    0, the odometry drifts by that scale of the simulator's model and the robot is localized
    by the default local SLAM (the pose graph off: snapshots are the online maps)."""
    world = build_world("arena")
    far = 12.0 - gap - HALF
    near = gap + HALF
    world.boxes = [Box("box0", HALF, HALF, [(near, 6.0), (6.0, far), (far, 6.0), (6.0, near)]),
                   world.boxes[1]]
    steps, truth = simulate(world, 600, 10.0, 0, noise=OdometryNoise().scaled(drift))
    with open(folder / "arena.log", "w") as f:
        write_carmen(f, steps, LaserModel(), "flaser", "arena")
    write_truth(folder / "truth.json", truth)
    t = json.loads((folder / "truth.json").read_text())
    t["objects"] = {k: v for k, v in t["objects"].items() if k == "box0"}
    source, _, reader = open_log(str(folder / "arena.log"), ReaderOptions())
    dynamic = DynamicConfig(neighbourhood_m=neighbourhood_m, surface_m=surface_m)
    config = (Config(ekf=EkfConfig(localization="odometry"), dynamic=dynamic) if drift == 0
              else Config(dynamic=dynamic, loop=LoopConfig(enabled=False)))
    _, snaps = snapshots_at(reader.scans(), config, [e["time"] for e in t["events"]])
    source.close()
    return score_events(snaps, t, MapThresholds(0.1, 0.9))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--neighbourhood", type=float, default=DynamicConfig().neighbourhood_m,
                    help="[dynamic] neighbourhood_m (m)")
    ap.add_argument("--surface", type=float, default=DynamicConfig().surface_m,
                    help="[dynamic] surface_m (m)")
    ap.add_argument("--drift", type=float, default=0.0,
                    help="odometry noise scale; above 0 the robot is localized by the local "
                         "SLAM instead of the (true) odometry")
    args = ap.parse_args()
    for gap in (0.05, 0.10, 0.20, 0.40):
        with tempfile.TemporaryDirectory() as d:
            ev = detection_at_gap(gap, Path(d), args.neighbourhood, args.surface, args.drift)
        m, v = ev["moved_objects_detected"], ev["vacated_places_cleared"]
        print(f"gap {gap:.2f} m: moved detected {m['detected']}/{m['of']}, "
              f"detected static {m['detected_static']}, vacated cleared {v['cleared']}/{v['of']}")


if __name__ == "__main__":
    main()
