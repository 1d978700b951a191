"""The paper's two-map update (Sec. 3): Tables 1 and 2 and the neighbourhood rule (Sec. 5).

Each cell of the previous static map S^{t-1} is *Free* (p < low threshold), *Occupied*
(p > high threshold) or *Unknown*; each cell the scan saw is *Free* (a beam passed through)
or *Occupied* (a beam ended there). The inverse sensor models map that pair to a *high* or a
*low* value, which Eqs. 12 and 13 add in log-odds to S and D (priors p(S) = p(D) = 0.5 cancel).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from dynslam_cli.geometry import compose
from dynslam_cli.mapping import _grid
from dynslam_cli.mapping.changes import ChangeRecorder
from dynslam_cli.mapping.grid import LOGODDS_STEP, GridStack, Observation, logit, steps
from dynslam_cli.mapping.surfaces import Surfaces
from dynslam_cli.sections import ChangeConfig, DynamicConfig, LaserConfig, MapConfig
from dynslam_cli.types import Pose2D, Scan

FREE, UNKNOWN, OCCUPIED = 0, 1, 2
STATE_NAMES = ("Free", "Unknown", "Occupied")
HIGH, LOW = "high", "low"
ONCE_FREE = "once_free"  # the layer of cells S held Free at some time (remember_free)

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
        """The table as a 3×2 array of log-odds in the grid's steps (int32), indexed
        [S^{t-1} state, o^t state]; stored by columns, so each observation's column is a
        contiguous array."""
        out = np.zeros((3, 2), order="F")
        for (prev, obs), value in rows.items():
            out[prev, 1 if obs == OCCUPIED else 0] = self.high if value == HIGH else self.low
        return np.asfortranarray(steps(out))

    @functools.cached_property
    def clamp_steps(self) -> tuple[int, int]:
        """The clamp in the grid's steps."""
        lo, hi = steps((self.clamp_min, self.clamp_max))
        return int(lo), int(hi)


def classify_static(stored: np.ndarray, low: float, high: float) -> np.ndarray:
    """Free / Unknown / Occupied state of S^{t-1} cells (their stored log-odds; thresholds
    as probabilities)."""
    logodds = stored * LOGODDS_STEP  # (exact: the step is a power of two)
    state = np.full(stored.shape, UNKNOWN, dtype=np.int8)
    state[logodds < logit(low)] = FREE
    state[logodds > logit(high)] = OCCUPIED
    return state


def classify_neighbourhood(grids: GridStack, cells: np.ndarray, radius: int, low: float,
                           high: float) -> np.ndarray:
    """State of S^{t-1} around each cell (flat indices; Sec. 5): Occupied if any cell of the
    square window of ``radius`` cells is Occupied, Free only if every cell is Free, else
    Unknown. So an end point that falls a cell off a wall (pose or rounding error) still
    counts as hitting the wall."""
    return grids.classify_cells("static", cells, radius, logit(low), logit(high))


def window_cells(grids: GridStack, cells: np.ndarray, radius: int) -> np.ndarray:
    """The flat indices of the square window of ``radius`` cells around each cell (flat
    indices; N × (2·radius + 1)²), -1 where no tile holds a cell."""
    rows, cols = grids.world_cells(cells)
    span = np.arange(-radius, radius + 1)
    dr, dc = np.meshgrid(span, span, indexing="ij")
    return grids.flat_cells(rows[:, None, None] + dr, cols[:, None, None] + dc)


def unknown_only_beside_walls(grids: GridStack, cells: np.ndarray, radius: int, low: float,
                              high: float) -> np.ndarray:
    """Whether every Unknown cell in the window of ``radius`` cells around each cell (flat
    indices) touches an Occupied one: the strip in front of a wall that no beam passed (free
    space stops a cell short of a hit), not the edge of what the robot has seen."""
    flat = window_cells(grids, cells, radius + 1)
    static = grids.layers["static"]
    state = classify_static(np.where(flat >= 0, static[np.maximum(flat, 0)], 0), low, high)
    occupied, unknown = state == OCCUPIED, state == UNKNOWN
    near = np.zeros_like(occupied)
    for a in (-1, 0, 1):
        for b in (-1, 0, 1):
            near[:, 1:-1, 1:-1] |= occupied[:, 1 + a:occupied.shape[1] - 1 + a,
                                            1 + b:occupied.shape[2] - 1 + b]
    inner = (slice(None), slice(1, -1), slice(1, -1))
    return ~(unknown[inner] & ~near[inner]).any(axis=(1, 2))


def known_free_windows(grids: GridStack, cells: np.ndarray, radius: int, low: float
                       ) -> np.ndarray:
    """Whether every cell of the window of ``radius`` cells around each cell (flat indices)
    is Free in S or was once (``[dynamic] remember_free``; call it where the window holds no
    Occupied cell): space the map knew free, which only hits of no clear class raised."""
    flat = window_cells(grids, cells, radius)
    stored = flat >= 0
    at = np.maximum(flat, 0)
    free = grids.layers["static"][at] * LOGODDS_STEP < logit(low)
    return (stored & (free | (grids.layers[ONCE_FREE][at] > 0))).all(axis=(1, 2))


def radius_cells(neighbourhood_m: float, resolution: float) -> int:
    return max(0, math.ceil(neighbourhood_m / resolution - 1e-9))


class DynamicMapper:
    """The two grids of Sec. 3: each scan, seen from a pose, is classified against S^{t-1}
    and updates S (Eq. 12, Table 1) and D (Eq. 13, Table 2)."""

    def __init__(self, m: MapConfig, laser: LaserConfig, d: DynamicConfig,
                 changes: ChangeConfig | None = None, keep_dynamic: bool = True) -> None:
        """``changes``: record the evidence of change events by these settings (None or
        disabled: not); ``keep_dynamic`` False: S only (D is made again at the end)."""
        self._map = m
        self._laser = laser
        self._keep_dynamic = keep_dynamic
        self._radius = radius_cells(d.neighbourhood_m, m.resolution_m) if d.enabled else 0
        layers = ("static", "dynamic") if keep_dynamic else ("static",)
        self.grids = GridStack(m.resolution_m, m.grow_margin_m, layers,
                               pad_cells=self._radius, max_extent_m=m.max_extent_m)
        static_model = InverseModel.from_probabilities(m.p_hit, m.p_miss, m.p_clamp_min,
                                                       m.p_clamp_max)
        self._static = static_model
        self._dynamic = InverseModel.from_probabilities(d.p_high, d.p_low, d.p_clamp_min,
                                                        d.p_clamp_max)
        if d.enabled:
            self._table_1 = static_model.table(TABLE_1)
            self._table_2 = self._dynamic.table(TABLE_2)
        else:  # an ordinary grid: every hit raises S, D is never touched
            self._table_1 = static_model.table({k: "high" if k[1] == OCCUPIED else "low"
                                                for k in TABLE_1})
            self._table_2 = None
        self._remember_free = d.enabled and d.remember_free
        if self._remember_free:
            self.grids.add_layer(ONCE_FREE, np.uint8)
        self._surfaces = (Surfaces(self.grids, d.surface_m, self._radius, laser.min_range_m,
                                   d.surface_beams)
                          if d.enabled and d.surface_m > 0 and self._radius > 0 else None)
        self.changes = (ChangeRecorder(changes, m, self.grids)
                        if changes is not None and changes.enabled and d.enabled else None)
        """The evidence of change events, if asked for (S/D separation only)."""
        self._free_rows_uniform = all(np.ptp(t[:, 0]) == 0 for t in (self._table_1,
                                                                      self._table_2)
                                      if t is not None)

    def integrate(self, pose: Pose2D, scan: Scan) -> None:
        """One scan from the robot's pose ``pose`` (map frame)."""
        seen = observation = self.observe(pose, scan)
        free_prev, hit_prev = self.classify_against_static_map(observation)
        if self._surfaces is not None:
            hit_prev, lone = self.off_the_surface(pose, scan, observation, hit_prev)
            static = (hit_prev != FREE) & ~lone
            if lone.any():  # no evidence either way
                observation = Observation(observation.free, observation.hit[~lone])
                hit_prev = hit_prev[~lone]
        if self.changes is not None:
            self.changes.record(scan.stamp, observation, hit_prev == FREE)
        if self._remember_free:
            self.note_free(observation)
        self.update_static_map(observation, free_prev, hit_prev)
        self.update_dynamic_map(observation, free_prev, hit_prev)
        if self._surfaces is not None:
            self._surfaces.learn(seen, static)

    def classify_landmarks(self, positions: np.ndarray) -> list[str]:
        """Table 3: each landmark's class ("static" or "dynamic") by the state of S^{t-1}
        around it (neighbourhood rule). Without S/D separation every landmark is static."""
        if self._table_2 is None or len(positions) == 0:
            return [TABLE_3[OCCUPIED]] * len(positions)
        m = self._map
        rows, cols = self.grids.world_cells_of(positions[:, 0], positions[:, 1])
        states = self.grids.classify_world_cells("static", rows, cols, self._radius,
                                                 logit(m.free_threshold),
                                                 logit(m.occupied_threshold))
        return [TABLE_3[int(s)] for s in states]

    def observe(self, pose: Pose2D, scan: Scan) -> Observation:
        """Cells the scan saw free and cells it hit, from the laser's pose in the map."""
        laser = self._laser
        return self.grids.observe(compose(pose, scan.laser), scan.ranges, scan.angles,
                                  scan.max_range, laser.min_range_m, laser.clear_cap_m)

    def off_the_surface(self, pose: Pose2D, scan: Scan, obs: Observation,
                        hit_prev: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``hit_prev``, but Free for a hit cell that S holds firmly Free (halfway in log-odds
        from the Free threshold to its floor) while the window around it says Occupied,
        or Unknown only for the strip in front of a wall that no beam passed
        (:func:`unknown_only_beside_walls`), where most of its end points lie off the
        surfaces around it (dynslam_cli.mapping.surfaces): something stands where the robot
        saw nothing, next to a wall but not on it. Next to the edge of what the robot has
        seen the window's Unknown stands (the paper's "static until seen to move").
        And which of those cells no beam beside one of their end points saw where S was
        seen free too (``[dynamic] surface_beams``): a lone end point off the surfaces,
        which tells neither map anything (a beam's edge on a chair leg is not an object, and
        not the wall's either; nor is the first view of a face beside cells still Unknown)."""
        m = self._map
        stored = self.grids.layers["static"].reshape(-1)[obs.hit]
        own = classify_static(stored, m.free_threshold, m.occupied_threshold)
        firm = stored <= (logit(m.free_threshold) + logit(m.p_clamp_min)) / 2 / LOGODDS_STEP
        doubt = firm & (hit_prev == OCCUPIED)
        shadow = firm & (hit_prev == UNKNOWN)
        if shadow.any():
            shadow[shadow] = unknown_only_beside_walls(self.grids, obs.hit[shadow],
                                                      self._radius, m.free_threshold,
                                                      m.occupied_threshold)
        freed = self._surfaces.off_surfaces(
            compose(pose, scan.laser), scan, obs, doubt | shadow, own == OCCUPIED,
            logit(m.free_threshold) / LOGODDS_STEP)
        out = hit_prev.copy()
        out[freed] = FREE
        return out, self._surfaces.lone(out == FREE) & freed

    def classify_against_static_map(self, obs: Observation) -> tuple[np.ndarray, np.ndarray]:
        """State of S^{t-1} (Free/Unknown/Occupied) at the cells seen free, and over the
        neighbourhood of each cell hit (Sec. 5)."""
        if self._table_2 is None:  # an ordinary grid: the state does not matter
            return (np.zeros(len(obs.free), np.int8), np.zeros(len(obs.hit), np.int8))
        m = self._map
        s = self.grids.layers["static"].reshape(-1)
        if self._free_rows_uniform:  # Tables 1 and 2 give "low" whatever S^{t-1} was
            free_prev = np.zeros(len(obs.free), np.int8)
        else:
            free_prev = classify_static(s[obs.free], m.free_threshold, m.occupied_threshold)
        hit_prev = classify_neighbourhood(self.grids, obs.hit, self._radius,
                                          m.free_threshold, m.occupied_threshold)
        if self._remember_free:
            unknown = np.flatnonzero(hit_prev == UNKNOWN)
            known = known_free_windows(self.grids, obs.hit[unknown], self._radius,
                                       m.free_threshold)
            hit_prev[unknown[known]] = FREE
        return free_prev, hit_prev

    def note_free(self, obs: Observation) -> None:
        """Remember the cells of a scan that S^{t-1} holds Free (S changes only where a scan
        reaches, so these notes, with S now, say which cells were ever Free)."""
        static, once = self.grids.layers["static"], self.grids.layers[ONCE_FREE]
        low = logit(self._map.free_threshold)
        for cells in (obs.free, obs.hit):
            once[cells[static[cells] * LOGODDS_STEP < low]] = 1

    def update_static_map(self, obs: Observation, free_prev: np.ndarray,
                          hit_prev: np.ndarray) -> None:
        """Eq. 12 with Table 1 as the inverse sensor model."""
        _apply_inverse_model(self.grids.layers["static"], obs, free_prev, hit_prev,
                             self._table_1, self._static)

    def update_dynamic_map(self, obs: Observation, free_prev: np.ndarray,
                           hit_prev: np.ndarray) -> None:
        """Eq. 13 with Table 2 as the inverse sensor model."""
        if self._table_2 is not None and self._keep_dynamic:
            _apply_inverse_model(self.grids.layers["dynamic"], obs, free_prev, hit_prev,
                                 self._table_2, self._dynamic)


def _apply_inverse_model(layer: np.ndarray, obs: Observation, free_prev: np.ndarray,
                         hit_prev: np.ndarray, table: np.ndarray, model: InverseModel) -> None:
    """Add the table's log-odds (indexed [S^{t-1} state, o^t]) to the observed cells, clamped
    to the model's range; in the layer's steps, so the sums are exact."""
    flat = layer.reshape(-1)
    lo, hi = model.clamp_steps
    _grid.add_clamped(flat, obs.free, free_prev, table[:, 0], lo, hi)
    _grid.add_clamped(flat, obs.hit, hit_prev, table[:, 1], lo, hi)
