"""Type signatures of mapping/_grid.pyx (documented there)."""

import numpy as np

def beam_extent(sx: float, sy: float, sth: float, ranges: np.ndarray, angles: np.ndarray,
                min_range: float, max_range: float, cap: float
                ) -> tuple[float, float, float, float]: ...
def trace_beams(seen: np.ndarray, listed: np.ndarray, mark: int, cols: int, res: float,
                row0: int, col0: int, sx: float, sy: float, sth: float, ranges: np.ndarray,
                angles: np.ndarray, min_range: float, max_range: float, cap: float
                ) -> tuple[np.ndarray, np.ndarray]: ...
def classify_cells(logodds: np.ndarray, cells: np.ndarray, offsets: np.ndarray, low: float,
                   high: float) -> np.ndarray: ...
def add_clamped(logodds: np.ndarray, cells: np.ndarray, states: np.ndarray,
                value: np.ndarray, lo: float, hi: float) -> None: ...
