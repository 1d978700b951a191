"""Type signatures of localization/_corners.pyx (documented there)."""

import numpy as np

def split_runs(p: np.ndarray, lo: int, hi: int, tol: float) -> list[tuple[int, int]]: ...
def detect_corners(ranges: np.ndarray, angles: np.ndarray, limit: float, jump_m: float,
                   jump_ratio: float, tol: float, min_points: int, min_length: float,
                   max_rms: float, cos_max: float, max_gap: float,
                   max_beams_between: int) -> list[tuple[float, float, bool]]: ...
