"""A picture of S ∪ D: static map in grey levels (dark = occupied, grey = unknown), dynamic
cells in red, the trajectory in blue, landmarks as small squares (static green, dynamic
orange)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image, ImageDraw

from dynslam_cli.mapping.grid import OccupancyMap
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
    render(static, dynamic, trajectory, landmarks, occupied_thresh).save(
        path, optimize=False, compress_level=1)  # a third of the default's time


class SnapshotWriter:
    """The S ∪ D picture every so many seconds of log time (``snapshots/t000123.4.png``), and
    at the end an animated GIF of them all on one canvas (``snapshots/evolution.gif``), like
    the rows of the paper's Figs. 2 and 4."""

    def __init__(self, folder: Path, every_s: float, config: Any) -> None:
        self.folder = folder
        self.every = every_s
        self.threshold = config.map.occupied_threshold
        self.next: float | None = None
        self.frames: list[tuple[Path, float, float, int, int]] = []
        folder.mkdir()

    def maybe_take(self, stamp: float, slam: Any) -> None:
        if self.next is None:
            self.next = stamp
        if stamp < self.next:
            return
        self.next = stamp + self.every
        self._take(stamp, slam.current())

    def _take(self, stamp: float, result: Any) -> None:
        s = result.static
        path = self.folder / f"t{stamp:012.3f}.png"
        render(s, result.dynamic, result.trajectory, result.landmarks, self.threshold).save(path)
        h, w = s.prob.shape
        self.frames.append((path, s.origin_x, s.origin_y, w, h))

    def finish(self, result: Any) -> None:
        """Add the final state and write the GIF, every frame placed on the final canvas."""
        if result.trajectory.size:
            self._take(float(result.trajectory[-1, 0]), result)
        if not self.frames:
            return
        res = result.static.resolution
        x0 = min(f[1] for f in self.frames)
        y0 = min(f[2] for f in self.frames)
        x1 = max(f[1] + f[3] * res for f in self.frames)
        y1 = max(f[2] + f[4] * res for f in self.frames)
        size = (round((x1 - x0) / res), round((y1 - y0) / res))
        scale = min(1.0, 800 / max(size))

        def frames() -> Any:
            for path, ox, oy, _w, h in self.frames:
                canvas = Image.new("RGB", size, (128, 128, 128))
                with Image.open(path) as im:
                    canvas.paste(im, (round((ox - x0) / res), round((y1 - (oy + h * res)) / res)))
                if scale < 1.0:
                    canvas = canvas.resize((max(1, round(size[0] * scale)),
                                            max(1, round(size[1] * scale))), Image.NEAREST)
                yield canvas

        it = frames()
        first = next(it)
        first.save(self.folder / "evolution.gif", save_all=True, append_images=it,
                   duration=500, loop=0)
