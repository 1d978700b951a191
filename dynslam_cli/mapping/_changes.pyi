"""Type signatures of mapping/_changes.pyx (documented there)."""

import numpy as np

def scan_blobs(xy: np.ndarray, gap: float, scan: float) -> np.ndarray: ...
def link_tracks(blobs: np.ndarray, stamps: np.ndarray, gate: float,
                gap_s: float) -> np.ndarray: ...
