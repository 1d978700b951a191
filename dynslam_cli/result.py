"""What a run of the SLAM hands the writers: the maps, the landmarks in the map frame, the
trajectory, the change events and the counts for the summary."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from dynslam_cli.mapping.changes import ChangeEvent
from dynslam_cli.mapping.grid import OccupancyMap


@dataclass(frozen=True)
class Landmark:
    """A corner landmark in the map frame."""

    id: int
    x: float
    y: float
    kind: str  # "convex" | "concave"
    cls: str  # "static" | "dynamic"
    observations: int
    cov_xx: float = 0.0
    cov_xy: float = 0.0
    cov_yy: float = 0.0


@dataclass
class SlamResult:
    """Everything the writers need."""

    static: OccupancyMap
    dynamic: OccupancyMap
    trajectory: np.ndarray  # N×4: stamp (s), x (m), y (m), theta (rad)
    landmarks: list[Landmark] = field(default_factory=list)
    localization: dict[str, int] = field(default_factory=dict)
    """Counts for the summary: scan matches, fallbacks, graph nodes, loop closures."""
    grid_memory: dict[str, float] = field(default_factory=dict)
    """What the final grids hold: tiles, cells stored and seen, bytes per cell seen."""
    changes: list[ChangeEvent] = field(default_factory=list)
    """What changed in the world during the run (final results only)."""
