"""A picture of S ∪ D: static map in grey levels (dark = occupied, grey = unknown), dynamic
cells in red, the trajectory in blue, landmarks as small squares (static green, dynamic
orange)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

from dynslam_cli.grid import OccupancyMap
from dynslam_cli.pipeline import Landmark

DYNAMIC_RGB = (220, 30, 30)
TRAJECTORY_RGB = (40, 90, 230)
LANDMARK_RGB = {"static": (20, 160, 60), "dynamic": (255, 140, 0)}


def render(static: OccupancyMap, dynamic: OccupancyMap, trajectory: np.ndarray,
           landmarks: Sequence[Landmark], occupied_thresh: float) -> Image.Image:
    """The S ∪ D picture, one pixel per cell, north up."""
    grey = np.rint(255.0 * (1.0 - static.prob)).astype(np.uint8)
    rgb = np.repeat(grey[:, :, None], 3, axis=2)
    rgb[dynamic.prob > occupied_thresh] = DYNAMIC_RGB
    image = Image.fromarray(np.ascontiguousarray(rgb[::-1]), mode="RGB")
    draw = ImageDraw.Draw(image)
    height, res = static.prob.shape[0], static.resolution

    def pixel(x: float, y: float) -> tuple[float, float]:
        return (x - static.origin_x) / res, height - (y - static.origin_y) / res

    if len(trajectory) > 1:
        draw.line([pixel(x, y) for x, y in trajectory[:, 1:3]], fill=TRAJECTORY_RGB, width=1)
    for lm in landmarks:
        u, v = pixel(lm.x, lm.y)
        draw.rectangle((u - 1, v - 1, u + 1, v + 1), outline=LANDMARK_RGB[lm.cls])
    return image


def write_picture(path: Path, static: OccupancyMap, dynamic: OccupancyMap,
                  trajectory: np.ndarray, landmarks: Sequence[Landmark],
                  occupied_thresh: float) -> None:
    render(static, dynamic, trajectory, landmarks, occupied_thresh).save(path, optimize=False)
