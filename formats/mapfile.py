"""Occupancy maps as map_server / nav2 files.

``NAME.pgm`` + ``NAME.yaml`` are what ``map_saver`` writes in its default ``trinary`` mode: 8-bit
P5, ``negate: 0``, occupied 0, unknown 205, free 254, first image row = top (largest y),
``origin`` = pose of the lower-left pixel. Each cell's class is dynslam's (Free below the
configured free threshold, Occupied above the occupied one); the YAML's thresholds (0.1 /
0.9) sort the three pixel values back into those classes under the loading rules of nav2's
``map_io`` and ROS 1's ``map_server`` alike, so a planner sees unknown space as unknown.

``NAME_prob.png`` + ``NAME_prob.yaml`` keep the probabilities: ``mode: scale``, grey v means
p = (255 − v)/255, and alpha 0 (transparent) where the cell is Unknown — the only way scale
mode marks a cell unknown. Free and Occupied pixels are nudged (by at most one grey level) to
the right side of the thresholds, so both files load to the same classes.
"""

from __future__ import annotations

import math
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image

from dynslam_cli.errors import InputError
from dynslam_cli.mapping.grid import OccupancyMap
from dynslam_formats.png import PgmWriter, PngWriter

FREE_PIXEL, UNKNOWN_PIXEL, OCCUPIED_PIXEL = 254, 205, 0
TRINARY_FREE_THRESH, TRINARY_OCCUPIED_THRESH = 0.1, 0.9  # 254 → 0.004, 205 → 0.196, 0 → 1


def to_pixels(prob: np.ndarray) -> np.ndarray:
    """Probabilities (row 0 = lowest y) → grey values p = (255 − v)/255 (row 0 = top)."""
    return np.rint(255.0 * (1.0 - np.clip(prob, 0.0, 1.0))).astype(np.uint8)[::-1]


def from_pixels(pixels: np.ndarray) -> np.ndarray:
    """Grey values (row 0 = top) → probabilities (row 0 = lowest y)."""
    return ((255.0 - pixels.astype(np.float64)) / 255.0)[::-1]


def class_masks(prob: np.ndarray, free_thresh: float, occupied_thresh: float
                ) -> tuple[np.ndarray, np.ndarray]:
    """Masks of Free and Occupied cells (the rest is Unknown), rows as in ``prob``."""
    return prob < free_thresh, prob > occupied_thresh


def classes(prob: np.ndarray, free_thresh: float, occupied_thresh: float
            ) -> tuple[np.ndarray, np.ndarray]:
    """:func:`class_masks` in image rows (row 0 = top)."""
    return class_masks(prob[::-1], free_thresh, occupied_thresh)


def trinary_pixels(free: np.ndarray, occupied: np.ndarray) -> np.ndarray:
    """The map_saver picture of the class masks: 254 Free, 205 Unknown, 0 Occupied."""
    pixels = np.full(free.shape, UNKNOWN_PIXEL, dtype=np.uint8)
    pixels[free] = FREE_PIXEL
    pixels[occupied] = OCCUPIED_PIXEL
    return pixels


def scale_pixels(prob: np.ndarray, free: np.ndarray, occupied: np.ndarray, free_thresh: float,
                 occupied_thresh: float) -> np.ndarray:
    """Grey + alpha (row 0 = top): grey the probability, transparent where Unknown (the class
    masks as :func:`classes` gives them); grey of known cells kept strictly on their side of
    the thresholds after rounding."""
    grey = to_pixels(prob)
    lightest_occupied = math.ceil(255.0 * (1.0 - occupied_thresh)) - 1
    darkest_free = math.floor(255.0 * (1.0 - free_thresh)) + 1
    grey[occupied] = np.minimum(grey[occupied], lightest_occupied)
    grey[free] = np.maximum(grey[free], darkest_free)
    alpha = np.where(free | occupied, 255, 0).astype(np.uint8)
    return np.dstack([grey, alpha])


def _yaml(image: str, mode: str, grid: OccupancyMap, free: float, occupied: float) -> str:
    return (f"image: {image}\n"
            f"mode: {mode}\n"
            f"resolution: {grid.resolution:.6f}\n"
            f"origin: [{grid.origin_x:.6f}, {grid.origin_y:.6f}, 0.000000]\n"
            f"negate: 0\n"
            f"occupied_thresh: {occupied:g}\n"
            f"free_thresh: {free:g}\n")


def write_map(folder: Path, name: str, grid: OccupancyMap, free_thresh: float,
              occupied_thresh: float, probabilities: bool = False) -> None:
    """Write ``folder/name.pgm`` + ``name.yaml`` (trinary), and with ``probabilities`` also
    ``name_prob.png`` + ``name_prob.yaml`` (scale, alpha = unknown)."""
    rows, cols = grid.shape
    with ExitStack() as files:  # one pass over the map, a band of rows at a time
        pgm = PgmWriter(files.enter_context(open(folder / f"{name}.pgm", "wb")), cols, rows)
        png = (PngWriter(files.enter_context(open(folder / f"{name}_prob.png", "wb")), cols,
                         rows, channels=2) if probabilities else None)
        for _, prob in grid.bands(from_top=True):
            free, occupied = classes(prob, free_thresh, occupied_thresh)
            pgm.add(trinary_pixels(free, occupied))
            if png is not None:
                png.add(scale_pixels(prob, free, occupied, free_thresh, occupied_thresh))
        if png is not None:
            png.finish()
    (folder / f"{name}.yaml").write_text(
        _yaml(f"{name}.pgm", "trinary", grid, TRINARY_FREE_THRESH, TRINARY_OCCUPIED_THRESH),
        encoding="utf-8")
    if probabilities:
        (folder / f"{name}_prob.yaml").write_text(
            _yaml(f"{name}_prob.png", "scale", grid, free_thresh, occupied_thresh),
            encoding="utf-8")


@dataclass(frozen=True)
class MapFile:
    """A map read back: the grid and the thresholds its YAML declares."""

    grid: OccupancyMap
    free_thresh: float
    occupied_thresh: float


def read_map(yaml_path: Path) -> MapFile:
    """Read a map written by :func:`write_map` (flat ``key: value`` YAML, trinary or scale
    mode; in a trinary map every cell's probability is its class's pixel value)."""
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
        mode = meta.get("mode", "trinary")
    except (KeyError, ValueError) as e:
        raise InputError(str(yaml_path), f"missing or malformed map field: {e}") from None
    if negate:
        raise InputError(str(yaml_path), "negate: 1 maps are not supported")
    if mode not in ("trinary", "scale"):
        raise InputError(str(yaml_path), f"mode: {mode} maps are not supported")
    try:
        with Image.open(image) as im:
            pixels = np.asarray(im.convert("L"))
    except OSError as e:
        raise InputError(str(image), f"cannot read map image: {e}") from None
    grid = OccupancyMap(prob=from_pixels(pixels), resolution=resolution, origin_x=origin[0],
                        origin_y=origin[1])
    return MapFile(grid=grid, free_thresh=free, occupied_thresh=occ)
