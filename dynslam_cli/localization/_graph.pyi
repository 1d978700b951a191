"""Type signatures of localization/_graph.pyx (documented there)."""

import numpy as np

def minimum_degree(n: int, ei: np.ndarray, ej: np.ndarray) -> tuple[np.ndarray, float]: ...
def solve_spd(indptr: np.ndarray, indices: np.ndarray, data: np.ndarray, perm: np.ndarray,
              rhs: np.ndarray) -> np.ndarray: ...
def conjugate_gradients(indptr: np.ndarray, indices: np.ndarray, data: np.ndarray,
                        inverse: np.ndarray, rhs: np.ndarray, tolerance: float,
                        max_steps: int) -> np.ndarray: ...
