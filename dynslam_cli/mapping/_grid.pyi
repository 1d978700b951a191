"""Type signatures of mapping/_grid.pyx (documented there)."""

import numpy as np

def beam_extent(sx: float, sy: float, sth: float, ranges: np.ndarray, angles: np.ndarray,
                min_range: float, max_range: float, cap: float
                ) -> tuple[float, float, float, float]: ...
TILE_SIDE: int
LOGODDS_STEP: float

def trace_beams(listed: np.ndarray, mark: int, table: np.ndarray, tr0: int, tc0: int,
                tcols: int, tile_row: np.ndarray, tile_col: np.ndarray, count: int,
                res: float, row0: int, col0: int, sx: float, sy: float, sth: float,
                ranges: np.ndarray, angles: np.ndarray, min_range: float, max_range: float,
                cap: float) -> tuple[np.ndarray | None, np.ndarray | None, int]: ...
def classify_cells(logodds: np.ndarray, cells: np.ndarray, radius: int, table: np.ndarray,
                   tr0: int, tc0: int, tcols: int, tile_row: np.ndarray, tile_col: np.ndarray,
                   count: int, low: float, high: float) -> np.ndarray: ...
def classify_world_cells(logodds: np.ndarray, rows: np.ndarray, cols: np.ndarray, radius: int,
                         table: np.ndarray, tr0: int, tc0: int, tcols: int,
                         tile_row: np.ndarray, tile_col: np.ndarray, count: int, low: float,
                         high: float) -> np.ndarray: ...
def add_clamped(logodds: np.ndarray, cells: np.ndarray, states: np.ndarray,
                value: np.ndarray, lo: int, hi: int) -> None: ...
def cells_above(logodds: np.ndarray, cells: np.ndarray, threshold: int,
                above: bool = True) -> np.ndarray: ...
