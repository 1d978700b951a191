"""Type signatures of localization/_loops.pyx (documented there)."""

import numpy as np

def splat_max(grid: np.ndarray, rows: np.ndarray, cols: np.ndarray,
              kernel: np.ndarray) -> None: ...
def lattice_scores(grid: np.ndarray, dr: np.ndarray, dc: np.ndarray, th: np.ndarray,
                   col: np.ndarray, row: np.ndarray) -> np.ndarray: ...
def mean_scores(grid: np.ndarray, ox: float, oy: float, res: float, pts: np.ndarray,
                x: float, y: float, thetas: np.ndarray, tx: np.ndarray,
                ty: np.ndarray, bilinear: bool = False) -> np.ndarray: ...
def spline_mean(coef: np.ndarray, pts: np.ndarray, x: float, y: float, theta: float,
                ox: float, oy: float, res: float) -> tuple[float, float, float, float]: ...
def spline_climb(coef: np.ndarray, pts: np.ndarray, sx: float, sy: float, sth: float,
                 gx: float, gy: float, gth: float, ox: float, oy: float, res: float,
                 kappa: float, wx: float, wy: float, wth: float, iterations: int,
                 step_m: float, step_rad: float) -> tuple[float, float, float]: ...
def shortest_paths(head: np.ndarray, nxt: np.ndarray, to: np.ndarray, length: np.ndarray,
                   n: int, sources: np.ndarray, limit: float,
                   max_nodes: int, targets: np.ndarray) -> np.ndarray: ...
