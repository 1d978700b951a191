"""A picture of S ∪ D: static map in grey levels (dark = occupied, grey = unknown), dynamic
cells in red, the trajectory in blue, landmarks as small squares (static green, dynamic
orange), change events numbered as in changes.csv: objects (appeared magenta, vacated
cyan; added and removed since a prior session dark magenta and dark cyan) as outlines of
their size, movers (violet) as thin paths. Numbers are written only where they overlap no
other number, and at most MAX_EVENTS_DRAWN events are drawn (the largest; the frame says
how many more changes.csv holds). ``map.png`` shows the part with walls, path, landmarks
or events, upscaled by whole pixels per cell when small, with metre ticks in the map
frame, a scale bar and a legend; the snapshots and the frames of ``evolution.gif`` have
the same frame and their time from the log's start."""

from __future__ import annotations

import io
import math
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from dynslam_cli.mapping.changes import ChangeEvent
from dynslam_cli.mapping.grid import BAND_ROWS, OccupancyMap
from dynslam_cli.result import Landmark, SlamResult

DYNAMIC_RGB = (220, 30, 30)
TRAJECTORY_RGB = (40, 90, 230)
LANDMARK_RGB = {"static": (20, 160, 60), "dynamic": (255, 140, 0)}
CHANGE_RGB = {"appeared": (230, 0, 200), "vacated": (0, 170, 200), "moving": (120, 60, 200),
              "removed_since_prior": (0, 110, 130), "added_since_prior": (150, 0, 120)}
PRIOR_KINDS = ("removed_since_prior", "added_since_prior")  # between sessions (--prior)
PAPER_RGB = (255, 255, 255)
INK_RGB = (0, 0, 0)

MIN_PICTURE_PX = 800  # map.png is upscaled (whole pixels per cell) to at least this size
MAX_UPSCALE = 8
MAX_PICTURE_PX = 4096  # and shrunk (whole cells per pixel) to at most this size
WALL_QUANTILE = 0.005
MARGIN_M = 1.0  # map.png shows the walls, path and landmarks with this much around them
NICE_STEPS_M = (0.5, 1, 2, 5, 10, 20, 50, 100, 200, 500, 1000, 2000, 5000)
MAX_EVENTS_DRAWN = 60


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
    ``changes`` drawn numbered (:func:`draw_changes`), inside the picture."""
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
    if changes:  # drawn on the picture alone: nothing reaches into the frame around it
        w, h = picture_size(window, scale, k)
        box = (left, top, left + w, top + h)
        picture = image.crop(box)
        draw_changes(ImageDraw.Draw(picture), changes,
                     lambda x, y: tuple(np.subtract(pixel(x, y), (left, top))),
                     px_per_cell / res, picture.size)
        image.paste(picture, box[:2])
    return image


def draw_changes(draw: ImageDraw.ImageDraw, changes: Sequence[ChangeEvent],
                 pixel: Any, px_per_m: float, size: tuple[int, int]) -> int:
    """The ``changes`` on a picture of ``size`` pixels (``pixel`` maps x, y in metres to
    it): objects as circles as wide as they are, movers as their paths, the MAX_EVENTS_DRAWN
    largest (an object's width, a mover's way) in order of their number; each numbered
    beside it where the number fits in the picture and overlaps no number already written
    (right, left, above or below), else unnumbered. Returns how many were left out."""
    drawn = sorted(changes, key=lambda e: (-_extent_m(e), e.id))[:MAX_EVENTS_DRAWN]
    font = ImageFont.load_default()
    written: list[tuple[float, float, float, float]] = []
    for e in sorted(drawn, key=lambda e: e.id):
        colour = CHANGE_RGB[e.kind]
        if e.path:
            points = [pixel(x, y) for x, y in e.path]
            if len(points) > 1:
                draw.line(points, fill=colour, width=1)
            (u, v), r = points[-1], 3.0  # numbered where the mover was last seen
            draw.ellipse((u - 2, v - 2, u + 2, v + 2), fill=colour)
        else:
            (u, v), r = pixel(e.x, e.y), max(3.0, math.sqrt(e.size_m2) / 2 * px_per_m + 2)
            draw.ellipse((u - r, v - r, u + r, v + r), outline=colour, width=2)
        text = str(e.id)
        for at, anchor in (((u + r + 2, v), "lm"), ((u - r - 2, v), "rm"),
                           ((u, v - r - 2), "mb"), ((u, v + r + 2), "mt")):
            b = draw.textbbox(at, text, font=font, anchor=anchor, stroke_width=1)
            inside = b[0] >= 0 and b[1] >= 0 and b[2] <= size[0] and b[3] <= size[1]
            if inside and not any(_overlap(b, w) for w in written):
                draw.text(at, text, fill=colour, font=font, anchor=anchor, stroke_width=1,
                          stroke_fill=PAPER_RGB)
                written.append(b)
                break
    return len(changes) - len(drawn)


def _extent_m(e: ChangeEvent) -> float:
    """How much of the map an event covers (m): an object's width, a mover's way."""
    if e.path:
        p = np.asarray(e.path)
        return float(np.hypot(*np.diff(p, axis=0).T).sum())
    return math.sqrt(e.size_m2)


def _overlap(a: tuple[float, ...], b: tuple[float, ...]) -> bool:
    return a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3]


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
                   occupied_thresh: float, margin_m: float = MARGIN_M,
                   changes: Sequence[ChangeEvent] = ()) -> tuple[int, int, int, int]:
    """Cells (col0, row0, col1, row1) around the walls, the path, the landmarks and the
    change events: free space cleared only by long no-return beams far beyond the walls is
    left out, and so are the farthest ``WALL_QUANTILE`` of occupied cells on each side
    (stray far readings)."""
    rows, cols = static.shape
    found = [(r0 + r, c) for r0, band in static.bands()
             for r, c in [np.nonzero(band > occupied_thresh)]]
    occ_r = np.concatenate([r for r, _ in found]) if found else np.zeros(0, np.intp)
    occ_c = np.concatenate([c for _, c in found]) if found else np.zeros(0, np.intp)
    if len(occ_r):
        occ_r = np.quantile(occ_r, [WALL_QUANTILE, 1 - WALL_QUANTILE])
        occ_c = np.quantile(occ_c, [WALL_QUANTILE, 1 - WALL_QUANTILE])
    res = static.resolution
    places = np.array([(lm.x, lm.y) for lm in landmarks]
                      + [p for e in changes for p in (e.path or _corners(e))]).reshape(-1, 2)
    xs = [occ_c.astype(float), trajectory[:, 1:2].ravel() / res - static.origin_x / res,
          (places[:, 0] - static.origin_x) / res]
    ys = [occ_r.astype(float), trajectory[:, 2:3].ravel() / res - static.origin_y / res,
          (places[:, 1] - static.origin_y) / res]
    x, y = np.concatenate(xs), np.concatenate(ys)
    if not len(x):
        return 0, 0, cols, rows
    m = margin_m / res
    return (max(0, int(x.min() - m)), max(0, int(y.min() - m)),
            min(cols, math.ceil(x.max() + m) + 1), min(rows, math.ceil(y.max() + m) + 1))


def _corners(e: ChangeEvent) -> list[tuple[float, float]]:
    """The corners of the square an object's circle is drawn in (m)."""
    r = math.sqrt(e.size_m2) / 2
    return [(e.x - r, e.y - r), (e.x + r, e.y + r)]


def _nice_step(span_m: float, wanted: int = 6) -> float:
    """A round tick spacing giving about ``wanted`` ticks over ``span_m``."""
    return next((s for s in NICE_STEPS_M if span_m / s <= wanted), NICE_STEPS_M[-1])


def _metres(v: float) -> str:
    return f"{v:g} m"


LEGEND = [((0, 0, 0), "static S (occupied)"), ((255, 255, 255), "free"),
          ((128, 128, 128), "unknown"), (DYNAMIC_RGB, "dynamic D"),
          (TRAJECTORY_RGB, "trajectory"), (LANDMARK_RGB["static"], "static landmark"),
          (LANDMARK_RGB["dynamic"], "dynamic landmark"),
          *((rgb, f"{kind} (changes.csv)") for kind, rgb in CHANGE_RGB.items()
            if kind not in PRIOR_KINDS)]


def legend(changes: Sequence[ChangeEvent] = ()) -> list[tuple[tuple[int, int, int], str]]:
    """The legend's entries: every picture's, and the kinds of events between sessions
    (``--prior``) where some are drawn."""
    kinds = {e.kind for e in changes}
    return LEGEND + [(CHANGE_RGB[k], f"{k} (changes.csv)") for k in PRIOR_KINDS if k in kinds]


def frame(lattice: tuple[float, float, float], window: tuple[int, int, int, int],
          size: tuple[int, int], scale: float, title: str = "", note: str = "",
          entries: Sequence[tuple[tuple[int, int, int], str]] = tuple(LEGEND)
          ) -> tuple[Image.Image, int, int]:
    """The frame of a picture of ``size`` pixels showing ``window`` (cells of a grid whose
    ``lattice`` is its origin x, y and resolution, m) at ``scale`` pixels per cell:
    ``title`` above, metre ticks (map frame) on the left and bottom, a scale bar, the legend
    of ``entries`` and ``note`` below. Returns the canvas and where the picture goes in it
    (left, top)."""
    font = ImageFont.load_default()
    ox, oy, res = lattice
    c0, r0, c1, r1 = window
    left, top, right = 56, 26 if title else 10, 16
    w, h = size
    width = max(left + w + right, left + int(font.getlength(note)) + right)
    legend, u, y = [], left, top + h + 46  # the legend's entries, wrapped to the width
    for colour, label in entries:
        length = font.getlength(label)
        if u + 16 + length > width - right and u > left:
            u, y = left, y + 16
        legend.append((u, y, colour, label))
        u += int(14 + length + 14)
    canvas = Image.new("RGB", (width, y + (34 if note else 18)), PAPER_RGB)
    draw = ImageDraw.Draw(canvas)
    if title:
        draw.text((left, top - 8), title, fill=INK_RGB, font=font, anchor="ls")
    if note:
        draw.text((left, y + 21), note, fill=INK_RGB, font=font, anchor="lm")
    draw.rectangle((left - 1, top - 1, left + w, top + h), outline=INK_RGB)
    px_per_m = scale / res
    x0, x1 = ox + c0 * res, ox + c1 * res
    y0, y1 = oy + r0 * res, oy + r1 * res
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


def left_out_note(events: int) -> str:
    """What the picture says of the events it leaves out (MAX_EVENTS_DRAWN at most)."""
    more = events - MAX_EVENTS_DRAWN
    return (f"the {MAX_EVENTS_DRAWN} largest of {events} events drawn: {more} more in "
            f"changes.csv" if more > 0 else "")


def map_picture(static: OccupancyMap, dynamic: OccupancyMap, trajectory: np.ndarray,
                landmarks: Sequence[Landmark], occupied_thresh: float,
                changes: Sequence[ChangeEvent] = ()) -> tuple[Image.Image, float]:
    """map.png: the part of S ∪ D with something in it, upscaled when small (shrunk when
    very large), framed; and its pixels per cell."""
    window = content_window(static, trajectory, landmarks, occupied_thresh, changes=changes)
    scale, shrink = picture_scale(window)
    framed = frame(_lattice(static), window, picture_size(window, scale, shrink), scale / shrink,
                   note=left_out_note(len(changes)), entries=legend(changes))
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
    """The S ∪ D picture every so many seconds of log time, framed like map.png and titled
    with its time from the log's start (``snapshots/t000123.4s.png``: 123.4 s in), and at
    the end an animated GIF of them all on one canvas (``snapshots/evolution.gif``), each
    frame framed and titled the same way, like the rows of the paper's Figs. 2 and 4."""

    GIF_PX = 800  # the GIF's pictures are shrunk to at most this size

    def __init__(self, folder: Path, every_s: float, occupied_threshold: float) -> None:
        self.folder = folder
        self.every = every_s
        self.threshold = occupied_threshold
        self.start: float | None = None
        self.next: float | None = None
        # each snapshot's picture (PNG bytes, one pixel per cell), grid origin, size, time
        self.frames: list[tuple[bytes, float, float, int, int, float]] = []
        folder.mkdir()

    def maybe_take(self, stamp: float, current: Callable[[], SlamResult]) -> None:
        """Take a snapshot at the scan stamped ``stamp`` if it is due: of what ``current``
        gives (the run's maps and path so far)."""
        if self.next is None:
            self.start = self.next = stamp
        if stamp < self.next:
            return
        self.next = stamp + self.every
        self._take(stamp, current())

    def _take(self, stamp: float, result: SlamResult) -> None:
        s = result.static
        since = stamp - (self.start if self.start is not None else stamp)
        picture = render(s, result.dynamic, result.trajectory, result.landmarks, self.threshold)
        h, w = s.shape
        canvas, left, top = frame(_lattice(s), (0, 0, w, h), picture.size, 1,
                                  title=_since(since))
        canvas.paste(picture, (left, top))
        canvas.save(self.folder / f"t{since:08.1f}s.png")
        plain = io.BytesIO()
        picture.save(plain, format="PNG", compress_level=1)
        self.frames.append((plain.getvalue(), s.origin_x, s.origin_y, w, h, since))

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
        cells = (round((x1 - x0) / res), round((y1 - y0) / res))
        scale = min(1.0, self.GIF_PX / max(cells))
        size = (max(1, round(cells[0] * scale)), max(1, round(cells[1] * scale)))

        def frames() -> Any:
            for png, ox, oy, _w, h, since in self.frames:
                picture = Image.new("RGB", cells, (128, 128, 128))
                with Image.open(io.BytesIO(png)) as im:
                    picture.paste(im, (round((ox - x0) / res), round((y1 - (oy + h * res)) / res)))
                if scale < 1.0:
                    picture = picture.resize(size, Image.NEAREST)
                canvas, left, top = frame((x0, y0, res), (0, 0, *cells), size, scale,
                                          title=_since(since))
                canvas.paste(picture, (left, top))
                yield canvas

        it = frames()
        first = next(it)
        first.save(self.folder / "evolution.gif", save_all=True, append_images=it,
                   duration=500, loop=0)


def _lattice(grid: OccupancyMap) -> tuple[float, float, float]:
    return grid.origin_x, grid.origin_y, grid.resolution


def _since(seconds: float) -> str:
    return f"t = {seconds:.1f} s since the log began"
