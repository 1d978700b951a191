"""The paper's two-map update (Sec. 3): Tables 1 and 2 and the neighbourhood rule (Sec. 5).

Each cell of the previous static map S^{t-1} is *Free* (p < low threshold), *Occupied*
(p > high threshold) or *Unknown*; each cell the scan saw is *Free* (a beam passed through)
or *Occupied* (a beam ended there). The inverse sensor models map that pair to a *high* or a
*low* value, which Eqs. 12 and 13 add in log-odds to S and D (priors p(S) = p(D) = 0.5 cancel).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from dynslam_cli import kernels
from dynslam_cli.grid import logit

FREE, UNKNOWN, OCCUPIED = 0, 1, 2
STATE_NAMES = ("Free", "Unknown", "Occupied")
HIGH, LOW = "high", "low"

# Table 1: inverse observation model for the static map, p(S^t | S^{t-1}, o^t).
TABLE_1 = {
    (FREE, FREE): LOW,
    (UNKNOWN, FREE): LOW,
    (OCCUPIED, FREE): LOW,
    (FREE, OCCUPIED): LOW,       # something stands where S was free: a mover, not static
    (UNKNOWN, OCCUPIED): HIGH,   # static until seen to move
    (OCCUPIED, OCCUPIED): HIGH,
}

# Table 2: inverse observation model for the dynamic map, p(D^t | o^t, S^{t-1}).
TABLE_2 = {
    (FREE, FREE): LOW,
    (UNKNOWN, FREE): LOW,
    (OCCUPIED, FREE): LOW,
    (FREE, OCCUPIED): HIGH,      # the only way into D
    (UNKNOWN, OCCUPIED): LOW,
    (OCCUPIED, OCCUPIED): LOW,
}


# Table 3: static and dynamic landmark classification, by the landmark's place in S.
TABLE_3 = {
    FREE: "dynamic",
    UNKNOWN: "dynamic",
    OCCUPIED: "static",      # only these correct the robot's pose
}


@dataclass(frozen=True)
class InverseModel:
    """High/low values (log-odds) of one inverse sensor model and the map's clamp."""

    high: float
    low: float
    clamp_min: float
    clamp_max: float

    @classmethod
    def from_probabilities(cls, high: float, low: float, clamp_min: float, clamp_max: float
                           ) -> InverseModel:
        return cls(logit(high), logit(low), logit(clamp_min), logit(clamp_max))

    def table(self, rows: dict[tuple[int, int], str]) -> np.ndarray:
        """The table as a 3×2 array of log-odds, indexed [S^{t-1} state, o^t state]; stored
        by columns, so each observation's column is a contiguous array."""
        out = np.zeros((3, 2), order="F")
        for (prev, obs), value in rows.items():
            out[prev, 1 if obs == OCCUPIED else 0] = self.high if value == HIGH else self.low
        return out


def classify_static(logodds: np.ndarray, low: float, high: float) -> np.ndarray:
    """Free / Unknown / Occupied state of S^{t-1} cells (thresholds as probabilities)."""
    state = np.full(logodds.shape, UNKNOWN, dtype=np.int8)
    state[logodds < logit(low)] = FREE
    state[logodds > logit(high)] = OCCUPIED
    return state


def neighbourhood_offsets(radius_cells: int, cols: int) -> np.ndarray:
    """Flat-index offsets of the square window of the given radius (row-major grid)."""
    r = np.arange(-radius_cells, radius_cells + 1)
    return (r[:, None] * cols + r[None, :]).ravel().astype(np.intp)


def classify_neighbourhood(static_flat: np.ndarray, cells: np.ndarray, offsets: np.ndarray,
                           low: float, high: float) -> np.ndarray:
    """State of S^{t-1} around each cell (Sec. 5): Occupied if any cell of the window is
    Occupied, Free only if every cell is Free, else Unknown. So an end point that falls a
    cell off a wall (pose or rounding error) still counts as hitting the wall."""
    return kernels.classify_cells(np.asarray(static_flat, dtype=np.float32), cells, offsets,
                                  logit(low), logit(high))


def radius_cells(neighbourhood_m: float, resolution: float) -> int:
    return max(0, math.ceil(neighbourhood_m / resolution - 1e-9))
