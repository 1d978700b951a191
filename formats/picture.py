"""A picture of S ∪ D: static map in grey levels (dark = occupied, grey = unknown), dynamic
cells in red, the trajectory in blue, landmarks as small squares (static green, dynamic
orange), change events as numbered circles (appeared magenta, vacated cyan, moving
violet; their rows in changes.csv). ``map.png`` shows the part with walls, path or
upscaled by whole pixels per cell when small, with metre ticks in the map frame, a scale bar
and a legend; the snapshots are the plain grid, one pixel per cell."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from dynslam_cli.mapping.changes import ChangeEvent
from dynslam_cli.mapping.grid import BAND_ROWS, OccupancyMap
from dynslam_cli.result import Landmark

DYNAMIC_RGB = (220, 30, 30)
TRAJECTORY_RGB = (40, 90, 230)
LANDMARK_RGB = {"static": (20, 160, 60), "dynamic": (255, 140, 0)}
CHANGE_RGB = {"appeared": (230, 0, 200), "vacated": (0, 170, 200), "moving": (120, 60, 200)}
PAPER_RGB = (255, 255, 255)
INK_RGB = (0, 0, 0)

MIN_PICTURE_PX = 800  # map.png is upscaled (whole pixels per cell) to at least this size
MAX_UPSCALE = 8
MAX_PICTURE_PX = 4096  # and shrunk (whole cells per pixel) to at most this size
WALL_QUANTILE = 0.005
MARGIN_M = 1.0  # map.png shows the walls, path and landmarks with this much around them
NICE_STEPS_M = (0.5, 1, 2, 5, 10, 20, 50, 100, 200, 500, 1000, 2000, 5000)


def render(static: OccupancyMap, dynamic: OccupancyMap, trajectory: np.ndarray,
           landmarks: Sequence[Landmark], occupied_thresh: float,
           window: tuple[int, int, int, int] | None = None, scale: int = 1,
           shrink: int = 1, into: tuple[Image.Image, int, int] | None = None,
           changes: Sequence[ChangeEvent] = ()) -> Image.Image:
    """The S ∪ D picture, north up: ``window`` (col0, row0, col1, row1, cells; default the
    whole grid), ``scale`` pixels per cell, or one pixel per ``shrink`` × ``shrink`` cells
    (the darkest of them, red if any is dynamic: walls and movers stay visible); the path
    and landmarks drawn at that scale. Drawn on a new image, or ``into`` (image, left, top)
    an existing one at that place (a frame: no second copy of a large picture); the
    ``changes`` drawn numbered."""
    rows, cols = static.shape
    c0, r0, c1, r1 = window = window or (0, 0, cols, rows)
    k = shrink
    height = picture_size(window, 1, k)[1]  # (in shrunk cells)
    if into is None:
        into = (Image.new("RGB", picture_size(window, scale, k)), 0, 0)
    image, left, top = into
    step = BAND_ROWS - BAND_ROWS % k
    for first in range(r0, r1, step):  # a band of rows at a time: the map is never held whole
        last = min(first + step, r1)
        grey = np.rint(255.0 * (1.0 - static.band(first, last)[:, c0:c1])).astype(np.uint8)
        moving = dynamic.band(first, last)[:, c0:c1] > occupied_thresh
        if k > 1:
            grey, moving = _block(grey, k, 255, np.minimum), _block(moving, k, False, np.maximum)
        rgb = np.repeat(grey[::-1, :, None], 3, axis=2)  # (image rows run from the top)
        rgb[moving[::-1]] = DYNAMIC_RGB
        band = Image.fromarray(rgb, mode="RGB")
        if scale > 1:
            band = band.resize((band.width * scale, band.height * scale), Image.NEAREST)
        image.paste(band, (left, top + (height - (first - r0) // k - len(grey)) * scale))
    draw = ImageDraw.Draw(image)
    res = static.resolution
    px_per_cell = scale / k

    def pixel(x: float, y: float) -> tuple[float, float]:
        return (left + ((x - static.origin_x) / res - c0) * px_per_cell,
                top + (r0 + height * k - (y - static.origin_y) / res) * px_per_cell)

    if len(trajectory) > 1:
        draw.line([pixel(x, y) for x, y in trajectory[:, 1:3]], fill=TRAJECTORY_RGB,
                  width=max(1, scale // 2))
    half = max(1, scale)
    for lm in landmarks:
        u, v = pixel(lm.x, lm.y)
        draw.rectangle((u - half, v - half, u + half, v + half), outline=LANDMARK_RGB[lm.cls])
    font = ImageFont.load_default()
    for e in changes:
        u, v = pixel(e.x, e.y)
        r = max(3.0, math.sqrt(e.size_m2) / 2 / res * px_per_cell + 2)
        draw.ellipse((u - r, v - r, u + r, v + r), outline=CHANGE_RGB[e.kind], width=2)
        draw.text((u + r + 1, v - r), str(e.id), fill=CHANGE_RGB[e.kind], font=font,
                  anchor="lb")
    return image


def picture_size(window: tuple[int, int, int, int], scale: int, shrink: int
                 ) -> tuple[int, int]:
    """(width, height) in pixels of the picture of ``window`` at ``scale`` pixels per cell
    or ``shrink`` cells per pixel (a partial block of cells makes a whole pixel)."""
    c0, r0, c1, r1 = window
    return -(-(c1 - c0) // shrink) * scale, -(-(r1 - r0) // shrink) * scale


def _block(a: np.ndarray, k: int, fill: Any, reduce: Any) -> np.ndarray:
    """``a`` reduced over k × k blocks (padded with ``fill`` to whole blocks)."""
    h, w = -(-a.shape[0] // k) * k, -(-a.shape[1] // k) * k
    padded = np.full((h, w), fill, a.dtype)
    padded[:a.shape[0], :a.shape[1]] = a
    return reduce.reduce(reduce.reduce(padded.reshape(h // k, k, w // k, k), axis=3), axis=1)


def content_window(static: OccupancyMap, trajectory: np.ndarray, landmarks: Sequence[Landmark],
                   occupied_thresh: float, margin_m: float = MARGIN_M
                   ) -> tuple[int, int, int, int]:
    """Cells (col0, row0, col1, row1) around the walls, the path and the landmarks: free
    space cleared only by long no-return beams far beyond the walls is left out, and so are
    the farthest ``WALL_QUANTILE`` of occupied cells on each side (stray far readings)."""
    rows, cols = static.shape
    found = [(r0 + r, c) for r0, band in static.bands()
             for r, c in [np.nonzero(band > occupied_thresh)]]
    occ_r = np.concatenate([r for r, _ in found]) if found else np.zeros(0, np.intp)
    occ_c = np.concatenate([c for _, c in found]) if found else np.zeros(0, np.intp)
    if len(occ_r):
        occ_r = np.quantile(occ_r, [WALL_QUANTILE, 1 - WALL_QUANTILE])
        occ_c = np.quantile(occ_c, [WALL_QUANTILE, 1 - WALL_QUANTILE])
    res = static.resolution
    xs = [occ_c.astype(float), trajectory[:, 1:2].ravel() / res - static.origin_x / res,
          np.array([(lm.x - static.origin_x) / res for lm in landmarks])]
    ys = [occ_r.astype(float), trajectory[:, 2:3].ravel() / res - static.origin_y / res,
          np.array([(lm.y - static.origin_y) / res for lm in landmarks])]
    x, y = np.concatenate(xs), np.concatenate(ys)
    if not len(x):
        return 0, 0, cols, rows
    m = margin_m / res
    return (max(0, int(x.min() - m)), max(0, int(y.min() - m)),
            min(cols, math.ceil(x.max() + m) + 1), min(rows, math.ceil(y.max() + m) + 1))


def _nice_step(span_m: float, wanted: int = 6) -> float:
    """A round tick spacing giving about ``wanted`` ticks over ``span_m``."""
    return next((s for s in NICE_STEPS_M if span_m / s <= wanted), NICE_STEPS_M[-1])


def _metres(v: float) -> str:
    return f"{v:g} m"


LEGEND = [((0, 0, 0), "static S (occupied)"), ((255, 255, 255), "free"),
          ((128, 128, 128), "unknown"), (DYNAMIC_RGB, "dynamic D"),
          (TRAJECTORY_RGB, "trajectory"), (LANDMARK_RGB["static"], "static landmark"),
          (LANDMARK_RGB["dynamic"], "dynamic landmark"),
          *((rgb, f"{kind} (changes.csv)") for kind, rgb in CHANGE_RGB.items())]


def frame(static: OccupancyMap, window: tuple[int, int, int, int], size: tuple[int, int],
          scale: float) -> tuple[Image.Image, int, int]:
    """The frame of a picture of ``size`` pixels showing ``window`` at ``scale`` pixels per
    cell: metre ticks (map frame) on the left and bottom, a scale bar and a legend below.
    Returns the canvas and where the picture goes in it (left, top)."""
    font = ImageFont.load_default()
    res = static.resolution
    c0, r0, c1, r1 = window
    left, top, right = 56, 10, 16
    w, h = size
    width = left + w + right
    legend, u, y = [], left, top + h + 46  # the legend's entries, wrapped to the width
    for colour, label in LEGEND:
        length = font.getlength(label)
        if u + 16 + length > width - right and u > left:
            u, y = left, y + 16
        legend.append((u, y, colour, label))
        u += int(14 + length + 14)
    canvas = Image.new("RGB", (width, y + 18), PAPER_RGB)
    draw = ImageDraw.Draw(canvas)
    draw.rectangle((left - 1, top - 1, left + w, top + h), outline=INK_RGB)
    px_per_m = scale / res
    x0, x1 = static.origin_x + c0 * res, static.origin_x + c1 * res
    y0, y1 = static.origin_y + r0 * res, static.origin_y + r1 * res
    step = _nice_step(min(x1 - x0, y1 - y0), wanted=4)
    while step * px_per_m < 44 and step < NICE_STEPS_M[-1]:  # labels must not overlap
        step = NICE_STEPS_M[NICE_STEPS_M.index(step) + 1]
    for k in range(math.ceil(x0 / step), math.floor(x1 / step) + 1):
        u = left + (k * step - x0) * px_per_m
        draw.line((u, top + h, u, top + h + 4), fill=INK_RGB)
        draw.text((u, top + h + 6), _metres(k * step), fill=INK_RGB, font=font, anchor="ma")
    for k in range(math.ceil(y0 / step), math.floor(y1 / step) + 1):
        v = top + h - (k * step - y0) * px_per_m
        draw.line((left - 5, v, left - 1, v), fill=INK_RGB)
        draw.text((left - 7, v), _metres(k * step), fill=INK_RGB, font=font, anchor="rm")
    # Scale bar: a round length about a fifth of the picture wide.
    bar_m = _nice_step(w / px_per_m, wanted=5)
    y = top + h + 30
    draw.rectangle((left, y, left + bar_m * px_per_m, y + 5), fill=INK_RGB)
    draw.text((left + bar_m * px_per_m + 6, y + 3), f"{_metres(bar_m)}   (cell {res:g} m)",
              fill=INK_RGB, font=font, anchor="lm")
    for u, y, colour, label in legend:  # what each colour means
        draw.rectangle((u, y, u + 10, y + 10), fill=colour, outline=INK_RGB)
        draw.text((u + 14, y + 5), label, fill=INK_RGB, font=font, anchor="lm")
    return canvas, left, top


def picture_scale(window: tuple[int, int, int, int]) -> tuple[int, int]:
    """(pixels per cell, cells per pixel) of map.png for a window of cells: upscaled by
    whole pixels to about ``MIN_PICTURE_PX`` when small, shrunk by whole cells to at most
    ``MAX_PICTURE_PX`` when large."""
    size = max(window[2] - window[0], window[3] - window[1], 1)
    return max(1, min(MAX_UPSCALE, MIN_PICTURE_PX // size)), -(-size // MAX_PICTURE_PX)


def map_picture(static: OccupancyMap, dynamic: OccupancyMap, trajectory: np.ndarray,
                landmarks: Sequence[Landmark], occupied_thresh: float,
                changes: Sequence[ChangeEvent] = ()) -> tuple[Image.Image, float]:
    """map.png: the part of S ∪ D with something in it, upscaled when small (shrunk when
    very large), framed; and its pixels per cell."""
    window = content_window(static, trajectory, landmarks, occupied_thresh)
    scale, shrink = picture_scale(window)
    framed = frame(static, window, picture_size(window, scale, shrink), scale / shrink)
    render(static, dynamic, trajectory, landmarks, occupied_thresh, window, scale, shrink,
           into=framed, changes=changes)
    return framed[0], scale / shrink


def write_picture(path: Path, static: OccupancyMap, dynamic: OccupancyMap,
                  trajectory: np.ndarray, landmarks: Sequence[Landmark],
                  occupied_thresh: float, changes: Sequence[ChangeEvent] = ()) -> float:
    """Write map.png; returns its pixels per cell."""
    image, pixels_per_cell = map_picture(static, dynamic, trajectory, landmarks,
                                         occupied_thresh, changes)
    image.save(path, optimize=False, compress_level=1)  # a third of the default's time
    return pixels_per_cell


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
        h, w = s.shape
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
