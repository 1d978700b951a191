"""Occupancy maps as map_server / nav2 files: ``NAME.pgm`` (8-bit P5) + ``NAME.yaml``.

``mode: scale``, ``negate: 0``: a pixel value v means occupancy p = (255 − v)/255, first
image row = top (largest y), ``origin`` = pose of the lower-left pixel. The thresholds written
are the ones dynslam classifies cells with (Free below ``free_thresh``, Occupied above
``occupied_thresh``), so a map_server loader agrees with the tool.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image

from dynslam_cli.errors import InputError
from dynslam_cli.mapping.grid import OccupancyMap


def to_pixels(prob: np.ndarray) -> np.ndarray:
    """Probabilities (row 0 = lowest y) → PGM pixel values (row 0 = top)."""
    return np.rint(255.0 * (1.0 - np.clip(prob, 0.0, 1.0))).astype(np.uint8)[::-1]


def from_pixels(pixels: np.ndarray) -> np.ndarray:
    """PGM pixel values (row 0 = top) → probabilities (row 0 = lowest y)."""
    return ((255.0 - pixels.astype(np.float64)) / 255.0)[::-1]


def write_map(folder: Path, name: str, grid: OccupancyMap, free_thresh: float,
              occupied_thresh: float) -> None:
    """Write ``folder/name.pgm`` and ``folder/name.yaml``."""
    Image.fromarray(to_pixels(grid.prob), mode="L").save(folder / f"{name}.pgm")
    (folder / f"{name}.yaml").write_text(
        f"image: {name}.pgm\n"
        f"mode: scale\n"
        f"resolution: {grid.resolution:.6f}\n"
        f"origin: [{grid.origin_x:.6f}, {grid.origin_y:.6f}, 0.000000]\n"
        f"negate: 0\n"
        f"occupied_thresh: {occupied_thresh:g}\n"
        f"free_thresh: {free_thresh:g}\n",
        encoding="utf-8")


@dataclass(frozen=True)
class MapFile:
    """A map read back: the grid and the thresholds its YAML declares."""

    grid: OccupancyMap
    free_thresh: float
    occupied_thresh: float


def read_map(yaml_path: Path) -> MapFile:
    """Read a map written by :func:`write_map` (flat ``key: value`` YAML, scale mode)."""
    yaml_path = Path(yaml_path)
    try:
        text = yaml_path.read_text(encoding="utf-8")
    except OSError as e:
        raise InputError(str(yaml_path), f"cannot read: {e.strerror}") from None
    meta: dict[str, str] = {}
    for lineno, line in enumerate(text.splitlines(), 1):
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        key, sep, value = line.partition(":")
        if not sep:
            raise InputError(str(yaml_path), "expected 'key: value'", lineno)
        meta[key.strip()] = value.strip()
    try:
        origin = [float(v) for v in meta["origin"].strip("[]").split(",")]
        resolution = float(meta["resolution"])
        free, occ = float(meta["free_thresh"]), float(meta["occupied_thresh"])
        image = yaml_path.parent / meta["image"]
        negate = int(meta.get("negate", "0"))
    except (KeyError, ValueError) as e:
        raise InputError(str(yaml_path), f"missing or malformed map field: {e}") from None
    if negate:
        raise InputError(str(yaml_path), "negate: 1 maps are not supported")
    try:
        with Image.open(image) as im:
            pixels = np.asarray(im.convert("L"))
    except OSError as e:
        raise InputError(str(image), f"cannot read map image: {e}") from None
    grid = OccupancyMap(prob=from_pixels(pixels), resolution=resolution, origin_x=origin[0],
                        origin_y=origin[1])
    return MapFile(grid=grid, free_thresh=free, occupied_thresh=occ)
