"""Type signatures of mapping/_changes.pyx (documented there)."""

import numpy as np

def scan_blobs(cells: np.ndarray, tile_rows: np.ndarray, tile_cols: np.ndarray, side: int,
               res: float, gap: float, scan: float) -> np.ndarray: ...
def link_tracks(blobs: np.ndarray, stamps: np.ndarray, gate: float,
                gap_s: float) -> np.ndarray: ...
