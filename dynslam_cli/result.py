"""What a run of the SLAM hands the writers: the maps, the landmarks in the map frame, the
trajectory, the change events and the counts for the summary."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from dynslam_cli.mapping.changes import ChangeEvent, change_events
from dynslam_cli.mapping.grid import OccupancyMap

if TYPE_CHECKING:
    from dynslam_cli.mapping.dynamic import DynamicMapper


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
    closures: np.ndarray = field(default_factory=lambda: np.zeros((0, 5)))
    """The pose graph's loop closures (final results only): per row the scan numbers of
    the two nodes' scans (old, new) and the new seen from the old (x, y, θ) as matched."""

    @classmethod
    def of(cls, mapper: DynamicMapper, trajectory: np.ndarray, landmarks: list[Landmark],
           localization: dict[str, int], final: bool = False,
           closures: np.ndarray | None = None) -> SlamResult:
        """The result of the maps of ``mapper``, with the change events found in its
        evidence if ``final`` (each named by the landmark it stands on, if any)."""
        changes = []
        if final and mapper.changes is not None:
            changes = change_events(mapper.changes, [(lm.id, lm.x, lm.y) for lm in landmarks])
        return cls(static=mapper.grids.snapshot("static"),
                   dynamic=mapper.grids.snapshot("dynamic"), trajectory=trajectory,
                   landmarks=landmarks, localization=localization,
                   grid_memory=mapper.grids.memory(), changes=changes,
                   closures=np.zeros((0, 5)) if closures is None else closures)


def landmarks_of(corners: list[tuple[int, bool, int, float, float, np.ndarray]],
                 classify: Callable[[np.ndarray], list[str]]) -> list[Landmark]:
    """The landmark map's rows from the corners (id, convex, observations, x, y, 2×2
    covariance; map frame), each classed by Table 3 (``classify``: the classes of N×2
    places)."""
    classes = classify(np.array([[x, y] for _, _, _, x, y, _ in corners]).reshape(-1, 2))
    return [Landmark(i, x, y, "convex" if convex else "concave", c, seen,
                     float(cov[0, 0]), float(cov[0, 1]), float(cov[1, 1]))
            for (i, convex, seen, x, y, cov), c in zip(corners, classes, strict=True)]
