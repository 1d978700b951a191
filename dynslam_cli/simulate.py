"""A 2D simulator of dynamic worlds that produces laser scans, drifting odometry and the
ground truth, after the paper's Stage experiments (Sec. 5).

A :class:`World` holds static wall segments, *boxes* (occasional movers: they stand still and
are relocated at set times, in view of the robot or out of it) and *walkers* (persistent
movers: discs that walk their own loops all the time). A robot follows a route that revisits
places; its laser is ray-cast against everything; its odometry integrates the true motion
with systematic scale and heading errors plus random noise.

Nothing here touches files: :func:`simulate` yields :class:`SimStep` records and fills a
:class:`Truth`; the CLI writes them with the format writers.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass, field, fields

import numpy as np

from dynslam_cli.geometry import (
    compose,
    distance_to_segments,
    relative,
    segment_crosses,
    wrap_angle,
)
from dynslam_cli.types import Pose2D

WORLD_NAMES = ("corridors", "arena", "hall", "crowd", "office", "wards")
SEEN_BEFORE_MOVE = 10  # scans that must hit a box at its place before it is moved again

# Fixtures: furniture that stands still through a session and may be moved between sessions
# (``dynslam simulate --sessions``). 0.4 m square, kept clear of walls (objects close to walls
# are a problem of their own), of the robot's path and of everything else that moves, and in
# view of the path.
FIXTURE_HALF_M = 0.2
FIXTURE_WALL_GAP_M = 0.25
FIXTURE_PATH_GAP_M = 0.7
FIXTURE_MOVER_GAP_M = 0.8
FIXTURE_VIEW_M = 3.5
FIXTURE_SPACING_M = 1.5
FIXTURE_VIEW_STEPS = 30  # steps of the path from which a fixture's spot is in sight
FIXTURE_SPOTS = 8  # places a world's fixtures may stand
FIXTURES = 5  # standing in the first session


@dataclass(frozen=True)
class LaserModel:
    beams: int = 181
    fov_deg: float = 180.0
    max_range_m: float = 8.0
    noise_m: float = 0.01
    """Standard deviation of the range noise (metres)."""


@dataclass(frozen=True)
class OdometryNoise:
    """Odometry error model; everything 0 gives odometry equal to the truth."""

    scale_error: float = 0.02
    """Systematic translation scale error (fraction)."""
    heading_bias_deg_per_m: float = 0.1
    """Systematic heading drift per metre driven (degrees)."""
    rotation_scale_error: float = 0.01
    """Systematic rotation scale error (fraction)."""
    sigma_m_per_sqrt_m: float = 0.01
    sigma_deg_per_sqrt_rad: float = 0.5
    lateral_sigma_m_per_sqrt_m: float = 0.0
    """Sideways slip, random (wheeled robots: small; 0 draws nothing)."""

    def scaled(self, factor: float) -> OdometryNoise:
        return OdometryNoise(*(factor * getattr(self, f.name) for f in fields(self)))


@dataclass
class Box:
    """An occasional mover: an axis-aligned rectangle relocated between ``spots``."""

    id: str
    half_x: float
    half_y: float
    spots: list[tuple[float, float]]
    spot: int = 0

    @property
    def center(self) -> tuple[float, float]:
        return self.spots[self.spot]

    def segments(self, center: tuple[float, float] | None = None) -> np.ndarray:
        cx, cy = center if center is not None else self.center
        x0, x1, y0, y1 = cx - self.half_x, cx + self.half_x, cy - self.half_y, cy + self.half_y
        return np.array([[x0, y0, x1, y0], [x1, y0, x1, y1], [x1, y1, x0, y1], [x0, y1, x0, y0]])


PAUSE_EVERY_M = 4.0  # a stop-and-go walker stands still after every this many metres


@dataclass
class Walker:
    """A persistent mover: a disc walking a closed loop of waypoints at constant speed, and
    where ``pause_s`` is set, standing still that long after every ``PAUSE_EVERY_M`` walked
    (a person who stops and walks on)."""

    id: str
    radius: float
    loop: list[tuple[float, float]]
    speed: float
    phase_m: float = 0.0
    pause_s: float = 0.0

    def walked(self, t: float) -> float:
        """Metres walked by time ``t``."""
        if self.pause_s <= 0:
            return self.speed * t
        leg_s = PAUSE_EVERY_M / self.speed
        legs, into = divmod(t, leg_s + self.pause_s)
        return legs * PAUSE_EVERY_M + self.speed * min(into, leg_s)

    def position(self, t: float) -> tuple[float, float]:
        pts = np.array([*self.loop, self.loop[0]], dtype=float)
        seg = np.hypot(*np.diff(pts, axis=0).T)
        s = (self.phase_m + self.walked(t)) % seg.sum()
        i = int(np.searchsorted(np.cumsum(seg), s, side="right"))
        i = min(i, len(seg) - 1)
        f = (s - (np.cumsum(seg)[i] - seg[i])) / seg[i]
        p = pts[i] + f * (pts[i + 1] - pts[i])
        return float(p[0]), float(p[1])


@dataclass
class World:
    name: str
    walls: np.ndarray  # K×4 segments x1 y1 x2 y2
    route: list[tuple[float, float]]
    start: Pose2D
    boxes: list[Box] = field(default_factory=list)
    walkers: list[Walker] = field(default_factory=list)
    relocations: int = 0
    relocate_in_view: bool = False
    speed: float = 0.5
    fixtures: list[Box] = field(default_factory=list)
    first_waypoint: int = 0

    @property
    def structure(self) -> np.ndarray:
        """What stands still all run: the walls and the fixtures' sides (K×4 segments)."""
        return np.vstack([self.walls, *(f.segments() for f in self.fixtures)])

    def static_corners(self) -> list[tuple[float, float]]:
        """End points shared by two non-collinear walls or fixture sides: the true static
        corners."""
        ends: dict[tuple[float, float], list[int]] = {}
        structure = self.structure
        for k, (x1, y1, x2, y2) in enumerate(structure):
            for p in ((round(x1, 6), round(y1, 6)), (round(x2, 6), round(y2, 6))):
                ends.setdefault(p, []).append(k)
        corners = []
        for p, ks in ends.items():
            if len(ks) >= 2:
                a, b = structure[ks[0]], structure[ks[1]]
                da, db = a[2:] - a[:2], b[2:] - b[:2]
                if abs(da[0] * db[1] - da[1] * db[0]) > 1e-9:
                    corners.append(p)
        return sorted(corners)


def _rect(x0: float, y0: float, x1: float, y1: float) -> list[list[float]]:
    return [[x0, y0, x1, y0], [x1, y0, x1, y1], [x1, y1, x0, y1], [x0, y1, x0, y0]]


def build_world(name: str, seed: int = 0, walkers: int | None = None) -> World:
    """One of the built-in worlds (:data:`WORLD_NAMES`)."""
    rng = np.random.default_rng(seed)
    if name == "corridors":
        # A ring of 2.4 m corridors around a 20 m × 10 m block, with six alcoves where boxes
        # are kept; boxes are always moved while the robot is elsewhere (Table 4, corridors).
        walls = [[0, 0, 0, 16], [26, 0, 26, 16], *_rect(3, 3, 23, 13)]
        alcove_x = (6.0, 13.0, 20.0)
        for y, d in ((0.0, -1.0), (16.0, 1.0)):
            xs = [0.0] + [v for ax in alcove_x for v in (ax - 0.8, ax + 0.8)] + [26.0]
            walls += [[xs[i], y, xs[i + 1], y] for i in range(0, len(xs), 2)]
            for ax in alcove_x:  # 1.6 m wide, 1.0 m deep notches in the outer wall
                walls += [[ax - 0.8, y, ax - 0.8, y + d], [ax - 0.8, y + d, ax + 0.8, y + d],
                          [ax + 0.8, y + d, ax + 0.8, y]]
        boxes = [Box("box0", 0.35, 0.3, [(6.0, -0.45), (13.0, 16.45), (20.0, -0.45)]),
                 Box("box1", 0.35, 0.3, [(13.0, -0.45), (20.0, 16.45), (6.0, 16.45)])]
        route = [(1.5, 1.5), (24.5, 1.5), (24.5, 14.5), (1.5, 14.5)]
        return World(name, np.array(walls, float), route, Pose2D(1.5, 8.0, -math.pi / 2),
                     boxes=boxes, relocations=20, speed=0.8)
    if name == "arena":
        # A 12 m × 12 m room with four pillars; boxes moved in front of the robot.
        walls = _rect(0, 0, 12, 12) + _rect(3, 3, 3.6, 3.6) + _rect(8.4, 3, 9, 3.6) \
            + _rect(3, 8.4, 3.6, 9) + _rect(8.4, 8.4, 9, 9)
        boxes = [Box("box0", 0.3, 0.3, [(6.0, 4.5), (7.5, 6.0), (6.0, 7.5), (4.5, 6.0)]),
                 Box("box1", 0.25, 0.4, [(9.0, 6.0), (6.0, 9.0), (3.0, 6.0), (6.0, 3.0)])]
        route = [(1.5, 1.5), (10.5, 1.5), (10.5, 10.5), (1.5, 10.5)]
        return World(name, np.array(walls, float), route, Pose2D(1.5, 6.0, -math.pi / 2),
                     boxes=boxes, relocations=20, relocate_in_view=True)
    if name == "hall":
        # 19 m × 11 m hall with columns, 2-10 robots walking loops, boxes moved out of view.
        walls = _rect(0, 0, 19, 11) + _rect(6, 3.5, 6.6, 4.1) + _rect(12.4, 3.5, 13, 4.1) \
            + _rect(6, 6.9, 6.6, 7.5) + _rect(12.4, 6.9, 13, 7.5) + [[9.5, 0, 9.5, 2.0]]
        n = 4 if walkers is None else walkers
        if not 2 <= n <= 10:
            raise ValueError("hall has 2 to 10 walkers")
        loops = []
        for k in range(n):
            cx, cy = 4.0 + 11.0 * rng.random(), 3.5 + 4.0 * rng.random()
            r = 0.6 + 0.6 * rng.random()
            loops.append(Walker(f"robot{k}", 0.2, [(cx - r, cy - r), (cx + r, cy - r),
                                                   (cx + r, cy + r), (cx - r, cy + r)],
                                0.3 + 0.2 * rng.random(), float(rng.random() * 4)))
        boxes = [Box("box0", 0.3, 0.3, [(17.8, 9.8), (17.8, 1.2), (1.2, 9.8)]),
                 Box("box1", 0.3, 0.3, [(1.2, 1.2), (9.5, 9.8), (17.8, 5.5)])]
        route = [(2.5, 2.0), (16.5, 2.0), (16.5, 9.0), (2.5, 9.0)]
        return World(name, np.array(walls, float), route, Pose2D(2.5, 5.5, -math.pi / 2),
                     boxes=boxes, walkers=loops, relocations=6)
    if name == "crowd":
        # 14 m × 10 m open space; three people walking round the robot (Sec. 5.2).
        walls = _rect(0, 0, 14, 10) + _rect(0, 4.0, 1.0, 6.0)
        people = [Walker(f"person{k}", 0.22,
                         [(7 + 3.2 * math.cos(a), 5 + 3.2 * math.sin(a))
                          for a in np.linspace(0, 2 * math.pi, 12, endpoint=False) + k],
                         0.6 + 0.15 * k, 0.0) for k in range(3)]
        route = [(5.5, 4.0), (8.5, 4.0), (8.5, 6.0), (5.5, 6.0)]
        return World(name, np.array(walls, float), route, Pose2D(5.5, 5.0, -math.pi / 2),
                     walkers=people, speed=0.3)
    if name == "office":
        # Hard on purpose: a 50 m corridor, 2 m wide, with two door recesses only (the walls
        # say nothing about where along it the robot is), opening into a 24 m × 24 m hall
        # with two pillars, where the 8 m laser often sees one wall or none. Boxes are
        # moved out of view along the hall's walls.
        walls = [[0, -1, 50, -1], [0, 1, 14.5, 1], [15.5, 1, 34.5, 1], [35.5, 1, 50, 1],
                 [0, -1, 0, 1], [50, -12, 74, -12], [74, -12, 74, 12], [74, 12, 50, 12],
                 [50, 12, 50, 1], [50, -1, 50, -12]]
        for x in (14.5, 34.5):  # 1 m doors, 0.4 m deep
            walls += [[x, 1, x, 1.4], [x, 1.4, x + 1, 1.4], [x + 1, 1.4, x + 1, 1]]
        walls += _rect(59.7, -2.3, 60.3, -1.7) + _rect(64.7, 2.7, 65.3, 3.3)
        boxes = [Box("box0", 0.3, 0.3, [(72.5, -10.5), (72.5, 10.5), (51.5, 10.5)])]
        route = [(2.0, 0.0), (48.0, 0.0), (56.0, -7.0), (68.0, -7.0), (68.0, 7.0),
                 (56.0, 7.0), (48.0, 0.0)]
        return World(name, np.array(walls, float), route, Pose2D(2.0, 0.0, 0.0),
                     boxes=boxes, relocations=6, speed=0.8)
    if name == "wards":
        # Hard on purpose: look-alike corridors. A ring of 3 m corridors round a 34 m × 8 m
        # block, with a 1 m door recess every 4 m along both long outer walls: any stretch
        # of a long corridor looks like the stretch 4 m on, and like the other long
        # corridor turned round (the ring is the same after a half turn). Boxes stand by
        # the block's wall, 0.25 m from it, and are moved while the robot is elsewhere.
        walls = [[0, 0, 0, 14], [40, 0, 40, 14], *_rect(3, 3, 37, 11)]
        doors = np.arange(4.0, 37.0, 4.0)
        for y, d in ((0.0, -0.5), (14.0, 0.5)):
            xs = [0.0] + [v for x in doors for v in (x - 0.5, x + 0.5)] + [40.0]
            walls += [[xs[i], y, xs[i + 1], y] for i in range(0, len(xs), 2)]
            for x in doors:
                walls += [[x - 0.5, y, x - 0.5, y + d], [x - 0.5, y + d, x + 0.5, y + d],
                          [x + 0.5, y + d, x + 0.5, y]]
        boxes = [Box("box0", 0.3, 0.2, [(10.0, 2.55), (26.0, 11.45), (30.0, 2.55)]),
                 Box("box1", 0.3, 0.2, [(22.0, 2.55), (14.0, 11.45), (34.0, 11.45)])]
        route = [(1.5, 1.5), (38.5, 1.5), (38.5, 12.5), (1.5, 12.5)]
        return World(name, np.array(walls, float), route, Pose2D(1.5, 7.0, -math.pi / 2),
                     boxes=boxes, relocations=12, speed=0.8)
    raise ValueError(f"unknown world {name!r}; built-in: {', '.join(WORLD_NAMES)}")


def ray_cast(origin: Pose2D, angles: np.ndarray, segments: np.ndarray, seg_owner: np.ndarray,
             discs: np.ndarray, disc_owner: np.ndarray, max_range: float
             ) -> tuple[np.ndarray, np.ndarray]:
    """Distance along each beam to the first segment or disc, and the owner index it hit
    (-1 walls/nothing is encoded by the caller's owner arrays; -2 = no return)."""
    a = angles + origin.theta
    d = np.column_stack((np.cos(a), np.sin(a)))
    p = np.array([origin.x, origin.y])
    best = np.full(len(a), np.inf)
    owner = np.full(len(a), -2, dtype=np.int64)
    if len(segments):
        q, e = segments[:, :2], segments[:, 2:] - segments[:, :2]
        denom = d[:, None, 0] * e[None, :, 1] - d[:, None, 1] * e[None, :, 0]
        w = q[None, :, :] - p[None, None, :]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (w[..., 0] * e[None, :, 1] - w[..., 1] * e[None, :, 0]) / denom
            u = (w[..., 0] * d[:, None, 1] - w[..., 1] * d[:, None, 0]) / denom
        ok = (np.abs(denom) > 1e-12) & (t > 1e-9) & (u >= 0) & (u <= 1)
        t = np.where(ok, t, np.inf)
        j = np.argmin(t, axis=1)
        best = t[np.arange(len(a)), j]
        owner = np.where(np.isfinite(best), seg_owner[j], -2)
    if len(discs):
        c, r = discs[:, :2], discs[:, 2]
        w = c[None, :, :] - p[None, None, :]
        proj = w[..., 0] * d[:, None, 0] + w[..., 1] * d[:, None, 1]
        dist2 = (w ** 2).sum(-1) - proj ** 2
        with np.errstate(invalid="ignore"):
            t = proj - np.sqrt(r[None, :] ** 2 - dist2)
        t = np.where((dist2 <= r[None, :] ** 2) & (t > 1e-9), t, np.inf)
        j = np.argmin(t, axis=1)
        td = t[np.arange(len(a)), j]
        closer = td < best
        best = np.where(closer, td, best)
        owner = np.where(closer, disc_owner[j], owner)
    far = best >= max_range
    owner[far] = -2
    return np.where(far, max_range, best), owner


@dataclass(frozen=True)
class SimStep:
    stamp: float
    truth: Pose2D
    odom: Pose2D
    ranges: np.ndarray
    hits: tuple[str, ...]


@dataclass
class Truth:
    """Everything known about a simulated run (written as truth.json)."""

    world: str
    seed: int
    laser: LaserModel
    walls: list[list[float]]
    corners: list[tuple[float, float]]
    poses: list[tuple[float, float, float, float]] = field(default_factory=list)
    odometry: list[tuple[float, float, float, float]] = field(default_factory=list)
    objects: dict[str, dict] = field(default_factory=dict)
    events: list[dict] = field(default_factory=list)
    hits: list[list[str]] = field(default_factory=list)
    stamp_offset_s: float = 0.0  # the log's stamps are the truth's times plus this
    session: int = 1
    fixtures: dict[str, dict] = field(default_factory=dict)
    prior_changes: list[dict] = field(default_factory=list)
    """Fixtures moved since the session before: {"object", "from", "to"}, either place None
    for one taken away or brought in."""


def _world_geometry(world: World, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                       np.ndarray, list[str]]:
    blocks = world.boxes + world.fixtures
    names = ["wall"] + [b.id for b in blocks] + [w.id for w in world.walkers]
    segs = [world.walls] + [b.segments() for b in blocks]
    owner = [np.zeros(len(world.walls), np.int64)] + [np.full(4, 1 + i, np.int64)
                                                     for i in range(len(blocks))]
    discs = np.array([(*w.position(t), w.radius) for w in world.walkers]).reshape(-1, 3)
    disc_owner = 1 + len(blocks) + np.arange(len(world.walkers), dtype=np.int64)
    return np.vstack(segs), np.concatenate(owner), discs, disc_owner, names


def simulate(world: World, duration_s: float, rate_hz: float = 10.0, seed: int = 0,
             laser: LaserModel | None = None, noise: OdometryNoise | None = None,
             odometry_start: Pose2D | None = None) -> tuple[Iterator[SimStep], Truth]:
    """Drive the route for ``duration_s``; returns the step stream and the truth it fills.
    The odometry starts at ``odometry_start`` (default: the true start, so the log's frame
    is the world's)."""
    laser = laser or LaserModel()
    noise = noise if noise is not None else OdometryNoise()
    truth = Truth(world=world.name, seed=seed, laser=laser, walls=world.structure.tolist(),
                  corners=world.static_corners())
    truth.fixtures = {f.id: {"place": list(f.center), "size": [2 * f.half_x, 2 * f.half_y]}
                      for f in world.fixtures}
    for b in world.boxes:
        truth.objects[b.id] = {"kind": "box", "size": [2 * b.half_x, 2 * b.half_y],
                               "positions": [[0.0, list(b.center)]]}
    for w in world.walkers:
        truth.objects[w.id] = {"kind": "walker", "radius": w.radius, "loop": w.loop,
                               "speed": w.speed, "phase_m": w.phase_m,
                               **({"pause_s": w.pause_s} if w.pause_s else {})}
    odom = world.start if odometry_start is None else odometry_start
    return _run(world, duration_s, rate_hz, seed, laser, noise, truth, odom), truth


def _run(world: World, duration_s: float, rate_hz: float, seed: int, laser: LaserModel,
         noise: OdometryNoise, truth: Truth, odom: Pose2D) -> Iterator[SimStep]:
    rng = np.random.default_rng(seed + 1)
    dt = 1.0 / rate_hz
    fov = math.radians(laser.fov_deg)
    angles = -fov / 2 + fov / max(laser.beams - 1, 1) * np.arange(laser.beams)
    pose = world.start
    target = world.first_waypoint
    n_steps = round(duration_s * rate_hz) + 1
    # Relocations spread over the first 3/4 of the run, so the robot revisits afterwards.
    event_times = [(k + 1) * 0.75 * duration_s / (world.relocations + 1)
                   for k in range(world.relocations)]
    next_event = 0
    # A box is moved again only after the robot has had a look at it where it was put (as
    # the experimenters of Table 4 did), so every relocation can be judged.
    seen_since_move = {o.id: 0 for o in [*world.boxes, *world.fixtures, *world.walkers]}
    for step in range(n_steps):
        t = step * dt
        segs, owner, discs, disc_owner, names = _world_geometry(world, t)
        if next_event < len(event_times) and t >= event_times[next_event]:
            box = world.boxes[next_event % len(world.boxes)]
            if seen_since_move[box.id] >= SEEN_BEFORE_MOVE and _try_relocate(
                    world, box, pose, angles, laser, t, truth):
                seen_since_move[box.id] = 0
                next_event += 1
                segs, owner, discs, disc_owner, names = _world_geometry(world, t)
        ranges, hit_owner = ray_cast(pose, angles, segs, owner, discs, disc_owner,
                                     laser.max_range_m)
        valid = hit_owner != -2
        if laser.noise_m > 0:
            ranges = np.where(valid, ranges + rng.normal(0, laser.noise_m, len(ranges)), ranges)
            ranges = np.where(valid, np.clip(ranges, 0.03, laser.max_range_m - 1e-3), ranges)
        hits = tuple(sorted({names[k] for k in hit_owner[hit_owner > 0]}))
        for name in hits:
            seen_since_move[name] += 1
        truth.poses.append((t, pose.x, pose.y, pose.theta))
        truth.odometry.append((t, odom.x, odom.y, odom.theta))
        truth.hits.append(list(hits))
        yield SimStep(stamp=t, truth=pose, odom=odom, ranges=ranges, hits=hits)
        new_pose, target = _drive(world, pose, target, dt)
        odom = compose(odom, noisy_increment(relative(pose, new_pose), noise, rng))
        pose = new_pose


def _drive(world: World, pose: Pose2D, target: int, dt: float) -> tuple[Pose2D, int]:
    """Unicycle steering toward the next route waypoint."""
    tx, ty = world.route[target]
    if math.hypot(tx - pose.x, ty - pose.y) < 0.4:
        target = (target + 1) % len(world.route)
        tx, ty = world.route[target]
    err = wrap_angle(math.atan2(ty - pose.y, tx - pose.x) - pose.theta)
    omega = max(-1.0, min(1.0, 2.0 * err))
    v = world.speed * max(0.0, math.cos(err)) ** 2
    th = pose.theta + 0.5 * omega * dt
    return Pose2D(pose.x + v * dt * math.cos(th), pose.y + v * dt * math.sin(th),
                  wrap_angle(pose.theta + omega * dt)), target


def noisy_increment(inc: Pose2D, noise: OdometryNoise, rng: np.random.Generator) -> Pose2D:
    """A motion increment (robot frame) as a wheel odometry with ``noise`` would report it:
    scale errors, a heading bias per metre, and random errors growing with the square root
    of the distance driven and the angle turned."""
    dist, rot = math.hypot(inc.x, inc.y), abs(inc.theta)
    scale = 1.0 + noise.scale_error
    sx = rng.normal(0, noise.sigma_m_per_sqrt_m * math.sqrt(dist)) if dist else 0.0
    sth = rng.normal(0, math.radians(noise.sigma_deg_per_sqrt_rad) * math.sqrt(rot + dist))
    dth = (inc.theta * (1.0 + noise.rotation_scale_error)
           + math.radians(noise.heading_bias_deg_per_m) * dist + sth)
    sy = (rng.normal(0, noise.lateral_sigma_m_per_sqrt_m * math.sqrt(dist))
          if dist and noise.lateral_sigma_m_per_sqrt_m else 0.0)
    return Pose2D(inc.x * scale + sx, inc.y * scale + sy, dth)


def _box_visible(world: World, box: Box, center: tuple[float, float], pose: Pose2D,
                 angles: np.ndarray, laser: LaserModel, t: float) -> bool:
    spot = box.spot
    box.spot = box.spots.index(center)
    segs, owner, discs, disc_owner, names = _world_geometry(world, t)
    box.spot = spot
    _, hit = ray_cast(pose, angles, segs, owner, discs, disc_owner, laser.max_range_m)
    return names.index(box.id) in hit


def _try_relocate(world: World, box: Box, pose: Pose2D, angles: np.ndarray,
                  laser: LaserModel, t: float, truth: Truth) -> bool:
    """Move ``box`` to its next spot if the view condition holds now; record the event."""
    old, new = box.center, box.spots[(box.spot + 1) % len(box.spots)]
    seen = (_box_visible(world, box, old, pose, angles, laser, t)
            or _box_visible(world, box, new, pose, angles, laser, t))
    if seen != world.relocate_in_view:
        return False
    box.spot = (box.spot + 1) % len(box.spots)
    truth.objects[box.id]["positions"].append([t, list(new)])
    truth.events.append({"time": t, "object": box.id, "from": list(old), "to": list(new),
                         "in_view": seen})
    return True


# -- sessions: the same world on another day ------------------------------------------------
def driven_path(world: World, steps: int = 3000, dt: float = 0.1) -> np.ndarray:
    """The robot's positions (N×2) over its first ``steps`` steps from the start."""
    pose, target = world.start, world.first_waypoint
    out = np.empty((steps, 2))
    for k in range(steps):
        out[k] = pose.x, pose.y
        pose, target = _drive(world, pose, target, dt)
    return out


def fixture_spots(world: World, seed: int) -> list[tuple[float, float]]:
    """FIXTURE_SPOTS places where a fixture may stand: clear of the walls, of the robot's path,
    of the walkers' loops and the boxes' spots, apart from one another, and in sight of
    FIXTURE_VIEW_STEPS steps of the path within FIXTURE_VIEW_M. Drawn at random from
    ``seed``."""
    rng = np.random.default_rng(seed + 2)
    path = driven_path(world)
    ends = world.walls.reshape(-1, 2)
    candidates = ends.min(0) + (ends.max(0) - ends.min(0)) * rng.random((5000, 2))
    half_diagonal = FIXTURE_HALF_M * math.sqrt(2)
    keep = distance_to_segments(candidates, world.walls) >= FIXTURE_HALF_M + FIXTURE_WALL_GAP_M
    path_segments = np.hstack((path[:-5:5], path[5::5]))
    to_path = distance_to_segments(candidates, path_segments)
    keep &= (to_path >= FIXTURE_PATH_GAP_M + half_diagonal) & (to_path <= FIXTURE_VIEW_M)
    for w in world.walkers:
        loop = np.array([*w.loop, w.loop[0]], dtype=float)
        keep &= (distance_to_segments(candidates, np.hstack((loop[:-1], loop[1:])))
                 >= w.radius + FIXTURE_MOVER_GAP_M + half_diagonal)
    for b in world.boxes:
        for spot in b.spots:
            keep &= (distance_to_segments(candidates, b.segments(spot))
                     >= FIXTURE_MOVER_GAP_M + half_diagonal)
    spots: list[tuple[float, float]] = []
    for c in candidates[keep]:
        if any(math.dist(c, s) < FIXTURE_SPACING_M for s in spots):
            continue
        near = path[((path - c) ** 2).sum(1) <= FIXTURE_VIEW_M ** 2]
        if sum(not segment_crosses(np.array([*p, *c]), world.walls)
               for p in near) >= FIXTURE_VIEW_STEPS:
            spots.append((round(float(c[0]), 3), round(float(c[1]), 3)))
            if len(spots) == FIXTURE_SPOTS:
                return spots
    raise ValueError(f"{world.name}: room for {len(spots)} fixtures, not {FIXTURE_SPOTS}")


def furnish(world: World, seed: int) -> list[tuple[float, float]]:
    """Make ``world`` a first session's: FIXTURES fixtures standing in it, and its boxes
    standing still (what changes is what changes between sessions, so that each session's
    start sees the world as the one before left it); returns every spot a fixture may stand
    on in later sessions."""
    world.relocations = 0
    spots = fixture_spots(world, seed)
    world.fixtures = [Box(f"fixture{i}", FIXTURE_HALF_M, FIXTURE_HALF_M, [spots[i]])
                      for i in range(FIXTURES)]
    return spots


def next_session(world: World, spots: list[tuple[float, float]], session: int, seed: int
                 ) -> list[dict]:
    """Turn ``world``, as the session before left it, into session ``session`` (2, 3, ...):
    three fixtures changed (one taken away, one moved to a free spot, one brought in), and
    the robot starting elsewhere on its route. Returns the changes, as
    :attr:`Truth.prior_changes` lists them."""
    rng = np.random.default_rng(seed + 1000 * session)
    taken = {f.center for f in world.fixtures}
    free = [s for s in spots if s not in taken]
    gone, moved = (world.fixtures[int(i)] for i in rng.choice(len(world.fixtures), 2, False))
    to_move, to_add = (free[int(i)] for i in rng.choice(len(free), 2, False))
    brought = Box(f"fixture{FIXTURES + session - 2}", FIXTURE_HALF_M, FIXTURE_HALF_M, [to_add])
    changes = [{"object": gone.id, "from": list(gone.center), "to": None},
               {"object": moved.id, "from": list(moved.center), "to": list(to_move)},
               {"object": brought.id, "from": None, "to": list(to_add)}]
    moved.spots = [to_move]
    world.fixtures = [f for f in world.fixtures if f is not gone] + [brought]
    j = (session - 1) % len(world.route)
    (ax, ay), (bx, by) = world.route[j], world.route[(j + 1) % len(world.route)]
    world.start = Pose2D((ax + bx) / 2, (ay + by) / 2, math.atan2(by - ay, bx - ax))
    world.first_waypoint = (j + 1) % len(world.route)
    return changes
