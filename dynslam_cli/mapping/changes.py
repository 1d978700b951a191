"""Change events: what changed in the world during a run, as objects (``changes.csv``).

The two-map update already says, scan by scan, where the world disagrees with S^{t-1}:

* a beam *ends* where S was Free (Table 2's only way into D): something stands where there
  was nothing. End points of neighbouring beams that lie close together are one *blob*;
  blobs of successive scans at nearly the same place are one *track*. A track that travels
  is ``moving`` (a walking person); a track that stays is an object standing still, and the
  stationary tracks of one place, over the whole run, are one ``appeared`` event.
* a beam *passes through* a cell S held Occupied (Table 1's third row): what stood there may
  have gone. Such cells that end the run Free in S are a place seen to be vacated;
  neighbouring ones are one ``vacated`` event.

:class:`ChangeRecorder` keeps that evidence compactly while the maps are made (a few numbers
per blob and per vacated cell, nothing per free cell); :func:`change_events` turns it into
events when the run ends. A box moved out of view and seen at its new place gives one
``vacated`` and one ``appeared`` event.
"""

from __future__ import annotations

import math
from array import array
from dataclasses import dataclass, replace

import numpy as np

from dynslam_cli.mapping import _changes, _grid
from dynslam_cli.mapping.grid import TILE, GridStack, Observation, logit, steps
from dynslam_cli.sections import ChangeConfig, MapConfig

KINDS = ("appeared", "vacated", "moving", "removed_since_prior", "added_since_prior")


@dataclass(frozen=True)
class ChangeEvent:
    """One row of changes.csv: times are the log's stamps (s), the place in the map frame."""

    id: int
    kind: str  # one of KINDS
    first_s: float
    last_s: float
    x: float
    y: float
    size_m2: float
    scans: int
    landmarks: tuple[int, ...] = ()
    path: tuple[tuple[float, float], ...] = ()
    """A moving track's way (x, y in time order): its places averaged over PATH_SMOOTH_S,
    one per PATH_STEP_M (drawn on map.png; not a column of changes.csv)."""


PATH_SMOOTH_S = 1.0
PATH_STEP_M = 0.1


# A place S held is an object gone only if this share of its cells were seen standing for
# ``still_s`` (hit while S held them that long after they were first hit): a walker's trail,
# mapped where nothing was mapped yet, is seen for about a second per cell, a box for
# seconds in most of its cells (drifting odometry, local maps of 64 and 128 key scans: the
# quarter of cells seen longest, at most 0.9 s in the hall's seven walker trails and at
# least 4.6 s in the boxes of the corridors, the arena and the hall).
SEEN_STANDING_SHARE = 0.25
COMPACT_AT = 1 << 18  # records of crossed and rising cells kept before compacting them

# A blob's record: its scan's index, centroid x y, bounding box x0 y0 x1 y1, cell count.
BLOB_FIELDS = 8
SCAN, CX, CY, X0, Y0, X1, Y1, CELLS = range(BLOB_FIELDS)




class ChangeRecorder:
    """The evidence of change, scan by scan, while a :class:`DynamicMapper` maps: the
    *sightings* (blobs of hits where S^{t-1} was Free), the *clearings* (blobs of cells D
    held Occupied that a beam crossed) and the cells S held Occupied that a beam crossed."""

    def __init__(self, config: ChangeConfig, m: MapConfig, grids: GridStack) -> None:
        self.config = config
        self.grids = grids
        self.occupied_logodds = logit(m.occupied_threshold)
        self._occupied = int(steps(self.occupied_logodds))
        self.free_limit = int(steps(logit(m.free_threshold)))
        clamp, miss = int(steps(logit(m.p_clamp_max))), int(steps(logit(m.p_miss)))
        self.passes_to_leave = math.ceil((clamp - self._occupied) / -miss)
        """Free passes that take a cell from S's clamp out of Occupied (Table 1, row 3): a
        cell crossed more often was hit again in between, a contested wall, not a place
        vacated."""
        self.stamps = array("d")  # per scan
        self._sightings = array("d")
        self._cleared = Records()  # cells D held Occupied that a beam crossed, the scan ...
        self._cleared_stood = array("b")  # ... and whether an object stood on it since it
        # was last cleared, or it never was (:meth:`_note_cleared`)
        self._standing = TileTimes(-np.inf)
        """Per cell: when a beam first ended there where S^{t-1} was Free (an object seen
        there) since the cell was last cleared, in seconds from the first scan (-inf if it
        was never cleared, +inf if nothing was seen there since it was), and when one last
        did; kept for the tiles where D ever held something."""
        self._crossed = Records()  # cells S held Occupied that a beam crossed cleanly ...
        self._grazed = Records()  # ... or grazed (:func:`_beside`), each with its scan
        self._rising = Records()  # cells hit where S did not yet hold them Occupied
        self._held = Records()  # cells hit where S held them Occupied
        self.contested = np.zeros(0, np.int64)
        """Cells crossed cleanly more often than ``passes_to_leave`` (sorted): never a place
        vacated, so their records are let go (:meth:`compact`)."""
        self._compact_at = COMPACT_AT
        self._first_free = np.zeros(0, np.int32)
        """On an earlier session's map (a seeded grid): the scan that first saw each cell
        free in this run, plus one (0: none yet), by flat index."""
        self._prior_standing = np.zeros(0, np.int64)
        """The cells the earlier session's D held Occupied at its end (objects standing
        there then), as sorted :func:`_cell_keys`."""
        self.prior_objects: list[tuple[float, float, float]] = []
        """Objects the earlier session's changes reported standing at its end (x, y, m²)."""

    def note_prior_standing(self, rows: np.ndarray, cols: np.ndarray,
                            objects: list[tuple[float, float, float]]) -> None:
        """What stood in the earlier session's D at its end (world rows and columns), and
        the objects its changes reported standing then (x, y, m²)."""
        self._prior_standing = np.unique(_cell_keys(rows, cols))
        self.prior_objects = list(objects)

    def stood_in_prior(self, x0: float, y0: float, x1: float, y1: float) -> int:
        """How many cells of a box (map frame, m) held an object at the earlier session's
        end (its D Occupied there)."""
        rows, cols = self._box_cells(x0, y0, x1, y1)
        return int(np.count_nonzero(np.isin(_cell_keys(rows, cols), self._prior_standing)))

    def _box_cells(self, x0: float, y0: float, x1: float, y1: float
                   ) -> tuple[np.ndarray, np.ndarray]:
        res = self.grids.resolution
        rows, cols = np.meshgrid(np.arange(math.floor(y0 / res), math.floor(y1 / res) + 1),
                                 np.arange(math.floor(x0 / res), math.floor(x1 / res) + 1),
                                 indexing="ij")
        return rows.ravel(), cols.ravel()

    def record(self, stamp: float, obs: Observation, hit_on_free: np.ndarray) -> None:
        """One scan's evidence: its observation (before the maps are updated with it) and
        which of its hits fell where S^{t-1} was Free (bool per hit, in beam order)."""
        scan = len(self.stamps)
        self.stamps.append(stamp)
        grids = self.grids
        if hit_on_free.any():
            self._sightings.frombytes(_changes.scan_blobs(
                grids.cell_centres(obs.hit[hit_on_free]), self.config.blob_gap_m,
                scan).tobytes())
        static = grids.layers["static"].reshape(-1)
        if "dynamic" in grids.layers:
            self._note_cleared(_grid.cells_above(grids.layers["dynamic"].reshape(-1),
                                                 obs.free, self._occupied),
                               obs.hit[hit_on_free], scan)
        crossed = _grid.cells_above(static, obs.free, self._occupied)
        hits = obs.hit[~hit_on_free]
        held = _grid.cells_above(static, hits, self._occupied)
        grazed = _beside(grids, crossed, held)
        self._crossed.add(scan, crossed[~grazed])
        self._grazed.add(scan, crossed[grazed])
        self._rising.add(scan, _grid.cells_above(static, hits, self._occupied, False))
        self._held.add(scan, held)
        if grids.seeded:
            self._note_first_free(obs.free, scan)
        if self._records() >= self._compact_at:
            self.compact()

    def _note_cleared(self, cleared: np.ndarray, hit: np.ndarray, scan: int) -> None:
        """One scan's cells D held Occupied that a beam crossed, and its cells hit where
        S^{t-1} was Free. Each clearing is recorded with whether the cell was never cleared
        before or an object was seen standing on it for ``still_s`` since it last was (how
        often it was cleared before is :func:`_episodes`' to weigh)."""
        times = self._standing
        if len(cleared):
            self._cleared.add(scan, cleared)
            start, end = times.get(cleared)
            stood = np.isneginf(start) | (end - start >= self.config.still_s)
            self._cleared_stood.frombytes(stood.astype(np.int8).tobytes())
            times.set(cleared, 0, np.inf)
        if len(hit):
            now = np.float32(self.stamps[-1] - self.stamps[0])
            start, _ = times.get(hit)
            times.set(hit[np.isposinf(start)], 0, now)
            times.set(hit, 1, now)

    def _note_first_free(self, cells: np.ndarray, scan: int) -> None:
        if len(self._first_free) < len(self.grids.layers["static"]):
            self._first_free = _grown(self._first_free, len(self.grids.layers["static"]), 0)
        fresh = cells[self._first_free[cells] == 0]
        self._first_free[fresh] = scan + 1

    def seen_free_before(self, x0: float, y0: float, x1: float, y1: float, scan: int
                         ) -> float:
        """The share of the cells of a box (map frame, m) that this run saw free before
        scan ``scan`` (on an earlier session's map only; else 1)."""
        if not self.grids.seeded:
            return 1.0
        first = self.first_free(x0, y0, x1, y1)
        return float(np.count_nonzero((first > 0) & (first <= scan))) / max(first.size, 1)

    def first_free(self, x0: float, y0: float, x1: float, y1: float) -> np.ndarray:
        """For each cell of a box (map frame, m), the scan that first saw it free in this
        run, plus one (0: not seen free; on an earlier session's map only)."""
        rows, cols = self._box_cells(x0, y0, x1, y1)
        flat = self.grids.flat_cells(rows, cols)
        known = (flat >= 0) & (flat < len(self._first_free))
        first = np.zeros(len(flat), np.int64)
        first[known] = self._first_free[flat[known]]
        return first

    def compact(self) -> None:
        """Let go of what can no longer make an event, so memory follows the cells, not the
        length of the log: every record of a contested cell (remembered as such), of each
        cell's hits while Occupied all but the last, of its rises all but the first, and
        its grazes before that last hit."""
        cells, scans = self._crossed.arrays()
        unique, times = np.unique(cells, return_counts=True)
        self.contested = np.union1d(self.contested, unique[times > self.passes_to_leave])
        keep = ~np.isin(cells, self.contested)
        self._crossed.set(cells[keep], scans[keep])
        self._held.set(*self._one_per_cell(*self._held.arrays(), last=True))
        self._rising.set(*self._one_per_cell(*self._rising.arrays(), last=False))
        cells, scans = self._grazed.arrays()
        keep = ~np.isin(cells, self.contested) & (scans > self.last_held(cells))
        self._grazed.set(cells[keep], scans[keep])
        self._compact_at = max(COMPACT_AT, 2 * self._records())

    def _records(self) -> int:
        """How many crossings, grazes, rises and hits are kept."""
        return sum(map(len, (self._crossed, self._grazed, self._rising, self._held)))

    def _one_per_cell(self, cells: np.ndarray, scans: np.ndarray, last: bool
                      ) -> tuple[np.ndarray, np.ndarray]:
        """Of records (cells, scans), each uncontested cell's ``last`` (else first), by
        cell."""
        ok = ~np.isin(cells, self.contested)
        cells, scans = cells[ok], scans[ok]
        order = np.lexsort((scans if last else -scans, cells))
        is_last = np.ones(len(order), bool)  # (none where nothing was: a log of no returns)
        is_last[:-1] = cells[order][1:] != cells[order][:-1]
        return cells[order[is_last]], scans[order[is_last]]

    def last_held(self, cells: np.ndarray) -> np.ndarray:
        """Each cell's last scan that hit it while S held it Occupied (-1: none); after
        :meth:`compact`."""
        return _lookup(*self._held.arrays(), cells)

    def first_rise(self, cells: np.ndarray) -> np.ndarray:
        """Each cell's first scan that hit it while S did not yet hold it Occupied (since
        when what stood there stood; -1: none, it stood in the prior's map); after
        :meth:`compact`."""
        return _lookup(*self._rising.arrays(), cells)

    def sightings(self) -> np.ndarray:
        """Every sighting (N × BLOB_FIELDS), in scan order."""
        return np.frombuffer(self._sightings, np.float64).reshape(-1, BLOB_FIELDS)

    def clearings(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Cells D held Occupied that a beam crossed: their x, y (cell centres), flat
        indices, scans, and whether an object stood on each since it was last cleared, or it
        never was (:meth:`_note_cleared`)."""
        cells, scans = self._cleared.arrays()
        stood = np.frombuffer(self._cleared_stood, np.int8).astype(bool)
        return self.grids.cell_centres(cells), cells, scans, stood

    def crossed(self) -> tuple[np.ndarray, np.ndarray]:
        """Cells S held Occupied that a beam crossed cleanly (flat indices), and the scan of
        each."""
        return self._crossed.arrays()

    def grazed(self) -> tuple[np.ndarray, np.ndarray]:
        """Cells S held Occupied that a beam grazed (:func:`_beside`), and the scan of each
        (after :meth:`compact`: those after the cell was last hit)."""
        return self._grazed.arrays()


class Records:
    """Cells (flat indices) with the scan that recorded each, appended scan by scan."""

    def __init__(self) -> None:
        self._cells = array("q")
        self._scans = array("i")

    def __len__(self) -> int:
        return len(self._cells)

    def add(self, scan: int, cells: np.ndarray) -> None:
        """The cells a scan recorded."""
        if len(cells):
            self._cells.frombytes(cells.astype(np.int64, copy=False).tobytes())
            self._scans.frombytes(np.full(len(cells), scan, np.int32).tobytes())

    def arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """The cells and their scans (int64 each)."""
        return (np.frombuffer(self._cells, np.int64),
                np.frombuffer(self._scans, np.int32).astype(np.int64))

    def set(self, cells: np.ndarray, scans: np.ndarray) -> None:
        """Keep only these records."""
        self._cells = array("q", cells.astype(np.int64).tobytes())
        self._scans = array("i", scans.astype(np.int32).tobytes())


class TileTimes:
    """Two float32 values per grid cell (by flat index: tile · TILE² + place), stored only
    for the tiles where one was set (a map's D touches few of them: the campus's 1.75 km,
    15 million cells, would take 123 MB for every cell); ``fill`` elsewhere."""

    def __init__(self, fill: float) -> None:
        self._fill = fill
        self._slot = np.full(0, -1, np.int64)  # per tile: its block, -1 none
        self._blocks = np.zeros((0, 2, TILE * TILE), np.float32)
        self._used = 0

    def get(self, flat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Both values of the cells ``flat``."""
        tile, place = np.divmod(flat, TILE * TILE)
        slot = np.full(len(flat), -1)
        known = tile < len(self._slot)
        slot[known] = self._slot[tile[known]]
        held = slot >= 0
        out = np.full((2, len(flat)), self._fill, np.float32)
        out[:, held] = self._blocks[slot[held], :, place[held]].T
        return out[0], out[1]

    def set(self, flat: np.ndarray, which: int, value: float) -> None:
        """Value ``which`` (0 or 1) of the cells ``flat`` set to ``value``."""
        if len(flat) == 0:
            return
        tile, place = np.divmod(flat, TILE * TILE)
        if tile.max() >= len(self._slot):
            self._slot = np.concatenate(
                [self._slot, np.full(int(tile.max()) + 1 - len(self._slot), -1)])
        new = np.unique(tile[self._slot[tile] < 0])
        if len(new):
            if self._used + len(new) > len(self._blocks):
                grown = np.full((2 * (self._used + len(new)), 2, TILE * TILE), self._fill,
                                np.float32)
                grown[:self._used] = self._blocks[:self._used]
                self._blocks = grown
            self._slot[new] = np.arange(self._used, self._used + len(new))
            self._used += len(new)
        self._blocks[self._slot[tile], which, place] = value


def _grown(values: np.ndarray, n: int, fill: float) -> np.ndarray:
    """``values`` grown to ``n`` entries, the new ones ``fill``."""
    grown = np.full(n, fill, values.dtype)
    grown[:len(values)] = values
    return grown


def change_events(recorder: ChangeRecorder, landmarks: list[tuple[int, float, float]]
                  ) -> list[ChangeEvent]:
    """The run's events, in order of first sighting, numbered from 1: the recorder's
    evidence read against the final S; ``landmarks`` (id, x, y of the landmark map) name
    the landmarks on each event's place."""
    config = recorder.config
    if not config.enabled:
        return []
    moving, trail, still = _tracks(recorder)
    found = [*moving, *_standing_objects(recorder, still), *_vacated_static(recorder, trail),
             *_gone_since_prior(recorder)]
    found = [e for e in found if e.kind == "moving" or e.size_m2 <= config.max_object_m2]
    found.sort(key=lambda e: (e.first_s, e.x, e.y, e.kind))
    places = np.array([(x, y) for _, x, y in landmarks], dtype=np.float64).reshape(-1, 2)
    ids = np.array([i for i, _, _ in landmarks], dtype=np.int64)
    out = []
    for n, e in enumerate(found, start=1):
        near = np.hypot(places[:, 0] - e.x, places[:, 1] - e.y) <= math.sqrt(e.size_m2) / 2
        out.append(replace(e, id=n, landmarks=tuple(sorted(ids[near].tolist()))))
    return out


def _tracks(recorder: ChangeRecorder
            ) -> tuple[list[ChangeEvent], np.ndarray, list[np.ndarray]]:
    """Sightings linked into tracks: the ``moving`` events, the trail of every moving
    track (stamp, x, y of its sightings) and the still tracks (their sightings)."""
    config = recorder.config
    blobs = recorder.sightings()
    stamps = np.asarray(recorder.stamps)
    res = recorder.grids.resolution
    movers, still, trail = [], [], [np.zeros((0, 3))]
    for members in _link(blobs, stamps, config.track_gate_m, config.track_gap_s):
        b = blobs[members]
        t = stamps[b[:, SCAN].astype(np.int64)]
        if _median_speed(t, b[:, CX:CY + 1], config.still_s / 2) <= config.moving_speed_m_s:
            still.append(b)
            continue
        if np.hypot(*(b[:, CX:CY + 1] - b[0, CX:CY + 1]).T).max() < config.moving_distance_m:
            continue  # (jitter at an object's edge)
        trail.append(np.column_stack((t, b[:, CX:CY + 1])))
        movers.append(_merged([(t, b)]))  # (in time order: a log's stamps may step back)
    moving = []
    for t, b in _one_per_mover(movers, config):
        if len(b) >= config.min_scans:
            size = np.median((b[:, X1] - b[:, X0] + res) * (b[:, Y1] - b[:, Y0] + res))
            moving.append(ChangeEvent(0, "moving", float(t[0]), float(t[-1]),
                                      float(b[:, CX].mean()), float(b[:, CY].mean()),
                                      float(size), len(b), path=_path(t, b[:, CX:CY + 1])))
    return moving, np.vstack(trail), still


def _path(t: np.ndarray, places: np.ndarray) -> tuple[tuple[float, float], ...]:
    """A track's places (N×2, at the sorted stamps ``t``) averaged over the PATH_SMOOTH_S
    around each (a blob's centre jumps as a walker's legs swing), thinned to the first of
    every PATH_STEP_M of the way along them, and the last."""
    lo = np.searchsorted(t, t - PATH_SMOOTH_S / 2, side="left")
    hi = np.searchsorted(t, t + PATH_SMOOTH_S / 2, side="right")
    total = np.vstack((np.zeros((1, 2)), np.cumsum(places, axis=0)))
    places = (total[hi] - total[lo]) / (hi - lo)[:, None]
    along = np.concatenate(([0.0], np.cumsum(np.hypot(*np.diff(places, axis=0).T))))
    _, first = np.unique(np.floor(along / PATH_STEP_M), return_index=True)
    keep = np.union1d(first, [len(places) - 1])
    return tuple((float(x), float(y)) for x, y in places[keep])


def _one_per_mover(tracks: list[tuple[np.ndarray, np.ndarray]], config: ChangeConfig
                   ) -> list[tuple[np.ndarray, np.ndarray]]:
    """Moving tracks (stamps, blobs) joined where they are one mover's: in order of their
    first sighting, a track continues the one it begins closest to, among those last seen
    at most ``join_gap_s`` before it begins (or still seen) within ``track_gate_m`` plus
    ``walker_speed_m_s`` times the time between (where the other was at that moment, if
    it is still seen)."""
    groups: list[tuple[list[tuple[np.ndarray, np.ndarray]], tuple[np.ndarray, np.ndarray]]] = []
    for k in sorted(range(len(tracks)), key=lambda k: (tracks[k][0][0], k)):
        t0, first = tracks[k][0][0], tracks[k][1][0, CX:CY + 1]
        best, best_d = None, math.inf
        for g, (_, (t, b)) in enumerate(groups):  # (each group's tracks merged: kept)
            gap = t0 - t[-1]
            if gap > config.join_gap_s:
                continue
            at = min(np.searchsorted(t, t0, side="right") - 1, len(t) - 1)
            d = float(np.hypot(*(first - b[max(at, 0), CX:CY + 1])))
            if d <= config.track_gate_m + config.walker_speed_m_s * max(gap, 0.0) and d < best_d:
                best, best_d = g, d
        if best is None:
            groups.append(([tracks[k]], tracks[k]))
        else:
            members = groups[best][0] + [tracks[k]]
            groups[best] = (members, _merged(members))
    return [merged for _, merged in groups]


def _merged(tracks: list[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    """Tracks (stamps, blobs) as one, in time order."""
    t = np.concatenate([t for t, _ in tracks])
    b = np.concatenate([b for _, b in tracks])
    order = np.argsort(t, kind="stable")
    return t[order], b[order]


def _link(blobs: np.ndarray, stamps: np.ndarray, gate: float, gap_s: float
          ) -> list[np.ndarray]:
    """Tracks (blob indices in time order): each scan's blobs continue the nearest track
    seen within ``gap_s`` whose last blob lies within ``gate``, nearest pairs first; one
    blob a scan per track."""
    if not len(blobs):
        return []
    track = _changes.link_tracks(blobs, stamps, gate, gap_s)
    order = np.argsort(track, kind="stable")  # (blobs in time order within each track)
    return np.split(order, np.flatnonzero(np.diff(track[order])) + 1)


def _median_speed(t: np.ndarray, places: np.ndarray, window_s: float) -> float:
    """Median over a track of its speed (m/s) from each sighting to the first one at least
    ``window_s`` later; over its whole span if it is shorter; 0 for a single instant."""
    later = np.searchsorted(t, t + window_s)
    ok = later < len(t)
    if not ok.any():
        span = t[-1] - t[0]
        return float(np.hypot(*(places[-1] - places[0])) / span) if span > 0 else 0.0
    i, j = np.flatnonzero(ok), later[ok]
    return float(np.median(np.hypot(*(places[j] - places[i]).T) / (t[j] - t[i])))


def _neighbour_groups(points: np.ndarray, within: float) -> np.ndarray:
    """Group label of each point: points less than ``within`` apart in x and in y are in
    one group."""
    return _box_groups(np.hstack((points, points)), within)


def _box_groups(boxes: np.ndarray, within: float) -> np.ndarray:
    """Group label of each box (x0, y0, x1, y1): boxes less than ``within`` apart are in
    one group. Pairs by a sweep along x: each box against those that start within its
    x extent (no n × n table)."""
    n = len(boxes)
    order = np.argsort(boxes[:, 0], kind="stable")
    b = boxes[order]
    reach = np.searchsorted(b[:, 0], b[:, 2] + within, side="right")
    count = np.maximum(reach - np.arange(1, n + 1), 0)
    first = np.repeat(np.arange(n), count)
    second = first + 1 + np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
    near = np.maximum(b[first, 1] - b[second, 3], b[second, 1] - b[first, 3]) < within
    return _components(n, order[first[near]], order[second[near]])


def _components(n: int, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Connected components of n nodes joined by the edges (a[k], b[k]): each node's
    label, 0, 1, ... in the order of the components' smallest nodes (labels spread along
    the edges, then follow each other, until nothing changes). scipy.sparse.csgraph would
    do; importing it costs a process 30 MB."""
    label = np.arange(n)
    while True:
        low = np.minimum(label[a], label[b])
        before = label.copy()
        np.minimum.at(label, a, low)
        np.minimum.at(label, b, low)
        while not np.array_equal(label, label[label]):
            label = label[label]
        if np.array_equal(label, before):
            return np.unique(label, return_inverse=True)[1].reshape(-1)


def _standing_objects(recorder: ChangeRecorder, still: list[np.ndarray]) -> list[ChangeEvent]:
    """Still tracks grouped by place. At each place, runs of sightings that no clearing of
    the place interrupts are objects that ``appeared`` there (if seen standing for
    ``still_s`` in ``min_scans`` scans), or, on an earlier session's map, stood there since
    (``added_since_prior``: most of its place not seen free by this run before); the
    clearings after one are it ``vacated``."""
    if not still:
        return []
    config, res = recorder.config, recorder.grids.resolution
    stamps = np.asarray(recorder.stamps)
    cleared_xy, cleared_cells, cleared_scans, cleared_stood = recorder.clearings()
    groups = _box_groups(np.array([(b[:, X0].min(), b[:, Y0].min(), b[:, X1].max(),
                                    b[:, Y1].max()) for b in still]), config.merge_distance_m)
    out = []
    for g in range(groups.max() + 1):
        b = np.vstack([still[k] for k in np.flatnonzero(groups == g)])
        x0, y0 = b[:, X0].min() - res, b[:, Y0].min() - res
        x1, y1 = b[:, X1].max() + res, b[:, Y1].max() + res
        seen = np.unique(b[:, SCAN]).astype(np.int64)
        inside = ((cleared_xy[:, 0] >= x0) & (cleared_xy[:, 0] <= x1)
                  & (cleared_xy[:, 1] >= y0) & (cleared_xy[:, 1] <= y1))
        enough = max(config.min_area_m2 / res ** 2, float(np.median(b[:, CELLS])) / 2)
        for episode, gone in _episodes(seen, cleared_cells[inside], cleared_scans[inside],
                                       cleared_stood[inside], enough, stamps,
                                       config.still_s, recorder.passes_to_leave):
            sightings = b[np.isin(b[:, SCAN], episode)]
            t = stamps[episode]
            if len(episode) < config.min_scans or not _steady(t, stamps, config.still_s):
                continue
            ex0, ey0 = sightings[:, X0].min(), sightings[:, Y0].min()
            ex1, ey1 = sightings[:, X1].max(), sightings[:, Y1].max()
            place = (float(ex0 + ex1) / 2, float(ey0 + ey1) / 2,
                     float((ex1 - ex0 + res) * (ey1 - ey0 + res)))
            # standing where the prior's S was Free when this run first looked: there
            # since, unless the prior's D held it standing at its end (no change then)
            kind: str | None = "appeared"
            if recorder.seen_free_before(ex0, ey0, ex1, ey1, int(episode[0])) < 0.5:
                held = recorder.stood_in_prior(ex0 - res, ey0 - res, ex1 + res, ey1 + res)
                kind = None if 2 * held >= np.median(sightings[:, CELLS]) else (
                    "added_since_prior")
            if kind is not None:
                out.append(ChangeEvent(0, kind, float(t[0]), float(t[-1]), *place,
                                       len(episode)))
            if gone is not None:
                out.append(ChangeEvent(0, "vacated", float(stamps[gone[0]]),
                                       float(stamps[gone[-1]]), *place, len(gone)))
    return out


def _cell_keys(rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """One int64 per world cell (|col| < 2^31)."""
    return rows.astype(np.int64) * (1 << 32) + cols.astype(np.int64)


def _steady(sighted: np.ndarray, stamps: np.ndarray, still_s: float) -> bool:
    """Whether the object was seen standing for ``still_s`` seconds (``sighted`` and
    ``stamps`` sorted): seen at the start and again at the end of such a span, and in at
    least half the log's scans of it. Not a few stray returns (a beam split on an edge)
    that come back now and then, nor a slow walker's fragment seen still for a moment."""
    end = np.searchsorted(sighted, sighted + still_s)  # first sighting still_s later
    ok = end < len(sighted)
    i, j = np.flatnonzero(ok), end[ok]
    scans = np.searchsorted(stamps, sighted[j], side="right") - np.searchsorted(stamps, sighted[i])
    return bool(np.any(2 * (j - i + 1) >= scans))


def _episodes(seen: np.ndarray, cells: np.ndarray, scans: np.ndarray, stood: np.ndarray,
              enough: float, stamps: np.ndarray, still_s: float, contested: int
              ) -> list[tuple[np.ndarray, np.ndarray | None]]:
    """Split a place's sighting scans (sorted) where, between two sightings, beams cleared
    ``enough`` of its cells in scans that did not see the object there, each cell not
    cleared before since the run of sightings began (a beam past a standing object's edge,
    or along a face it grazes, clears the same cells again and again), or cleared at most
    ``contested`` times and seen standing since (``stood``,
    :meth:`ChangeRecorder._note_cleared`: a face crossed while the object arrived counts
    again); and where the place then stayed so for ``still_s`` (by the scans' ``stamps``:
    seen again sooner, it had not gone). Each run of sightings and, if it ended so, the
    scans that saw it gone (from the one that brought the count to ``enough`` to the next
    sighting)."""
    order = np.argsort(scans, kind="stable")
    cells, scans, stood = cells[order], scans[order], stood[order]
    cut = np.searchsorted(seen, scans, side="right")  # sightings up to each clearing
    bounds = np.flatnonzero(np.diff(cut, prepend=-1, append=-1))  # (runs of one gap)
    unseen = ~np.isin(scans, seen)  # (not a scan that saw the object there)
    keys = np.sort(cells * len(cells) + np.arange(len(cells)))  # by cell, then order
    before = _earlier_count(keys, cells, np.arange(len(cells)), len(cells))
    out: list[tuple[np.ndarray, np.ndarray | None]] = []
    start, since = 0, 0  # (the entry where the run of sightings began)
    for a, b in zip(bounds[:-1].tolist(), bounds[1:].tolist(), strict=True):
        gap = int(cut[a])
        if gap == 0:
            since = b
            continue
        here = cells[a:b]
        cleared = before[a:b] - _earlier_count(keys, here, np.full(b - a, since), len(cells))
        counted = unseen[a:b] & ((cleared == 0) | (stood[a:b] & (cleared <= contested)))
        new = np.unique(here[counted], return_index=True)[1]
        if len(new) >= enough:
            reached = np.sort(new)[math.ceil(enough) - 1]
            gone = np.unique(scans[a:b][counted][reached:])
            if gap < len(seen) and stamps[seen[gap]] - stamps[gone[0]] < still_s:
                continue
            out.append((seen[start:gap], gone))
            start, since = gap, b
    out.append((seen[start:], None))
    return [e for e in out if len(e[0])]


def _earlier_count(keys: np.ndarray, cells: np.ndarray, at: np.ndarray, n: int) -> np.ndarray:
    """For each cell, how many clearings of it come before entry ``at`` (``keys``: the
    clearings' cell · n + entry, sorted)."""
    return np.searchsorted(keys, cells * n + at) - np.searchsorted(keys, cells * n)


def _lookup(cells: np.ndarray, values: np.ndarray, wanted: np.ndarray) -> np.ndarray:
    """The value of each wanted cell among ``cells`` (sorted, each once) and their
    ``values``; -1 where it is not there."""
    at = np.minimum(np.searchsorted(cells, wanted), max(len(cells) - 1, 0))
    found = (cells[at] == wanted) if len(cells) else np.zeros(len(wanted), bool)
    return np.where(found, values[at] if len(cells) else -1, -1)


NEIGHBOURS = np.array([(dr, dc) for dr in (-1, 0, 1) for dc in (-1, 0, 1)], np.int64)


def _beside(grids: GridStack, cells: np.ndarray, hit: np.ndarray) -> np.ndarray:
    """Which of ``cells`` (flat) touch a cell of ``hit`` (flat; where the same scan's beams
    ended on S's Occupied cells), sides and corners: a beam that passes such a cell grazes
    the surface the others ended on (at a shallow incidence a beam runs along a face for
    several cells before it ends in it)."""
    if not len(cells) or not len(hit):
        return np.zeros(len(cells), bool)
    rows, cols = grids.world_cells(cells)
    keys = np.sort(_cell_keys(*grids.world_cells(hit)))
    around = (_cell_keys(rows, cols)[None, :]
              + (NEIGHBOURS[:, 0, None] << 32) + NEIGHBOURS[:, 1, None]).ravel()
    at = np.minimum(np.searchsorted(keys, around), len(keys) - 1)
    return (keys[at] == around).reshape(len(NEIGHBOURS), -1).any(axis=0)


def standing_at_end(events: list[ChangeEvent]) -> tuple[tuple[float, float, float], ...]:
    """The objects a run's change events say stood at its end (x, y, m²): each that arrived
    (``appeared``, ``added_since_prior``) and was not seen to leave after (no ``vacated``
    within its half-width)."""
    came = [e for e in events if e.kind in ("appeared", "added_since_prior")]
    left = [e for e in events if e.kind == "vacated"]
    return tuple((e.x, e.y, e.size_m2) for e in came
                 if not any(v.first_s >= e.first_s and math.hypot(v.x - e.x, v.y - e.y)
                            <= max(0.3, math.sqrt(e.size_m2) / 2) for v in left))


def _gone_since_prior(recorder: ChangeRecorder) -> list[ChangeEvent]:
    """The objects an earlier session saw arrive and still standing at its end (in its D,
    not its S), whose place this run saw free over at least half its cells:
    ``removed_since_prior``, seen so when half of them had been (a place taken as a square
    of the object's area)."""
    stamps = np.asarray(recorder.stamps)
    out = []
    for x, y, area in recorder.prior_objects:
        half = math.sqrt(area) / 2
        first = recorder.first_free(x - half, y - half, x + half, y + half)
        seen = np.sort(first[first > 0]) - 1
        if 2 * len(seen) < len(first):
            continue
        out.append(ChangeEvent(0, "removed_since_prior", float(stamps[seen[len(first) // 2]]),
                               float(stamps[seen[-1]]), x, y, area, len(np.unique(seen))))
    return out


def _vacated_static(recorder: ChangeRecorder, trail: np.ndarray) -> list[ChangeEvent]:
    """Places S held Occupied, crossed cleanly by beams at most ``passes_to_leave`` times
    each over the run, Free at the end, and since they were last hit crossed cleanly and
    never grazed (a wall's face that grazing beams wore away is no place vacated), grouped
    by neighbourhood (cells ``merge_distance_m`` apart): a static object gone, seen so when
    half its cells had been crossed since; ``removed_since_prior`` where S held it from an
    earlier session's map (``--prior``) and this run never saw it come. A place a mover was
    seen beside when it went is that mover's trail, not an event; one not seen standing for
    ``still_s`` in enough of its cells is a mover that went into S unmapped."""
    config, grids = recorder.config, recorder.grids
    recorder.compact()  # (no contested cell left: each crossed at most passes_to_leave times)
    cells, scans = recorder.crossed()
    since = scans > recorder.last_held(cells)  # (the crossings since it was last hit)
    cells, scans = cells[since], scans[since]
    if not len(cells):
        return []
    unique, which = np.unique(cells, return_inverse=True)
    gone = ((grids.layers["static"].reshape(-1)[unique] < recorder.free_limit)
            & ~np.isin(unique, recorder.grazed()[0]))
    if not gone.any():
        return []
    rows, cols = grids.world_cells(unique[gone])
    beside_wall = (grids.classify_cells("static", unique[gone], 1, -math.inf,
                                        recorder.occupied_logodds) == 2
                   if config.skip_wall_faces else np.zeros(len(rows), bool))
    res = grids.resolution
    groups = _neighbour_groups(np.column_stack((rows, cols)) * res, config.merge_distance_m)
    first_crossed = np.full(len(unique), np.iinfo(np.int64).max)
    np.minimum.at(first_crossed, which, scans)
    first_crossed = first_crossed[gone]
    entered = recorder.first_rise(unique[gone])
    held = recorder.last_held(unique[gone])
    stamps = np.asarray(recorder.stamps)
    watched = np.where(entered < 0, math.inf, np.where(
        held > entered, stamps[held] - stamps[entered], 0.0))
    group_of = np.full(len(unique), -1, np.int64)
    group_of[gone] = groups
    record_group = group_of[which]
    out = []
    for g in range(groups.max() + 1):
        members = groups == g
        area = float(members.sum()) * res * res
        if area < config.min_area_m2 or beside_wall[members].all():
            continue  # (too small, or a wall's face: see ChangeConfig.skip_wall_faces)
        seen = np.unique(scans[record_group == g])
        x, y = (cols[members].mean() + 0.5) * res, (rows[members].mean() + 0.5) * res
        # seen gone from when half its cells had been crossed
        first = float(stamps[np.sort(first_crossed[members])[members.sum() // 2]])
        if np.quantile(watched[members], 1.0 - SEEN_STANDING_SHARE) < config.still_s:
            continue  # (a mover that went into S where nothing was mapped yet)
        last = float(stamps[seen[-1]])
        near = np.abs(trail[:, 0] - first) <= config.track_gap_s
        if np.any(np.hypot(trail[near, 1] - x, trail[near, 2] - y) <= config.track_gate_m):
            continue  # (a mover's trail)
        # no cell of it came into S in this run: it stood there in the prior's map
        kind = ("removed_since_prior" if grids.seeded and (entered[members] < 0).all()
                else "vacated")
        out.append(ChangeEvent(0, kind, first, last, float(x), float(y), area, len(seen)))
    return out
