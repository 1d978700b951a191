"""Scores against the truth: trajectory (ATE), static and dynamic maps, moved objects,
vacated places, landmarks; and the Kümmerle et al. (2009) relation metric.

Everything here works on arrays and plain dicts (``truth.json`` as loaded);
``job.score_output`` reads the files. Distances are in metres, angles in degrees where
reported.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np

from dynslam_cli.errors import ScoreError
from dynslam_cli.geometry import distance_to_segments, segment_crosses, wrap_angles
from dynslam_cli.mapping.changes import ChangeEvent
from dynslam_cli.mapping.grid import OccupancyMap
from dynslam_cli.result import Landmark

UNKNOWN_BAND = 0.01  # |p − 0.5| within this is "never observed" (PGM quantisation included)
MIN_MATCHED = 0.5  # a score needs at least this share of the poses (relations) it could match


# -- trajectory -----------------------------------------------------------------------------
def align_se2(est: np.ndarray, ref: np.ndarray) -> tuple[np.ndarray, float]:
    """Rigid 2D alignment (rotation + translation, no scale) of est (N×2) onto ref (N×2):
    returns the aligned points and the rotation angle (Kabsch / Umeyama without scale)."""
    mu_e, mu_r = est.mean(0), ref.mean(0)
    h = (est - mu_e).T @ (ref - mu_r)
    angle = math.atan2(h[0, 1] - h[1, 0], h[0, 0] + h[1, 1])
    c, s = math.cos(angle), math.sin(angle)
    rot = np.array([[c, -s], [s, c]])
    return (est - mu_e) @ rot.T + mu_r, angle


def match_stamps(est: np.ndarray, ref: np.ndarray, max_dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs (i_est, i_ref) of stamps that agree within ``max_dt`` (nearest neighbour)."""
    order = np.argsort(ref[:, 0], kind="stable")
    ts = ref[order, 0]
    j = np.clip(np.searchsorted(ts, est[:, 0]), 1, max(len(ts) - 1, 1))
    left = np.abs(est[:, 0] - ts[j - 1]) <= np.abs(est[:, 0] - ts[np.minimum(j, len(ts) - 1)])
    k = np.where(left, j - 1, np.minimum(j, len(ts) - 1))
    ok = np.abs(est[:, 0] - ts[k]) <= max_dt
    return np.flatnonzero(ok), order[k[ok]]


def _span(rows: np.ndarray) -> str:
    return f"{rows[:, 0].min():.3f}–{rows[:, 0].max():.3f} s" if len(rows) else "empty"


def ate_rmse(est: np.ndarray, ref: np.ndarray, max_dt: float = 1e-3) -> float:
    """Absolute trajectory error (RMSE of positions, m) after SE(2) alignment; rows are
    (stamp, x, y, theta). Raises :class:`ScoreError` when fewer than two poses, or fewer than
    ``MIN_MATCHED`` of ``est``'s, have a reference pose at their stamp."""
    i, j = _enough_matched(est, ref, max_dt)
    return aligned_rmse(est[i, 1:3], ref[j, 1:3])


def _enough_matched(est: np.ndarray, ref: np.ndarray, max_dt: float
                    ) -> tuple[np.ndarray, np.ndarray]:
    """:func:`match_stamps`, or :class:`ScoreError` where it pairs too few (see
    :func:`ate_rmse`)."""
    i, j = match_stamps(est, ref, max_dt) if len(est) and len(ref) else (np.zeros(0, int),) * 2
    if len(i) < max(2, MIN_MATCHED * len(est)):
        raise ScoreError(f"only {len(i)} of {len(est)} poses have a reference pose within "
                         f"{max_dt:g} s (poses {_span(est)}, reference {_span(ref)}): not the "
                         "same run, or its stamps are shifted")
    return i, j


def _on_truth_clock(trajectory: np.ndarray, truth: dict[str, Any]) -> np.ndarray:
    """A copy of the trajectory (rows stamp, x, y, theta) with the log's stamps put on the
    truth's clock (``stamp_offset_s``: bags are stamped from a plausible ROS epoch)."""
    out = np.array(trajectory, dtype=float)
    out[:, 0] -= float(truth.get("stamp_offset_s", 0.0))
    return out


def aligned_rmse(est: np.ndarray, ref: np.ndarray) -> float:
    """RMSE (m) of positions est (N×2) against ref (N×2), row by row, after SE(2) alignment."""
    aligned, _ = align_se2(est, ref)
    return float(np.sqrt(np.mean(np.sum((aligned - ref) ** 2, axis=1))))


# -- geometry of the truth ------------------------------------------------------------------
def box_segments(center: list[float], size: list[float]) -> np.ndarray:
    cx, cy = center
    hx, hy = size[0] / 2, size[1] / 2
    x0, x1, y0, y1 = cx - hx, cx + hx, cy - hy, cy + hy
    return np.array([[x0, y0, x1, y0], [x1, y0, x1, y1], [x1, y1, x0, y1], [x0, y1, x0, y0]])


def in_box(points: np.ndarray, center: list[float], size: list[float], margin: float
           ) -> np.ndarray:
    return ((np.abs(points[:, 0] - center[0]) <= size[0] / 2 + margin)
            & (np.abs(points[:, 1] - center[1]) <= size[1] / 2 + margin))


def mover_distance(points: np.ndarray, objects: dict[str, Any]) -> np.ndarray:
    """Distance of each point to anywhere a moving thing ever stood (box outlines at every
    position, walkers' swept loops less their radius); 0 inside a box."""
    best = np.full(len(points), np.inf)
    for obj in objects.values():
        if obj["kind"] == "box":
            for _, center in obj["positions"]:
                d = distance_to_segments(points, box_segments(center, obj["size"]))
                d[in_box(points, center, obj["size"], 0.0)] = 0.0
                best = np.minimum(best, d)
        else:
            loop = np.array(obj["loop"] + obj["loop"][:1], dtype=float)
            segs = np.hstack((loop[:-1], loop[1:]))
            best = np.minimum(best, np.maximum(distance_to_segments(points, segs)
                                               - obj["radius"], 0.0))
    return best


def cell_centers(grid: OccupancyMap, mask: np.ndarray) -> np.ndarray:
    rows, cols = np.nonzero(mask)
    r = grid.resolution
    return np.column_stack((grid.origin_x + (cols + 0.5) * r, grid.origin_y + (rows + 0.5) * r))


def _window_any(mask: np.ndarray, radius_cells: int) -> np.ndarray:
    """Cells with any True within a square window of the given radius."""
    from scipy.ndimage import maximum_filter

    return maximum_filter(mask, size=2 * radius_cells + 1, mode="constant", cval=False)


def _cells_of(grid: OccupancyMap, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    col = np.floor((points[:, 0] - grid.origin_x) / grid.resolution).astype(int)
    row = np.floor((points[:, 1] - grid.origin_y) / grid.resolution).astype(int)
    ok = (row >= 0) & (row < grid.prob.shape[0]) & (col >= 0) & (col < grid.prob.shape[1])
    return row, col, ok


# -- visibility of places, from the truth ---------------------------------------------------
SEEN_SCANS = 3  # scans that must hit an object before it counts as seen in its place


def _seen_after(truth: dict[str, Any], obj_id: str, since: float, until: float) -> bool:
    """Did at least SEEN_SCANS scans in [since, until) hit the object in its place?"""
    poses = truth["poses"]
    return sum(since <= poses[k][0] < until and obj_id in hits
               for k, hits in enumerate(truth["hits"])) >= SEEN_SCANS


def _known_free_before(truth: dict[str, Any], place: list[float], arrived: float) -> bool:
    """Was the place seen empty before a box arrived there (so S could know it was Free)?
    A place never seen empty is Unknown in S and a box there is static by Table 1, row 5."""
    vacated = [o["positions"][i + 1][0] for o in truth["objects"].values()
               if o["kind"] == "box" for i, (_, c) in enumerate(o["positions"][:-1])
               if np.allclose(c, place) and o["positions"][i + 1][0] <= arrived]
    occupied_at_start = any(np.allclose(o["positions"][0][1], place)
                            for o in truth["objects"].values() if o["kind"] == "box")
    if occupied_at_start and not vacated:
        return False
    max_range, fov = _view(truth)
    return _place_seen_empty(truth, place, max(vacated, default=0.0), arrived, max_range, fov)


def _place_seen_empty(truth: dict[str, Any], center: list[float], since: float, until: float,
                      max_range: float, fov: float) -> bool:
    """Did a beam of a scan in [since, until) pass over the place's centre unobstructed by
    walls? (Ray-casting from the true poses against the static walls.)"""
    walls = np.asarray(truth["walls"], dtype=float)
    c = np.asarray(center, dtype=float)
    for t, x, y, th in truth["poses"]:
        if not since <= t < until:
            continue
        v = c - (x, y)
        dist = float(np.hypot(*v))
        if dist > max_range - 0.1 or dist < 0.2:
            continue
        bearing = math.atan2(v[1], v[0]) - th
        if abs(math.remainder(bearing, 2 * math.pi)) > fov / 2:
            continue
        beyond = c + 0.3 * v / dist  # the beam must reach past the centre
        seg = np.array([[x, y, *beyond]])
        if not segment_crosses(seg[0], walls):
            return True
    return False


# -- the scores -----------------------------------------------------------------------------
@dataclass(frozen=True)
class MapThresholds:
    free: float
    occupied: float


def score_run(static: OccupancyMap, dynamic: OccupancyMap, trajectory: np.ndarray,
              landmarks: list[Landmark], truth: dict[str, Any], thresholds: MapThresholds,
              tolerance_m: float = 0.1) -> dict[str, Any]:
    """All scores of one output folder against ``truth.json`` (see the module docstring)."""
    walls = np.asarray(truth["walls"], dtype=float)
    objects = truth["objects"]
    ref = np.asarray(truth["poses"], dtype=float)
    odom = np.asarray(truth["odometry"], dtype=float)
    trajectory = _on_truth_clock(trajectory, truth)
    res = static.resolution
    tol = max(tolerance_m, res)
    occ_s = static.prob > thresholds.occupied
    occ_d = dynamic.prob > thresholds.occupied

    # Static map: precision, recall, ghosts.
    pts_s = cell_centers(static, occ_s)
    d_wall = distance_to_segments(pts_s, walls)
    on_static = d_wall <= tol
    ghost = ~on_static & (mover_distance(pts_s, objects) <= tol)
    samples = _wall_samples(walls, res / 2)
    row, col, ok = _cells_of(static, samples)
    k = max(1, math.ceil(tol / res))
    observed = _window_any(np.abs(static.prob - 0.5) > UNKNOWN_BAND, k)
    found = _window_any(occ_s, k)
    seen = np.zeros(len(samples), bool)
    seen[ok] = observed[row[ok], col[ok]]
    hit = np.zeros(len(samples), bool)
    hit[ok] = found[row[ok], col[ok]]

    # Dynamic map precision.
    pts_d = cell_centers(dynamic, occ_d)
    d_prec = mover_distance(pts_d, objects) <= tol

    moved, vacated = _score_moves(static, dynamic, truth, thresholds, tol)
    lm = _score_landmarks(landmarks, truth, objects, tol=max(0.2, 2 * res))
    return {
        "trajectory": {"ate_rmse_m": ate_rmse(trajectory, ref),
                       "odometry_ate_rmse_m": ate_rmse(odom, ref), "poses": len(trajectory)},
        "static_map": {"precision": _ratio(on_static.sum(), len(pts_s)),
                       "recall": _ratio((hit & seen).sum(), seen.sum()),
                       "ghost_rate": _ratio(ghost.sum(), len(pts_s)),
                       "occupied_cells": len(pts_s)},
        "dynamic_map": {"precision": _ratio(d_prec.sum(), len(pts_d)),
                        "occupied_cells": len(pts_d),
                        "moved_objects_detected": moved,
                        "vacated_places_cleared": vacated},
        "landmarks": lm,
        "tolerance_m": tol,
    }


def _ratio(a: float, b: float) -> float | None:
    return float(a) / float(b) if b else None


def _wall_samples(walls: np.ndarray, step: float) -> np.ndarray:
    out = []
    for x1, y1, x2, y2 in walls:
        n = max(2, math.ceil(math.hypot(x2 - x1, y2 - y1) / step) + 1)
        f = np.linspace(0, 1, n)
        out.append(np.column_stack((x1 + f * (x2 - x1), y1 + f * (y2 - y1))))
    return np.vstack(out) if out else np.zeros((0, 2))


def _footprint(grid: OccupancyMap, center: list[float], size: list[float],
               walls: np.ndarray, tol: float) -> tuple[np.ndarray, np.ndarray]:
    """(rows, cols) of the cells of a box footprint grown by tol, less cells near walls."""
    r = grid.resolution
    h, w = grid.prob.shape
    cols = np.arange(w)
    rows = np.arange(h)
    xs = grid.origin_x + (cols + 0.5) * r
    ys = grid.origin_y + (rows + 0.5) * r
    cx = cols[np.abs(xs - center[0]) <= size[0] / 2 + tol]
    ry = rows[np.abs(ys - center[1]) <= size[1] / 2 + tol]
    rr, cc = np.meshgrid(ry, cx, indexing="ij")
    rr, cc = rr.ravel(), cc.ravel()
    pts = np.column_stack((grid.origin_x + (cc + 0.5) * r, grid.origin_y + (rr + 0.5) * r))
    keep = distance_to_segments(pts, walls) > tol
    return rr[keep], cc[keep]


def _view(truth: dict[str, Any]) -> tuple[float, float]:
    """(max range m, field of view rad) of the simulated laser."""
    laser = truth.get("laser", {})
    return float(laser.get("max_range_m", 8.0)), math.radians(float(laser.get("fov_deg", 180.0)))


def _detected(static: OccupancyMap, dynamic: OccupancyMap, place: list[float],
              size: list[float], walls: np.ndarray, th: MapThresholds, tol: float) -> bool | None:
    """A box at ``place``: occupied in D and nowhere in S? None if no cell is off the walls."""
    rr, cc = _footprint(dynamic, place, size, walls, tol)
    if not len(rr):
        return None
    return bool((dynamic.prob[rr, cc] > th.occupied).any()
                and not (static.prob[rr, cc] > th.occupied).any())


def _cleared(static: OccupancyMap, place: list[float], size: list[float], walls: np.ndarray,
             th: MapThresholds) -> bool | None:
    """A place a box left: no cell of its footprint Occupied in S? None if nothing to check."""
    rr, cc = _footprint(static, place, size, walls, 0.0)
    if not len(rr):
        return None
    return not bool((static.prob[rr, cc] > th.occupied).any())


def _tally(results: list[bool | None]) -> dict[str, Any]:
    judged = [r for r in results if r is not None]
    return {"detected": sum(judged), "of": len(judged), "rate": _ratio(sum(judged), len(judged))}


def _moves(truth: dict[str, Any]) -> Iterator[tuple[str, dict, int, float, float]]:
    """(object id, object, index of position, arrived at, left at) for every box position."""
    end = truth["poses"][-1][0] + 1.0 if truth["poses"] else 0.0
    for obj_id, obj in truth["objects"].items():
        if obj["kind"] != "box" or len(obj["positions"]) < 2:
            continue
        positions = obj["positions"]
        for i, (t, _) in enumerate(positions):
            yield obj_id, obj, i, t, positions[i + 1][0] if i + 1 < len(positions) else end


def _score_moves(static: OccupancyMap, dynamic: OccupancyMap, truth: dict[str, Any],
                 th: MapThresholds, tol: float) -> tuple[dict[str, Any], dict[str, Any]]:
    """Judged on the final maps: every box's final place, if it had moved there and was seen
    there afterwards, must be occupied in D and not in S; every place a box left, that the
    robot then saw empty and where no box stands at the end, must not be occupied in S."""
    walls = np.asarray(truth["walls"], dtype=float)
    max_range, fov = _view(truth)
    end = truth["poses"][-1][0] + 1.0 if truth["poses"] else 0.0
    finals = [o["positions"][-1][1] for o in truth["objects"].values() if o["kind"] == "box"]
    detected, cleared = [], []
    for obj_id, obj, i, arrived, left in _moves(truth):
        place = obj["positions"][i][1]
        if left >= end:  # the final place
            if (i > 0 and _seen_after(truth, obj_id, arrived, end)
                    and _known_free_before(truth, place, arrived)):
                detected.append(_detected(static, dynamic, place, obj["size"], walls, th, tol))
            continue
        if any(np.allclose(place, c) for c in finals):
            continue
        back = [t for t, c in obj["positions"][i + 1:] if np.allclose(c, place)]
        if _place_seen_empty(truth, place, left, back[0] if back else end, max_range, fov):
            cleared.append(_cleared(static, place, obj["size"], walls, th))
    moved, vacated = _tally(detected), _tally(cleared)
    vacated = {"cleared": vacated.pop("detected"), **vacated}
    return moved, vacated


def score_events(snapshots: list[tuple[float, OccupancyMap, OccupancyMap]],
                 truth: dict[str, Any], thresholds: MapThresholds, tolerance_m: float = 0.1
                 ) -> dict[str, Any]:
    """The paper's Table 4, event by event. ``snapshots`` holds (time, S, D) taken just before
    the scan at each relocation time and at the end of the run. Each relocation whose box was
    seen at its new place before it moved again is *detected* if, in the snapshot taken when
    it moved again (or at the end), the new place is occupied in D and not in S — else, if S
    holds it, it was *detected static*. Each place a box left and the robot saw empty is
    *cleared* if S is not occupied there in the snapshot before a box came back (or the end).
    """
    walls = np.asarray(truth["walls"], dtype=float)
    max_range, fov = _view(truth)
    times = np.array([t for t, _, _ in snapshots])
    tol = max(tolerance_m, snapshots[0][1].resolution)

    def at(t: float) -> tuple[OccupancyMap, OccupancyMap]:
        k = int(np.searchsorted(times, t - 1e-9))
        _, s, d = snapshots[min(k, len(snapshots) - 1)]
        return s, d

    detected, static_hits, cleared = [], 0, []
    for obj_id, obj, i, arrived, left in _moves(truth):
        place = obj["positions"][i][1]
        if (i > 0 and _seen_after(truth, obj_id, arrived, left)
                and _known_free_before(truth, place, arrived)):
            s, d = at(left)
            ok = _detected(s, d, place, obj["size"], walls, thresholds, tol)
            detected.append(ok)
            if ok is False:
                rr, cc = _footprint(s, place, obj["size"], walls, tol)
                static_hits += int((s.prob[rr, cc] > thresholds.occupied).any())
        later = [t for t, c in obj["positions"][i + 1:] if np.allclose(c, place)]
        others = [t for o in truth["objects"].values() if o["kind"] == "box"
                  for t, c in o["positions"] if t > left and np.allclose(c, place)]
        until = min(later + others) if later or others else times[-1] + 1.0
        if left <= times[-1] and _place_seen_empty(truth, place, left, until, max_range, fov):
            s, _ = at(until)
            cleared.append(_cleared(s, place, obj["size"], walls, thresholds))
    moved = _tally(detected)
    moved["detected_static"] = static_hits
    vacated = _tally(cleared)
    return {"moved_objects_detected": moved,
            "vacated_places_cleared": {"cleared": vacated.pop("detected"), **vacated}}


def truth_changes(truth: dict[str, Any]) -> list[dict[str, Any]]:
    """The change events a run of the simulated world should report: each box's arrival
    at a place (``appeared``, from its time until it left) and each departure (``vacated``,
    from then until a box stood there again), with whether the map could know it: an
    arrival where the robot had seen the floor empty and that it then saw (Table 1 makes
    a box on a place never seen empty static), a departure from a place where the robot
    had seen the box and then saw the floor."""
    max_range, fov = _view(truth)
    end = truth["poses"][-1][0] + 1.0 if truth["poses"] else 0.0
    boxes = [o for o in truth["objects"].values() if o["kind"] == "box"]
    out = []
    for obj_id, obj, i, arrived, left in _moves(truth):
        place = obj["positions"][i][1]
        seen_there = _seen_after(truth, obj_id, arrived, left)
        if i > 0:
            out.append({"kind": "appeared", "object": obj_id, "place": place,
                        "from": arrived, "until": left,
                        "detectable": seen_there and _known_free_before(truth, place, arrived)})
        if left < end:
            back = [t for o in boxes for t, c in o["positions"]
                    if t > left and np.allclose(c, place)]
            until = min(back, default=end)
            out.append({"kind": "vacated", "object": obj_id, "place": place, "from": left,
                        "until": until, "detectable": seen_there and _place_seen_empty(
                            truth, place, left, until, max_range, fov)})
    return out


def score_changes(events: list[ChangeEvent], trajectory: np.ndarray, truth: dict[str, Any],
                  tolerance_m: float = 0.3) -> dict[str, Any]:
    """changes.csv against the truth, its places moved into the truth's frame by the
    alignment the trajectory's ATE uses. An ``appeared`` or ``vacated`` event is right if it
    lies within ``tolerance_m`` of a true event of its kind and was first seen in that
    event's time (one event each, nearest first): precision over all such events, recall
    over the true events the map could know. Walkers: ``moving`` events in a walker's
    loop, and appeared events there that are none of the boxes' (they must never be)."""
    offset = float(truth.get("stamp_offset_s", 0.0))
    events = _aligned_events(events, trajectory, truth)
    true = truth_changes(truth)
    walkers = {k: o for k, o in truth["objects"].items() if o["kind"] == "walker"}
    out: dict[str, Any] = {}
    right: set[int] = set()
    for kind in ("appeared", "vacated"):
        mine = [e for e in events if e.kind == kind]
        theirs = [t for t in true if t["kind"] == kind]
        out[kind], used = _tally_events(mine, theirs, tolerance_m, lambda e, t: (
            t["from"] - 1e-6 <= e.first_s - offset <= t["until"]))
        right.update(mine[i].id for i in used)
    moving = np.array([(e.x, e.y) for e in events if e.kind == "moving"]).reshape(-1, 2)
    stray = np.array([(e.x, e.y) for e in events
                      if e.kind == "appeared" and e.id not in right]).reshape(-1, 2)
    out["moving"] = {"reported": len(moving),
                     "on_walkers": int(_in_loops(moving, walkers, tolerance_m).sum()),
                     "appeared_on_walkers": int(_in_loops(stray, walkers, tolerance_m).sum())}
    return out


def score_closures(closures: np.ndarray, trajectory: np.ndarray, truth: dict[str, Any],
                   tolerance_m: float = 0.1, tolerance_deg: float = 1.0) -> dict[str, Any]:
    """The pose graph's loop closures (rows: the scan numbers of the old and the new node's
    scans, the new seen from the old as matched: x, y, θ) against the truth's poses at
    those scans' stamps: a closure is right where its pose is within ``tolerance_m`` (two
    cells) and ``tolerance_deg`` of the true one; its errors' median and largest."""
    closures = np.asarray(closures, dtype=float).reshape(-1, 5)
    stamps = _on_truth_clock(trajectory, truth)[:, :1]
    scans = closures[:, :2].astype(np.int64).reshape(-1)
    poses = np.asarray(truth["poses"], dtype=float)
    _, at = match_stamps(stamps[scans], poses, 0.01)
    if len(at) < len(scans):
        raise ScoreError("the closures' scans have no true pose at their stamps")
    ends = poses[at].reshape(-1, 2, 4)
    true = seen_from_first(ends[:, 0], ends[:, 1])
    error_m = np.hypot(*(closures[:, 2:4] - true[:, :2]).T)
    error_deg = np.degrees(np.abs(wrap_angles(closures[:, 4] - true[:, 2])))
    right = (error_m <= tolerance_m) & (error_deg <= tolerance_deg)
    return {"right": int(right.sum()), "reported": len(closures),
            "precision": _ratio(right.sum(), len(closures)),
            "error_m_median": float(np.median(error_m)) if len(error_m) else None,
            "error_m_max": float(error_m.max()) if len(error_m) else None,
            "error_deg_max": float(error_deg.max()) if len(error_deg) else None}


def _tally_events(mine: list[ChangeEvent], theirs: list[dict[str, Any]], tolerance_m: float,
                  when: Callable[[ChangeEvent, dict[str, Any]], bool]
                  ) -> tuple[dict[str, Any], set[int]]:
    """Reported events against true ones of a kind: each pair within ``tolerance_m`` (and
    ``when`` allows) matched once, nearest first. The tally (precision over what was
    reported, recall over the true events marked detectable) and the reported ones right."""
    pairs = sorted((math.hypot(e.x - t["place"][0], e.y - t["place"][1]), i, j)
                   for i, e in enumerate(mine) for j, t in enumerate(theirs) if when(e, t))
    used_e: set[int] = set()
    used_t: set[int] = set()
    for d, i, j in pairs:
        if d <= tolerance_m and i not in used_e and j not in used_t:
            used_e.add(i)
            used_t.add(j)
    knowable = {j for j, t in enumerate(theirs) if t["detectable"]}
    return {"reported": len(mine), "right": len(used_e),
            "precision": _ratio(len(used_e), len(mine)),
            "true": len(knowable), "found": len(used_t & knowable),
            "recall": _ratio(len(used_t & knowable), len(knowable))}, used_e


def truth_prior_changes(truth: dict[str, Any]) -> list[dict[str, Any]]:
    """The events a later session on the earlier one's map should report, from the
    fixtures changed in between: ``removed_since_prior`` where one stood (detectable if this
    session saw the place empty), ``added_since_prior`` where one stands now (if this
    session saw it there)."""
    max_range, fov = _view(truth)
    end = truth["poses"][-1][0] + 1.0 if truth["poses"] else 0.0
    out = []
    for change in truth.get("prior_changes", []):
        if change["from"] is not None:
            out.append({"kind": "removed_since_prior", "object": change["object"],
                        "place": change["from"], "detectable": _place_seen_empty(
                            truth, change["from"], 0.0, end, max_range, fov)})
        if change["to"] is not None:
            out.append({"kind": "added_since_prior", "object": change["object"],
                        "place": change["to"],
                        "detectable": _seen_after(truth, change["object"], 0.0, end)})
    return out


def score_sessions(events: list[ChangeEvent], trajectory: np.ndarray, truth: dict[str, Any],
                   tolerance_m: float = 0.3) -> dict[str, Any]:
    """A later session run on the earlier one's map (``--prior``), whose frame is the
    truth's: the trajectory's error there (no alignment) and the between-session events
    (``*_since_prior``) matched to the fixtures' changes within ``tolerance_m``."""
    est = _on_truth_clock(trajectory, truth)
    ref = np.asarray(truth["poses"], dtype=float)
    i, j = _enough_matched(est, ref, 1e-3)
    error = np.hypot(*(est[i, 1:3] - ref[j, 1:3]).T)
    out: dict[str, Any] = {"ate_in_prior_frame_m": float(np.sqrt(np.mean(error ** 2)))}
    true = truth_prior_changes(truth)
    for kind in ("removed_since_prior", "added_since_prior"):
        out[kind], _ = _tally_events([e for e in events if e.kind == kind],
                                     [t for t in true if t["kind"] == kind], tolerance_m,
                                     lambda e, t: True)
    return out


def _aligned_events(events: list[ChangeEvent], trajectory: np.ndarray, truth: dict[str, Any]
                    ) -> list[ChangeEvent]:
    """The events with their places in the truth's frame: the rigid alignment of the
    trajectory's positions onto the true ones at the same stamps (as for the ATE)."""
    est = _on_truth_clock(trajectory, truth)
    ref = np.asarray(truth["poses"], dtype=float)
    i, j = match_stamps(est, ref, 1e-3)
    if len(i) < 2 or not events:
        return events
    a, b = est[i, 1:3], ref[j, 1:3]
    _, angle = align_se2(a, b)
    c, s = math.cos(angle), math.sin(angle)
    moved = (np.array([(e.x, e.y) for e in events]) - a.mean(0)) @ np.array([[c, s], [-s, c]])
    moved += b.mean(0)
    return [dataclasses.replace(e, x=float(x), y=float(y)) for e, (x, y) in zip(events, moved,
                                                                               strict=True)]


def _in_loops(points: np.ndarray, walkers: dict[str, Any], tolerance_m: float) -> np.ndarray:
    """Whether each point lies within a walker's loop (its waypoints' hull) or within
    ``tolerance_m`` of its path (less its radius): a track's centre lies inside the curve
    it walked."""
    from scipy.spatial import Delaunay

    inside = np.zeros(len(points), bool)
    if not len(points):
        return inside
    for obj in walkers.values():
        loop = np.asarray(obj["loop"], dtype=float)
        inside |= Delaunay(loop).find_simplex(points) >= 0
    return inside | (mover_distance(points, walkers) <= tolerance_m) if walkers else inside


def _score_landmarks(landmarks: list[Landmark], truth: dict[str, Any], objects: dict[str, Any],
                     tol: float) -> dict[str, Any]:
    static = [lm for lm in landmarks if lm.cls == "static"]
    if not static:
        return {"static": 0, "on_true_corners": None, "static_on_movers": 0}
    pts = np.array([(lm.x, lm.y) for lm in static])
    corners = np.asarray(truth.get("static_corners", []), dtype=float).reshape(-1, 2)
    if len(corners):
        d = np.sqrt(((pts[:, None, :] - corners[None, :, :]) ** 2).sum(-1)).min(1)
    else:
        d = np.full(len(pts), np.inf)
    walls = np.asarray(truth["walls"], dtype=float)
    on_movers = (mover_distance(pts, objects) <= tol) & (distance_to_segments(pts, walls) > tol)
    return {"static": len(static), "on_true_corners": _ratio((d <= tol).sum(), len(pts)),
            "static_on_movers": int(on_movers.sum())}


# -- Kümmerle et al. (2009) relations -------------------------------------------------------
def relation_errors(trajectory: np.ndarray, relations: np.ndarray, max_dt: float = 0.1,
                    frame: tuple[float, float] = (0.0, 0.0)) -> dict[str, Any]:
    """The relation metric as the Freiburg metricEvaluator reports it.

    ``relations`` rows: t1 t2 x y z roll pitch yaw (pose at t2 in the frame of t1). Each
    stamp is matched to the nearest estimated pose within ``max_dt``; the estimated relation
    inv(P1)·P2 minus the reference, component-wise (angle wrapped), gives the translational
    error sqrt(dx² + dy²) and the rotational error |dθ|.

    ``frame``: where on the robot the relations' poses are, (x, y) metres in the
    trajectory's frame (a laser mounted 0.1 m ahead of the wheels' centre: (0.1, 0), if the
    relations are of the laser's poses and the trajectory of the robot's). The report's
    ``fitted_frame`` is the (x, y) whose relations match best (:func:`fitted_frame`) and
    the error there: far from ``frame`` when the two frames differ by a mount the log does
    not state.
    """
    if not len(trajectory) or not len(relations):
        raise ScoreError(f"nothing to score: {len(trajectory)} poses, {len(relations)} relations")
    i1, j1 = match_stamps(relations[:, [0]], trajectory, max_dt)
    i2, j2 = match_stamps(relations[:, [1]], trajectory, max_dt)
    have1 = np.full(len(relations), -1)
    have1[i1] = j1
    have2 = np.full(len(relations), -1)
    have2[i2] = j2
    ok = (have1 >= 0) & (have2 >= 0)
    t0, t1 = trajectory[:, 0].min() - max_dt, trajectory[:, 0].max() + max_dt
    in_span = int(((relations[:, :2] >= t0) & (relations[:, :2] <= t1)).all(axis=1).sum())
    if not ok.any() or ok.sum() < MIN_MATCHED * in_span:
        raise ScoreError(f"only {int(ok.sum())} of {len(relations)} relations ({in_span} within "
                         f"the trajectory's {_span(trajectory)}) have both poses within "
                         f"{max_dt:g} s: not the same run, or its stamps are shifted")
    rel = relations[ok][:, [2, 3, 7]]
    est = seen_from_first(trajectory[have1[ok]], trajectory[have2[ok]])
    trans = _translation_errors(seen_from(est, frame), rel)
    rot = np.degrees(np.abs(wrap_angles(est[:, 2] - rel[:, 2])))
    fit = fitted_frame(est, rel)

    def stats(v: np.ndarray) -> dict[str, float | None]:
        if not len(v):
            return {"mean": None, "std": None}
        return {"mean": float(v.mean()), "std": float(v.std(ddof=1)) if len(v) > 1 else 0.0}

    return {"relations": len(relations), "matched": int(ok.sum()),
            "unmatched": int((~ok).sum()),
            "frame": {"x_m": frame[0], "y_m": frame[1]},
            "translational_m": stats(trans), "translational_squared_m2": stats(trans ** 2),
            "rotational_deg": stats(rot), "rotational_squared_deg2": stats(rot ** 2),
            "fitted_frame": {"x_m": fit[0], "y_m": fit[1], "translational_m": stats(
                _translation_errors(seen_from(est, fit), rel))}}


def seen_from_first(first: np.ndarray, second: np.ndarray) -> np.ndarray:
    """Each pose of ``second`` in the frame of the pose of ``first`` on its row (rows stamp,
    x, y, θ): rows x, y, θ."""
    c, s = np.cos(first[:, 3]), np.sin(first[:, 3])
    dx, dy = second[:, 1] - first[:, 1], second[:, 2] - first[:, 2]
    return np.column_stack((c * dx + s * dy, -s * dx + c * dy,
                            wrap_angles(second[:, 3] - first[:, 3])))


def seen_from(est: np.ndarray, frame: tuple[float, float]) -> np.ndarray:
    """Relations (rows x, y, θ: a pose in the frame of another) of the robot's centre, as
    the frame at ``frame`` = (a, b) on the robot sees them: F⁻¹ · rel · F."""
    (a, b), c, s = frame, np.cos(est[:, 2]), np.sin(est[:, 2])
    return np.column_stack((est[:, 0] + a * (c - 1) - b * s, est[:, 1] + a * s + b * (c - 1),
                            est[:, 2]))


def fitted_frame(est: np.ndarray, rel: np.ndarray) -> tuple[float, float]:
    """The frame (a, b) on the robot (metres in its frame) from which the estimated
    relations ``est`` best match the reference ``rel`` (rows x, y, θ), least squares: their
    translations are linear in (a, b) (:func:`seen_from`). (0, 0) if no relation turns."""
    c, s = np.cos(est[:, 2]), np.sin(est[:, 2])
    a = np.vstack((np.column_stack((c - 1, -s)), np.column_stack((s, c - 1))))
    r = np.concatenate((rel[:, 0] - est[:, 0], rel[:, 1] - est[:, 1]))
    ab = np.linalg.lstsq(a, r, rcond=None)[0] if np.abs(a).max() > 1e-9 else np.zeros(2)
    return float(ab[0]), float(ab[1])


def _translation_errors(est: np.ndarray, rel: np.ndarray) -> np.ndarray:
    return np.hypot(est[:, 0] - rel[:, 0], est[:, 1] - rel[:, 1])
