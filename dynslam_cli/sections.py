"""The configuration's sections: one frozen dataclass per component, holding that
component's parameters with their units, each checking its own ranges.

Pure data: nothing here imports an algorithm module, so every part of the program can take
its own section as a plain argument (the scan matcher its ``MatchConfig``, the mapper its
``MapConfig`` and ``DynamicConfig``) without reaching into the others. The whole tree of
them, read from TOML, is :class:`dynslam_cli.config.Config`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from dynslam_cli.errors import ConfigError


def require(checks: list[tuple[bool, str]]) -> None:
    """Raise ConfigError with the message of the first check that failed."""
    for ok, message in checks:
        if not ok:
            raise ConfigError(message)


@dataclass(frozen=True)
class NoiseModel:
    """Motion noise grows with the motion; measurement noise with the range."""

    trans_per_m: float = 0.05
    """Std of translation error per metre driven (fraction)."""
    rot_per_rad: float = 0.05
    """Std of rotation error per radian turned (fraction)."""
    rot_per_m_deg: float = 1.0
    """Std of rotation error per metre driven (degrees)."""
    trans_floor_m: float = 0.002
    """Added to every motion's std of translation error, however small the motion (metres) ..."""
    rot_floor_deg: float = 0.1
    """... and to its std of rotation error (degrees)."""
    range_m: float = 0.03
    """Std of a corner's measured range (metres) ..."""
    range_per_m: float = 0.01
    """... plus this much per metre of that range (fraction)."""
    bearing_deg: float = 1.0
    """Std of a corner's measured bearing (degrees)."""


@dataclass(frozen=True)
class MapConfig:
    """Occupancy grids: geometry and the inverse sensor model of an ordinary grid."""

    resolution_m: float = 0.05
    """Cell edge length (metres)."""
    p_hit: float = 0.85
    """Inverse sensor model value for a cell where a beam ended (probability)."""
    p_miss: float = 0.35
    """Inverse sensor model value for a cell a beam passed through (probability)."""
    p_clamp_min: float = 0.02
    """The lowest probability a cell can hold: log-odds are clamped to [logit(p_clamp_min),
    logit(p_clamp_max)] so maps stay revisable."""
    p_clamp_max: float = 0.98
    """The highest probability a cell can hold."""
    free_threshold: float = 0.1
    """A cell with p below this is Free (paper Sec. 3.1: 0.1)."""
    occupied_threshold: float = 0.9
    """A cell with p above this is Occupied (paper Sec. 3.1: 0.9)."""
    grow_margin_m: float = 10.0
    """When the robot leaves the grid, it grows by at least this much on that side (metres)."""
    max_extent_m: float = 2000.0
    """The map may span at most this much in x and in y (metres); a run whose map would grow
    beyond stops with an error (an odometry jump, a unit error)."""

    def check(self) -> None:
        require([
            (0.005 <= self.resolution_m <= 10, "map.resolution_m must be in [0.005, 10] m"),
            (self.max_extent_m > 0, "map.max_extent_m must be > 0"),
            (0.5 < self.p_hit < 1, "map.p_hit must be in (0.5, 1)"),
            (0 < self.p_miss < 0.5, "map.p_miss must be in (0, 0.5)"),
            (0 < self.p_clamp_min < 0.5 < self.p_clamp_max < 1,
             "map clamp must be 0 < p_clamp_min < 0.5 < p_clamp_max < 1"),
            (0 < self.free_threshold < 0.5 < self.occupied_threshold < 1,
             "map thresholds must be 0 < free_threshold < 0.5 < occupied_threshold < 1"),
            (self.grow_margin_m > 0, "map.grow_margin_m must be > 0"),
        ])


MAX_MOUNT_M = 10.0  # a laser's mount lies within this of the robot's centre


@dataclass(frozen=True)
class LaserConfig:
    """How readings are interpreted."""

    min_range_m: float = 0.02
    """Readings at or below this are invalid (SICK error codes are often 0) and dropped."""
    max_range_m: float | None = None
    """Override the log's max range (metres); readings at or above it are 'no return'."""
    clear_cap_m: float = 10.0
    """A no-return beam clears free space up to this distance (metres) and marks no hit."""
    fov_deg: float | None = None
    """Field of view for logs whose records carry no beam angles (old FLASER), overriding
    CARMEN's rule (degrees). The first beam is at -fov/2, beams evenly spaced."""
    beam_step_deg: float | None = None
    """The angle between two beams (degrees), for a log of any format whose records state it
    wrong; the first beam stays where the log puts it. The usual mistake is a converter's
    fov/(n-1) for a laser whose beams are fov/n apart: the Intel benchmark's ``.orig.bag``
    says 180/179 degrees for its SICK's 1 (as the Carmen log has them), which spreads every
    scan 0.56% too wide, its edges half a degree out, and doubles the local SLAM's error
    (relations 0.251 m, 0.128 m at 1 degree)."""
    check_beam_step: bool = True
    """Where ``beam_step_deg`` is not set and a log's beams look spread by such a converter
    (an even count spanning a whole number of quarter turns), match its first scans at the
    laser's own spacing, fov/n, as well, and read the log at it where they fit it better
    in two scans of three (dynslam_cli.localization.beams; a warning says so, and
    summary.json's ``input.beam_spacing`` holds the check). Not for a log read from
    standard input."""

    mount_x_m: float | None = None
    """The laser's mount on the robot, for a log that states it wrong or not at all: its x
    (metres, forward of the odometry's centre), instead of the log's. The trajectory is the
    robot's, so a mount stated wrong turns into an error in each turn of the relations
    between its poses: the Kümmerle FR079 logs as converted to ROS (and the Carmen log
    rebuilt from them) put the laser 4 cm ahead, where the original log's PARAM
    robot_frontlaser_offset puts it 4 cm behind; read with -0.04, the benchmark's
    relations fit the trajectory's own frame (within 8 mm) and the full run's relation
    error falls from 0.065 to 0.031 m."""
    mount_y_m: float | None = None
    """... its y (metres, to the left), instead of the log's."""
    mount_deg: float | None = None
    """... its heading (degrees, from the robot's), instead of the log's."""
    scan_latency_s: float = 0.0
    """How much older a scan's content is than its stamp and its odometry pose (seconds):
    each scan's odometry is taken this much earlier, between the scan before's and its
    own. A laser's scans reach the logger after the sweep and the transfer (a SICK LMS at
    38.4 kbaud: 94 ms), while the logger reads the odometry at arrival."""

    interlace_s: float | None = None
    """A laser that sweeps its beams in two interlaced passes, the even beams in one turn of
    its mirror and the odd ones in the next (a SICK LMS at half a degree: 13.3 ms apart at
    75 Hz): the time between the passes (seconds). Each odd beam's angle is turned by the
    robot's turn in that time, at the odometry's turn rate since the scan before (where
    that was at most 0.5 s before), so a turning robot does not see every wall twice.
    Unset (None, the default since stop 61): estimated from the log's first 200 turning
    scans, taken where it is 3 ms or more from 50 of them or more (said once: MIT CSAIL
    7.4 ms, FR079 11.3; Intel's SICK at one degree sweeps once, and the built-in worlds'
    laser too). 0: the beams as the log has them. Measured at 385007d, this machine,
    relations, pose graph off / on, before -> after: MIT 0.0564 / 0.0266 -> 0.0384 /
    0.0266 m, FR079 0.0879 / 0.0649 -> 0.0724 / 0.0648, its bag 0.0754 / 0.0648 -> 0.0746 /
    0.0622, with the original mount 0.0551 / 0.0306 -> 0.0389 / 0.0304 and its bag 0.0668 /
    0.0311 -> 0.0523 / 0.0311; Intel, its bag, the worlds and the Radish rows but
    freiburg-079's (0.0825 / 0.0820 / 0.0796 -> 0.0844 / 0.0774 / 0.0788) unchanged."""

    stopped_clock_period_s: float = 1.0
    """Where a log's stamps carry no time (most of its first 50 scans repeat one: the
    corrected Radish freiburg-campus, orebro, belgioioso stamp every scan 0), its scans are
    timed by their order, this many seconds apart (as trajectory.tum numbers them), so the
    change events, whose rules are in seconds and metres per second, have a time to go
    by. Say the laser's rate where it is known (a scan every 0.1-0.2 s for the raw
    benchmark logs; the corrected Radish logs keep one every 1.5-5 s)."""

    def reader_options(self) -> dict[str, float | None]:
        """The reader options this section sets (dynslam_formats.ReaderOptions fields): the
        readers apply them, so every part of the program sees the same scans."""
        return {"fov_deg": self.fov_deg, "beam_step_deg": self.beam_step_deg,
                "scan_latency_s": self.scan_latency_s, "max_range_m": self.max_range_m,
                "mount_x_m": self.mount_x_m, "mount_y_m": self.mount_y_m,
                "mount_deg": self.mount_deg, "interlace_s": self.interlace_s,
                "stopped_clock_period_s": self.stopped_clock_period_s}

    def check(self) -> None:
        require([
            (self.clear_cap_m > 0, "laser.clear_cap_m must be > 0"),
            (self.interlace_s is None or 0 <= self.interlace_s <= 0.1,
             "laser.interlace_s must be in [0, 0.1] s"),
            (self.min_range_m >= 0, "laser.min_range_m must be >= 0"),
            (self.max_range_m is None or self.max_range_m > 0, "laser.max_range_m must be > 0"),
            (self.fov_deg is None or 0 < self.fov_deg <= 360,
             "laser.fov_deg must be in (0, 360]"),
            (self.beam_step_deg is None or 0 < self.beam_step_deg <= 360,
             "laser.beam_step_deg must be in (0, 360]"),
            (0 <= self.scan_latency_s <= 1, "laser.scan_latency_s must be in [0, 1] s"),
            (0 < self.stopped_clock_period_s <= 3600,
             "laser.stopped_clock_period_s must be in (0, 3600] s"),
            *((v is None or abs(v) <= MAX_MOUNT_M, f"laser.{name} must be within "
               f"{MAX_MOUNT_M:g} m of the robot") for name, v in (("mount_x_m", self.mount_x_m),
                                                                 ("mount_y_m", self.mount_y_m))),
            (self.mount_deg is None or abs(self.mount_deg) <= 360,
             "laser.mount_deg must be in [-360, 360]"),
        ])


@dataclass(frozen=True)
class DynamicConfig:
    """The dynamic map D (paper Sec. 3.2) and the neighbourhood rule (Sec. 5).

    S uses the ``[map]`` values: ``p_hit`` is Table 1's *high*, ``p_miss`` its *low*.
    """

    enabled: bool = True
    """False: one ordinary occupancy grid, D stays empty (``--no-dynamic``, paper Fig. 3b)."""
    p_high: float = 0.97
    """Table 2's *high*: a hit where S was Free (probability); two in a row make a cell
    Occupied in D from Free."""
    p_low: float = 0.0001
    """Table 2's *low*. Very low so one free observation clears D: D keeps no history."""
    p_clamp_min: float = 0.05
    """The lowest probability a cell of D can hold (its log-odds clamped, as S's)."""
    p_clamp_max: float = 0.99
    """The highest probability a cell of D can hold."""
    neighbourhood_m: float = 0.1
    """An end point is compared with S^{t-1} over a square window of this half-width
    (metres), so small pose or rounding errors do not turn walls dynamic (Sec. 5)."""
    surface_m: float = 0.0
    """Above 0: a hit where S was firmly Free, which the window would hand to a wall beside
    it (or to the strip in front of a wall that no beam passed), stays the wall's only if it
    lies within this distance (metres) of the surface the wall's own end points drew, or
    within three times how far the scan's end points around it lie off S's walls where that
    is wider (dynslam_cli.mapping.surfaces): a box 5 or 10 cm from a wall goes into D, not S
    (bench/near_walls.py: 10 of 10 moves found at both gaps with 0.03; 1 and 1 of 10 with
    0). 0: the window alone, the paper's rule. Off: the worlds' maps and the corridors'
    and arena's events score as without it, but the office's events get worse (with
    drifting odometry 15 appeared objects reported, 1 true, against 6), MIT CSAIL's D grows
    from 62 to 92 cells and its moving tracks from 14 to 21, Radish freiburg-079's D cells
    beside S's from 9 to 22 (README, "Objects close to walls"); it costs 24 bytes a cell
    more."""
    surface_beams: int = 2
    """... and only where the hit lies among this many consecutive beams whose end points
    land where S was seen free (off the surfaces, or where the window says Free); a hit off
    the surfaces alone among beams on S's walls or on what S has not seen yet (a beam's
    edge on a chair leg, the first view of a box's face) updates neither map. 1: every hit
    off the surfaces goes into D."""
    remember_free: bool = False
    """True: a cell S once held Free counts as Free in a hit's window for as long as it is not
    Occupied again. Table 1 keeps what a hit lands on where S is Unknown ("static until seen
    to move"); that is for space not known yet. Without this, a mover first seen where S was
    still Unknown (in view from the first scan, or beside a wall) raises the cells it stands
    on, and each of its next end points, a cell or two on, has them in its window: it drags
    Unknown along and never enters D for as long as it stays in view. False: the window of
    S^{t-1} alone, the paper's rule. Off, because the same drag is what lets a wall that a
    pose error puts a few cells off S stay the wall's: with it, the crowd world seen all
    round (``simulate crowd --fov 360 --beams 361``, 300 s, three walkers always in view)
    reports 9 moving tracks, not 51 (with ``--stop-and-go 5``: 5, not 33), and the bag
    people-walking-rear 3 tracks for its 3 people, not 4; but MIT CSAIL's D grows from 79
    to 355 cells and its events from 12 appeared / 15 moving to 39 / 38, and the office
    world (ATE 0.08 m) reports 54 false moving tracks, not 4 (D precision 0.83 -> 0.10).
    The other worlds: the same maps and events, 2-8 more moving tracks, all on walkers
    (bench/accuracy.py --modes S/D). It costs a byte a cell."""

    def check(self) -> None:
        require([
            (0.5 < self.p_high < 1, "dynamic.p_high must be in (0.5, 1)"),
            (0 < self.p_low < 0.5, "dynamic.p_low must be in (0, 0.5)"),
            (0 < self.p_clamp_min < 0.5 < self.p_clamp_max < 1,
             "dynamic clamp must be 0 < p_clamp_min < 0.5 < p_clamp_max < 1"),
            (0 <= self.neighbourhood_m <= 1.0, "dynamic.neighbourhood_m must be in [0, 1] m"),
            (0 <= self.surface_m <= 1.0, "dynamic.surface_m must be in [0, 1] m"),
            (self.surface_beams >= 1, "dynamic.surface_beams must be >= 1"),
        ])


@dataclass(frozen=True)
class CornerConfig:
    """Corner detector parameters (units in the names)."""

    jump_m: float = 0.25
    """Range jump between neighbouring beams that splits a cluster (plus jump_ratio · r)."""
    jump_ratio: float = 0.05
    """Share of the range r added to ``jump_m`` (a fraction): far beams lie farther apart."""
    split_tolerance_m: float = 0.04
    """A run is straight while no point is farther than this from its chord."""
    min_points: int = 7
    """Each side of a corner must hold at least this many beams."""
    min_length_m: float = 0.35
    """... and be at least this long."""
    max_fit_rms_m: float = 0.03
    """... and fit its line with at most this RMS residual."""
    min_angle_deg: float = 50.0
    """Angle between the two sides: a corner is between min and 180 − min degrees."""
    max_gap_m: float = 0.15
    """The lines' intersection must lie this close to the last point of each side."""
    max_range_m: float = 7.0
    """No corners beyond this range (or within 5% of the laser's max range)."""

    def check(self) -> None:
        require([
            (self.min_points >= 3 and self.min_length_m > 0,
             "corners: min_points >= 3, length > 0"),
            (0 < self.min_angle_deg < 90, "corners.min_angle_deg must be in (0, 90)"),
        ])


@dataclass(frozen=True)
class EkfConfig:
    """Localization parameters."""

    localization: str = "ekf"
    """``ekf`` (corner EKF-SLAM) or ``odometry`` (no correction, paper Fig. 3a)."""
    gate_chi2: float = 9.21
    """Mahalanobis gate for data association (χ², 2 dof; 9.21 = 99%)."""
    search_radius_m: float = 1.5
    """Only landmarks this close to an observation are considered for association."""
    confirm_observations: int = 3
    """A new corner becomes a landmark after this many sightings ..."""
    candidate_radius_m: float = 0.25
    """... within this distance of each other ..."""
    candidate_expiry_scans: int = 15
    """... each within this many scans of the previous one."""
    max_landmarks: int = 300
    """At most this many landmarks in the filter (its cost grows with their square): beyond,
    the least recently seen leave it first."""
    active_window_scans: int = 30
    """A landmark not seen for this many scans leaves the filter (the EKF corrects with
    what it has just seen; a corner seen again after longer is matched under a pose that
    drifted meanwhile, a loop closure nothing verified, and is confirmed anew instead: the
    landmark map fuses the two, and the pose graph closes the loop) ..."""
    keep_observations: int = 5
    """... and is kept in the landmark map if it was seen at least this often."""
    robocentric: bool = True
    """After each scan the filter is conditioned on the robot's pose (a robocentric filter:
    :meth:`dynslam_cli.localization.ekf.Ekf.condition_on_robot`): its covariance keeps what
    the robot does not know of the landmarks around it, not the drift since the first scan
    (the pose graph's to correct), and a landmark's covariance in landmarks.csv is its
    uncertainty relative to the robot that saw it. With the drift kept (false, the default
    before), a heading a few degrees uncertain makes re-observed corners move the robot
    sideways: on FR079 1 m within 5 s while it turns in place."""
    noise: NoiseModel = field(default_factory=NoiseModel)

    @property
    def filtered(self) -> bool:
        """Whether the EKF localizes (else the odometry alone, paper Fig. 3a): the switch,
        read by the pipeline and by what measures each scan for it."""
        return self.localization == "ekf"

    def check(self) -> None:
        require([
            (self.localization in ("ekf", "odometry"),
             "ekf.localization must be ekf or odometry"),
            (self.gate_chi2 > 0 and self.search_radius_m > 0, "ekf gate values must be > 0"),
            (self.confirm_observations >= 1, "ekf.confirm_observations must be >= 1"),
            (self.max_landmarks >= 1, "ekf.max_landmarks must be >= 1"),
        ])


ODOMETRY_NOISE = NoiseModel(trans_per_m=0.1, rot_per_rad=0.2, rot_per_m_deg=5.0,
                            trans_floor_m=0.01, rot_floor_deg=0.5)


@dataclass(frozen=True)
class CorrelativeConfig:
    """Its lookup table, the odometry's prior and the window searched."""

    resolution_m: float = 0.05
    """Cell of the lookup table and step of the translation search (m)."""
    field_sigma_m: float = 0.05
    """Spread of a beam's end point about the wall it hit (m)."""
    outlier_share: float = 0.1
    """Probability that an end point is not on the submap's walls at all."""
    effective_points: float = 40.0
    """A scan's end points count as this many independent ones in the posterior."""
    odometry: NoiseModel = field(default_factory=lambda: ODOMETRY_NOISE)
    """The wheel odometry's noise, the prior of each match (its range keys are not used).
    The defaults are what the benchmark's real robots show between poses under 5 s apart
    (Kümmerle et al. relations against the raw odometry: 2.5° rms over 0.45 m with 2° of
    turn, 4.4° over 11°, 4-8% of the distance): five times the EKF's default rotation
    noise."""
    learn_odometry: bool = False
    """Scale the odometry's noise model by what the log shows (OdometryScale): a robot whose
    odometry is better than the model (a simulator's, a well-calibrated one) is followed
    more closely, one whose odometry is worse is trusted less. Off: on the built-in worlds
    with perfect odometry it won when it was made (ATE 0.0014-0.016 m; with today's front
    end and the pose graph off, office 0.117, corridors 0.033, hall 0.023, crowd 0.004,
    arena 0.004 against 0.110, 0.048, 0.036, 0.015, 0.006 without), but on the Radish logs it loses
    (geometric mean of the ATE ratios to ICP 1.49 against 1.07 without; csail 2.7 m at
    every level): a SLAM-corrected "perfect" odometry jumps where its own loops closed,
    and a model learned from the smooth stretches trusts it there too. Measured again at
    ecc2fb8, with ``learned_scale_in`` either way: ``bench/configs/learn_odometry.toml``."""
    learned_scale_in: str = "search"
    """With ``learn_odometry``, where the learned scale applies: "search", the search's
    window and prior, its slip tests and the fusion; "fusion", the fusion of a match that
    agrees with the odometry alone, while the window and the slip tests take the noise as
    stated (a scale learned where the odometry agreed says nothing of where it slips)."""
    calibrate_odometry: bool = True
    """Learn the odometry's systematic errors from the matches (OdometryCalibration: a
    scale of its translation, with ``calibrate_rotation`` of its rotation and a heading
    drift per metre) and take them out of each wheel increment before it is the match's
    prior: where the scans cannot see how far the robot went (a corridor between doors
    20 m apart, an 8 m laser) the odometry's scale error is what is left. On since stop 60,
    translation alone (figures under ``calibrate_rotation``). Measured before the matches
    were weighed by what the scan saw of them, translation and rotation, pose graph off:
    relations MIT 0.0632 -> 0.0654 m, Intel 0.1115 -> 0.1260, FR079 0.0731 -> 0.0823;
    with perfect odometry the office learned a translation scale of 0.99, its corridor's
    matches handing their bias to the odometry."""
    calibrate_rotation: bool = False
    """With ``calibrate_odometry``, its rotation's scale and drift too; False: the translation's
    scale alone. Each match teaches the calibration as much as the scan determined it against
    the odometry's prior (``scan_share``: along the travel for the scale, in rotation for the
    rest), so a match along a featureless corridor, the odometry's own, teaches nothing.
    Measured at 0382c98, this machine, one run each, calibration off -> translation alone (the
    default since stop 60): relations (pose graph off / on) MIT 0.0603 / 0.0263 -> 0.0564 /
    0.0266 m, Intel 0.0906 / 0.0136 -> 0.0908 / 0.0138, FR079 0.0757 / 0.0649 -> 0.0879 /
    0.0649, Intel bag 0.0922 / 0.0144 -> 0.0752 / 0.0141, FR079 bag 0.0788 / 0.0627 -> 0.0754 /
    0.0648, FR079 with the original mount 0.0461 / 0.0305 -> 0.0551 / 0.0306; five perturbed
    copies, pose graph off, median (spread): MIT 0.0554 (39%) -> 0.0560 (19%), Intel 0.0826
    (25%) -> 0.0754 (20%); worlds, drifting odometry (seed 0): office 0.2724 -> 0.0963,
    corridors 0.0547 -> 0.0075, hall 0.0041 -> 0.0051, crowd 0.0075 -> 0.0069, arena 0.0030 ->
    0.0029; true odometry (seeds 0 / 1 / 2): office 0.0535 / 0.0386 / 0.0482 -> 0.0801 / 0.0607
    / 0.0462 (its matches come out 0.2-0.3% short, and the calibration takes that for the
    odometry's: README, "The local map's horizon"), corridors 0.0042 / 0.0045 / 0.0043 ->
    0.0049 / 0.0043 / 0.0052, hall, crowd and arena within 2 mm; Radish (seed 0) 26 -> 25 of 39
    rows at or below the better of Karto and GMapping, geometric mean of the ATE ratios 1.107,
    0.993 without csail moderate (0.102 -> 2.85 m) and freiburg-campus moderate (9.95 -> 24.8);
    csail moderate breaks on 2 of 5 perturbed copies either way (bench/stability.py --radish
    csail:moderate: 2.64 and 2.83 m with the calibration, 2.90 and 2.92 without). Rotation too
    (at fcd00d3, the wheel's turn regressed on the match's): relations, graph off, MIT 0.0545,
    Intel 0.0921, FR079 0.0750, Intel bag 0.1012; five copies MIT 0.0564 (60%), Intel 0.0852
    (29%); drifting office 0.0846: the rotation's learning makes the local SLAM chaotic, so it
    stays off."""
    calibrate_mount: bool = False
    """With ``calibrate_odometry``, learn the laser mount's error too: where the log states
    the laser, less where the wheels turn it about (a converter that wrote it wrong, a laser
    moved on its robot). Turning, the matches then see the robot turn about another point
    than the odometry says (OdometryCalibration); the error is learned with the
    translation's scale and taken out of each wheel increment before it is the match's
    prior. The trajectory stays in the frame the log states (``summary.json`` says what was
    learned: ``laser_mount_error_m``). Off: it learns FR079's 8 cm as 3.8 cm (and its
    original's -4 cm as -4.2: the wheels turn the laser about itself there), Intel -9 cm,
    MIT 1.8 cm, and loses on the whole. Measured at b82596b, this machine, one run each,
    default -> with it: relations, pose graph off / on, MIT 0.0564 / 0.0266 -> 0.0582 /
    0.0264 m, Intel 0.0908 / 0.0138 -> 0.0769 / 0.0138, FR079 0.0879 / 0.0649 -> 0.0758 /
    0.0649, Intel bag 0.0752 / 0.0141 -> 0.1153 / 0.0143, FR079 bag 0.0754 / 0.0648 ->
    0.0780 / 0.0649, FR079 with the original mount 0.0551 / 0.0306 -> 0.0567 / 0.0305, its
    bag 0.0668 / 0.0311 -> 0.0604 / 0.0312; five perturbed copies, pose graph off, median
    (spread): MIT 0.0560 (19%) -> 0.0593 (19%), Intel 0.0754 (20%) -> 0.0754 (27%); worlds,
    true odometry, seeds 0 / 1 / 2: office 0.0801 / 0.0607 / 0.0462 -> 0.0997 / 0.0649 /
    0.0728 (a lever learned from matches the local map's horizon shortens), the others
    within 3 mm; drifting (seed 0): hall 0.0051 -> 0.0039, crowd 0.0069 -> 0.0084, the others
    within 1 mm. Reported in the robot's true centre instead, FR079's full run scores 0.0428
    but Intel's 0.0382 and MIT's 0.0274: the relations are in the frame each log states."""
    odometry_glitch: float = 1e-3
    """The odometry's prior never falls below this share of its peak (slips, glitches)."""
    seen_only: bool = False
    """A pose is scored on the end points that land where the local map's key scans looked
    (inside their fans, and a wall's reach beyond), at least half of them, as
    ``[loop] seen_only`` scores a closure: an end point where the local map never looked
    (a wall beyond its key scans' reach, round a corner they did not see) is neither a hit
    nor a miss, so the search does not pull the scan back onto the walls it knows. The
    share of all end points on walls still decides whether the scan is lost
    (``min_inliers``): a scan of new rooms is not placed on the few walls it knows. Off: it
    wins the worlds and loses the real logs. Measured at 161c9aa -> with it, this machine,
    one run each: the office world with perfect odometry, the search's step 0.31 -> 0.05
    mm short of the odometry's 5 cm (the fused step's 0.06 -> 0.03 mm), ATE seeds 0 / 1 /
    2, pose graph on 0.0551 / 0.0837 / 0.0499 -> 0.0252 / 0.0371 / 0.0530 m, off 0.0837 /
    0.1281 / 0.1323 -> 0.0580 / 0.1011 / 0.0854; crowd 0.0152 / 0.0103 / 0.0104 -> 0.0081
    / 0.0079 / 0.0062, corridors, hall, arena and wards within 1 mm; drifting (seed 0)
    office 0.0775 -> 0.0445, the others within 1.2 mm; relations, pose graph off / on, MIT
    0.0342 / 0.0262 -> 0.0352 / 0.0263, Intel 0.0801 / 0.0138 -> 0.0826 / 0.0142, FR079
    0.0706 / 0.0649 -> 0.0832 / 0.0648, Intel bag 0.0812 / 0.0142 -> 0.1314 / 0.0165,
    FR079 bag 0.0762 / 0.0625 -> 0.0767 / 0.0624, FR079 with the original mount 0.0372 /
    0.0303 -> 0.0445 / 0.0305, its bag 0.0555 -> 0.0540 off; five perturbed copies, pose
    graph off, median (spread): MIT 0.0350 (31%) -> 0.0358 (26%), Intel 0.0803 (29%) ->
    0.0872 (33%)."""
    slip_test: str = "refined"
    """Where the odometry is judged to have slipped, so the match alone places the scan:
    "refined", where the search's best pose lies outside the odometry's window or the
    refined (ICP) pose differs from the odometry's by more than χ² = 2 ln(1/odometry_glitch)
    under their combined covariance; "search", only the former: the search weighs the fit
    of the whole window against the odometry's prior with its glitch floor, and where it
    agrees with the odometry a refinement that slid off is fused with it, not believed
    alone (with a perfect odometry, the hall world's 20 mm slides of ICP on a walker).
    Measured (one run each, relations m, local / full): MIT 0.0632 / 0.0264 -> 0.0687 /
    0.0275, Intel 0.1115 / 0.0172 -> 0.1112 / 0.0171, FR079 0.0731 / 0.0702 -> 0.0746 /
    0.0721; perfect-odometry worlds with a 1% odometry model, pose graph off: crowd 0.0106
    -> 0.0047 m but hall 0.0314 -> 0.0409, the others the same. Not the default."""
    fusion: str = "step"
    """How a match and the wheel odometry are fused: "step", the match with the odometry's
    increment from the last pose (``odometry``'s noise, the last pose taken as certain);
    "filter", a Kalman filter of the pose about the local map: the last pose's
    covariance carried on by each wheel increment with ``filter_odometry``'s noise, each
    match fused with that (where the scan sees little, the odometry carries the pose on;
    where it sees well, the matches of many scans are averaged). "step" by default: with
    the pose graph off, the perfect-odometry worlds office / crowd / corridors / hall /
    arena go 0.110 / 0.0145 / 0.0475 / 0.0355 / 0.0060 -> 0.048 / 0.017 / 0.036 / 0.090 /
    0.004 m (the hall: a walker pulls 15 scans' matches 8-15 cm, each sure of itself), but
    the real logs lose (five perturbed copies, medians: MIT 0.0630 -> 0.0703 m, Intel
    0.1295 -> 0.1984, FR079 0.0822 -> 0.0796)."""
    filter_odometry: NoiseModel = field(default_factory=NoiseModel)
    """The wheel odometry's noise per increment as the filter carries it (its range keys
    are not used): what a robot's wheels do between two scans, not the slips that
    ``odometry_glitch`` stands for."""
    window_sigmas: float = 3.0
    """The window spans this many of the odometry prior's standard deviations ..."""
    min_window_m: float = 0.1
    """... but at least this far either way in translation (metres) ..."""
    min_window_deg: float = 3.0
    """... and in rotation (degrees) ..."""
    max_window_m: float = 1.0
    """... and at most this far in translation (metres) ..."""
    max_window_deg: float = 60.0
    """... and in rotation (degrees)."""
    bilinear: bool = False
    """Each end point reads the lookup table between the four cells around it, weighed by
    its place among their centres (bilinear), so that a window's scores and the pose found
    move with the odometry's guess continuously; off: it reads its nearest cell, and where
    a wall's end points cross a cell's edge together the pose found jumps by most of a
    cell (the office world with true odometry: at scan 643 the search's pose a cell off
    the truth along a corridor, kept as a slip six scans in a row). Off: measured with the
    local map of first points (``thin_to = "first"``, the default then), pose graph off,
    five perturbed copies, medians (spread) MIT 0.0619 (45%) -> 0.0574 (43%), Intel 0.0997
    (42%) -> 0.1220 (52%), FR079 0.0796 (7%) -> 0.0807 (21%); one run each, local, MIT
    0.0727 -> 0.0638, Intel 0.0795 -> 0.1199, FR079 0.0878 -> 0.0836, Intel bag 0.1105 ->
    0.1283, FR079 bag 0.0895 -> 0.0865; the office with true odometry stated exact
    (bench/configs/exact_odometry.toml, seeds 0-2) 0.0315 / 0.0476 / 0.0360 -> 0.0255 /
    0.0254 / 0.0650 m. Measured again at a25fc0e (the local map of means), one run each,
    off -> on: relations local / full MIT 0.0384 / 0.0266 -> 0.0306 / 0.0269, Intel 0.0908 /
    0.0138 -> 0.0778 / 0.0140, FR079 0.0724 / 0.0650 -> 0.0763 / 0.0649, Intel bag 0.0645 /
    0.0142 -> 0.0738 / 0.0147, FR079 bag 0.0763 / 0.0621 -> 0.0735 / 0.0626; the office with
    true odometry, pose graph on, 0.0801 / 0.0607 / 0.0457 -> 0.0746 / 0.0581 / 0.0710 (its
    slide at scan 643 stays); Radish (seed 0) geometric mean of the 39 ATE ratios 1.079, fhw
    perfect 0.152 -> 7.68 m."""
    polish: str = "none"
    """Where ICP's refined pose goes last: "none", it stands; "surface", to where the end
    points lie best on the local map's smooth surface (each end point's distances to the
    tangent lines of its reference points within ``surface_radius_m``, weighed so they
    fade in and out smoothly; scanmatch.surface_fit); "field", to the top of the lookup
    table's smooth surface (its cells as a cubic B-spline's coefficients;
    correlative.climbed). ICP pairs each end point with its nearest reference point, and
    the pairs switch as the pose moves: a range moved by 1 mm moved ICP's pose 0.30 mm
    and 0.0032° a scan on MIT CSAIL, about 7 times what least squares would. ICP's share,
    RMS and information stand (the polish moves the pose by about a millimetre). Off:
    the smooth surface makes the front end less chaotic (two perturbed copies of MIT,
    front end alone: their increments differ by a median 0.70 mm / 0.017° a scan against
    1.48 mm / 0.032°; 0.52 mm / 0.011° with a radius of 0.15 m), but the local SLAM's
    relation errors are not steadier for it (five copies, pose graph off, median
    (spread): MIT 0.0396 (42%) -> 0.0385 (43%) with "surface", 0.0646 (24%) with
    "field") and its single runs lose more rows than they
    win: every figure in bench/configs/polish_surface.toml."""
    surface_radius_m: float = 0.08
    """With ``polish = "surface"``: how far an end point's reference points shape its
    surface (m). Wider, the lines of a corner's other wall and of a door's jamb pull the
    pose along a corridor: the corridors world with true odometry, pose graph on, seeds
    0 / 1 / 2, 0.0054 / 0.0044 / 0.0049 m at 0.08, 0.0075 / 0.0066 / 0.0071 at 0.15,
    0.0105 / 0.0086 / 0.0093 at 0.3 (no polish: 0.0049 / 0.0043 / 0.0051)."""
    voxel_m: float = 0.0
    """The scan's end points searched are one per square of this side (the first in beam
    order; 0: all of them): near the robot a scan's end points crowd (a wall 1 m away holds
    ten times the points of one 10 m away) and add little but time; the ICP that refines
    the search's pose uses them all. Measured at stop 69, 0 -> 0.05 (single runs, this
    machine): MIT CSAIL 11.8 -> 9.4 s, freiburg-campus 95 -> 86 s; relations local / full
    MIT 0.0400 / 0.0264 -> 0.0277 / 0.0263 m, Intel 0.0671 / 0.0140 -> 0.0840 / 0.0140,
    FR079 0.0869 / 0.0650 -> 0.0729 / 0.0648, Intel bag 0.0835 / 0.0142 -> 0.1186 / 0.0143
    (issue 36's local bound is 0.110), FR079 bag 0.0805 / 0.0625 -> 0.0802 / 0.0624, with
    the original mount 0.0480 / 0.0303 -> 0.0482 / 0.0303 and 0.0513 / 0.0312 -> 0.0554 /
    0.0310; worlds with true odometry, pose graph on, seeds 0 / 1 / 2: corridors 0.0061 /
    0.0040 / 0.0045, hall 0.0035 / 0.0056 / 0.0046, arena 0.0028 each, crowd 0.0106 /
    0.0071 / 0.0103 (the rest not run)."""

    def check(self) -> None:
        require([
            (0.005 <= self.resolution_m <= 0.5 and self.field_sigma_m > 0,
             "match.correlative: resolution_m must be in [0.005, 0.5] m, field_sigma_m > 0"),
            (0 < self.outlier_share < 1, "match.correlative.outlier_share must be in (0, 1)"),
            (self.effective_points > 0 and self.window_sigmas > 0,
             "match.correlative: effective_points and window_sigmas must be > 0"),
            (0 < self.min_window_m <= self.max_window_m <= 5
             and 0 < self.min_window_deg <= self.max_window_deg <= 180,
             "match.correlative: 0 < min_window <= max_window (at most 5 m and 180 deg)"),
            (self.slip_test in ("refined", "search"),
             'match.correlative.slip_test must be "refined" or "search"'),
            (self.fusion in ("step", "filter"),
             'match.correlative.fusion must be "step" or "filter"'),
            (self.learned_scale_in in ("search", "fusion"),
             'match.correlative.learned_scale_in must be "search" or "fusion"'),
            (self.polish in ("none", "surface", "field") and self.surface_radius_m > 0,
             'match.correlative: polish must be "none", "surface" or "field", '
             "surface_radius_m > 0"),
        ])


@dataclass(frozen=True)
class IcpConfig:
    """Point-to-line ICP (dynslam_cli.localization.scanmatch.icp): the front end's and the
    loop closures' each their own."""

    iterations: int = 24
    """Gauss-Newton steps, over which the pairing gate shrinks from ``max_correspondence_m``
    to ``min_correspondence_m``: slowly enough for a match from a poor odometry guess to
    converge (with 12, outdoor and open-hall matches kept a fifth of the odometry's heading
    error)."""
    max_correspondence_m: float = 0.5
    """Pairs farther apart than this (at the first iteration) are ignored ..."""
    min_correspondence_m: float = 0.1
    """... shrinking to this by the last iteration."""
    effective_pairs: float = 100.0
    """A scan's pairs err together (a wall is seen as a whole, and the map it is matched
    against shares its key scans' errors): for the match's information they count as this
    many independent pairs, or as themselves where there are fewer."""
    prior_as_pairs: bool = False
    """Inside ICP the guess's prior weighs against the pairs as they count in the match's
    information (``effective_pairs`` of them), not against every pair: a scan of 300 end
    points holds its prior three times as firmly, so where the walls leave a direction
    free (a long wall, a turn in front of one) the pairs that are not on the map's walls
    (a walker, a wall's far end) no longer slide the match along it. Off (the front end's
    and the loop closures' alike): with the pose graph off, the perfect-odometry worlds
    office / crowd / corridors / hall / arena go 0.110 / 0.0145 / 0.0475 / 0.0355 / 0.0060
    -> 0.109 / 0.0142 / 0.0383 / 0.0142 / 0.0042 m, but the real logs' relations (five
    perturbed copies, medians) MIT 0.0630 -> 0.0660, Intel 0.1295 -> 0.1398, FR079 0.0822 ->
    0.0783 (spreads 36, 57, 15% -> 27, 24, 26%)."""
    thickness_weights: bool = False
    """Each pair weighed by how well its reference point's neighbours lie on the line
    through it: σ² / (σ² + their variance along its normal), σ the residual's 2 cm
    (Segal et al.'s generalized ICP, "plane-to-plane", reduced to its point-to-line case):
    a normal fitted across a corner, a doorway's edge or a cluttered shelf pulls less, in
    the solve and in the match's information. Off: it wins the simulated worlds and loses
    the raw logs. Measured at e2ea65b -> with it (the front end's), this machine, one run
    each: the office world with perfect odometry, the fused steps' error 2.60 -> 1.49 mm
    rms (seed 0, odometry calibration off), ATE seeds 0 / 1 / 2, pose graph on 0.0801 /
    0.0607 / 0.0457 -> 0.0269 / 0.0262 / 0.0483 m, off 0.1795 / 0.1488 / 0.1076 -> 0.1308 /
    0.1710 / 0.1591; relations, pose graph off: MIT 0.0384 -> 0.0330, Intel 0.0908 ->
    0.0987, FR079 0.0724 -> 0.0784, Intel bag 0.0645 -> 0.0823; five perturbed copies,
    pose graph off, median (spread): MIT 0.0390 (22%) -> 0.0360 (26%), Intel 0.0754 (20%)
    -> 0.0969 (22%). Weighing the solve alone and not the information: Intel 0.1198, Intel
    bag 0.1780."""

    segments: bool = False
    """A point pairs with a reference point's line only beside it, as far along it as the
    neighbours that gave its normal reach (point to segment), not on the line's extension
    past its last point: the end of a wall the local map has seen so far (where its key
    scans' reach ends; a far wall seen at a grazing angle as points a metre apart) does not
    pull the scan's points that lie beyond it back onto it (a pair there has a residual of
    its offset along the wall times its normal's tilt, whose pull on the match points to
    the wall's end whichever way the normal tilts). Off: it mends the office world and
    loses the Radish logs. Measured at daae04a -> with it (the front end's ICP), this
    machine, one run each: the office with perfect odometry (seed 0, pose graph off, the
    odometry's scale not learned), ICP's own shortfall of each 8 cm step 0.155 -> 0.065 mm
    (the search 0.31 mm short either way); worlds, pose graph on, seeds 0 / 1 / 2, ATE m,
    true odometry: office 0.0920 / 0.0682 / 0.0498 -> 0.0378 / 0.0440 / 0.0558, hall
    0.0038 / 0.0035 / 0.0043 -> 0.0035 / 0.0051 / 0.0050, crowd 0.0107 / 0.0067 / 0.0104
    -> 0.0085 / 0.0088 / 0.0109, wards 0.0057 / 0.0060 / 0.0063 -> 0.0068 / 0.0070 /
    0.0064; drifting: office 0.1110 / 0.1225 / 0.0517 -> 0.1084 / 0.0495 / 0.0749, hall
    0.0038 / 0.0050 / 0.0367 -> 0.0039 / 0.0049 / 0.0049, crowd 0.0069 / 0.0065 / 0.0062
    -> 0.0169 / 0.0112 / 0.0090 (its map stretched about 2% along x), corridors and arena
    within 2 mm (geometric mean of the 36 ratios 0.963); relations, local / full, MIT
    0.0384 / 0.0266 -> 0.0452 / 0.0262, Intel 0.0908 / 0.0138 -> 0.0727 / 0.0141, FR079
    0.0724 / 0.0650 -> 0.0707 / 0.0649, Intel bag 0.0645 / 0.0142 -> 0.0790 / 0.0146, FR079
    bag 0.0763 / 0.0621 -> 0.0733 / 0.0623; Radish (seed 0) 29 of 39 rows at or below the
    better peer (28), but the geometric mean of the 39 ratios 1.107 (freiburg-campus
    moderate 0.84 -> 13.4 m, edmonton perfect 0.541 -> 0.723; orebro moderate 0.240 ->
    0.132, seattle moderate 0.065 -> 0.040) (bench/configs/segments.toml)."""

    residual_sigma: str = "stated"
    """The pairs' residual standard deviation the match's information is counted in:
    "stated", a good match's 2 cm (scanmatch.RESIDUAL_SIGMA_M) whatever the laser; "fit",
    the match's own RMS distance of its pairs to their lines (at least
    scanmatch.MIN_RESIDUAL_SIGMA_M): s² (Σ J Jᵀ)⁻¹, least squares' own estimate, so a 1 cm
    laser's match is held four times as firmly as a 2 cm one's, and a scan that fits its
    map loosely less firmly. Off: it calibrates the worlds' covariance but loses the
    office, the Intel bag and the copies' spread. Measured at 9bcd7d9, this machine, one
    run each, "stated" -> "fit" with ``effective_pairs = 50`` (bench/configs/
    residual_sigma_fit.toml): NEES of the matched increments on the worlds (drifting
    odometry; bench/calibration.py, 3 is honest) corridors 0.58, arena 0.87, hall 1.03,
    crowd 1.36, office 0.74, wards 0.70 -> 1.54, 2.53, 2.49, 3.49, 3.63, 1.73 (with 100
    pairs: 3.28 to 9.23); relations, local / full, MIT 0.0384 / 0.0266 -> 0.0335 / 0.0264,
    Intel 0.0908 / 0.0138 -> 0.0691 / 0.0139, FR079 0.0724 / 0.0650 -> 0.0717 / 0.0647,
    Intel bag 0.0645 / 0.0142 -> 0.0963 / 0.0146, FR079 bag 0.0763 / 0.0621 -> 0.0746 /
    0.0626; five perturbed copies, pose graph off, median (spread) MIT 0.0390 (22%) ->
    0.0375 (32%), Intel 0.0739 (17%) -> 0.0870 (30%); worlds, pose graph on, seeds 0 / 1 /
    2, true odometry: office 0.0920 / 0.0682 / 0.0498 -> 0.0971 / 0.0790 / 0.1771,
    crowd 0.0107 / 0.0067 / 0.0104 -> 0.0085 / 0.0064 / 0.0065, corridors 0.0049 / 0.0043 /
    0.0051 -> 0.0053 / 0.0060 / 0.0062; drifting: office 0.1110 / 0.1225 / 0.0517 ->
    0.1024 / 0.0937 / 0.0804, hall 0.0038 / 0.0050 / 0.0367 -> 0.0046 / 0.0041 / 0.0053;
    the rest within 2 mm."""

    def check(self) -> None:
        require([(self.residual_sigma in ("stated", "fit"),
                  'icp.residual_sigma must be "stated" or "fit"'),
                 (self.iterations >= 1, "icp.iterations must be >= 1"),
                 (0 < self.min_correspondence_m <= self.max_correspondence_m,
                  "icp: 0 < min_correspondence_m <= max_correspondence_m"),
                 (self.effective_pairs > 0, "icp.effective_pairs must be > 0")])


@dataclass(frozen=True)
class MatchConfig:
    """Scan matching: each scan's motion, measured against a local map of key scans, is the
    EKF's control input."""

    enabled: bool = True
    """False: the EKF predicts from wheel odometry alone."""
    method: str = "correlative"
    """"correlative": the best pose of a window around the odometry's guess on the local
    map's likelihood (see dynslam_cli.localization.correlative), refined by ICP and fused
    with the odometry by their information. "icp": point-to-line ICP from the odometry's
    guess, with retries from turned guesses where it fails (the default before the
    benchmark's raw logs showed the correlative search ahead on every one; best with
    ``local_map_scans = 8``)."""
    max_range_m: float = 40.0
    """Readings beyond this are not matched (metres). 40 since stop 68, 20 before: outdoors
    and in long corridors most of an 80 m laser's readings lie beyond 20 m, and a scan
    with a few dozen end points left (freiburg-campus between its buildings) fails its
    match, so the odometry alone carries the robot there (24 of 27 scans in a row, 21° of
    heading lost on its harsh odometry). Measured at b18cdba, this machine, one run each,
    20 -> 40 m (with ``[loop] max_range_m`` alike): Radish (seed 0) 28 -> 30 of 39 rows at
    or below the better of Karto and GMapping, geometric mean of the 39 ATE ratios 0.911
    (infinite-corridor 0.566 / 0.615 / 0.923 -> 0.395 / 0.372 / 0.499 m, freiburg-campus
    0.290 / 0.840 / 14.99 -> 0.393 / 0.313 / 8.73, orebro moderate 0.240 -> 0.118,
    edmonton perfect 0.541 -> 0.666); relations, local / full, MIT 0.0384 / 0.0266 ->
    0.0400 / 0.0264, Intel 0.0908 / 0.0138 -> 0.0671 / 0.0140, FR079 0.0724 / 0.0650 ->
    0.0869 / 0.0650, Intel bag 0.0645 / 0.0142 -> 0.0835 / 0.0142, FR079 bag 0.0763 /
    0.0621 -> 0.0805 / 0.0625; the worlds' 8 m lasers: the same. 80 m on the campus:
    0.279 / 0.303 / 15.6 m."""
    subsample: int = 1
    """Use every n-th beam of the current scan."""
    min_inliers: float = 0.5
    """Share of points that must pair up for the match to count."""
    lost_over: str = "all"
    """When the correlative search's window around the odometry's guess explains nothing
    and is searched again wider (up to ``correlative.max_window_m``): where its best pose
    scores under ``min_inliers`` of all the end points ("all"), or under the share a match
    found there is taken at with ``inliers_over = "seen"`` ("seen": ``seen_inliers`` of
    those that land, at the guess, where the local map looked). A scan that sees much the
    local map did not (walkers, open space) scores low where it stands, and in a window a
    metre wide what the walkers left in the local map can score higher elsewhere: the hall
    world (drifting odometry, seed 2) at scan 220 scored 0.468 at its odometry's guess
    (0.0013 m off the truth), the window was widened, and 0.93 m ahead scored 0.552 and
    was taken; the map stayed 0.4 m off for 9 s (ATE 0.0367 m; with ``within_reach`` on,
    the default since, the scan scores enough at its guess and the run stays on the truth).
    Off: the widening
    guards the office world's open hall too, where a scan that sees one wall scores low, a
    partial fit in the narrow window is off by a degree or two, and the widened search's
    pose outside the window is refused, so the odometry's increment is taken (true
    odometry, seed 1, scan 596: 1.72° off with "seen", the odometry's exact increment
    with "all"). Measured at stop 69, "all" -> "seen", this machine, one run each:
    relations local / full MIT 0.0400 / 0.0264 -> 0.0332 / 0.0262 m, Intel 0.0671 /
    0.0140 the same, FR079 0.0869 / 0.0650 the same, Intel bag 0.0835 / 0.0142 the same,
    FR079 bag 0.0805 / 0.0625 -> 0.0824 / 0.0625, with the original mount 0.0480 / 0.0303
    -> 0.0450 / 0.0303 and 0.0513 / 0.0312 -> 0.0524 / 0.0311; worlds, pose graph on,
    seeds 0 / 1 / 2, corridors, arena, crowd and wards the same to 0.1 mm (true and
    drifting), hall true 0.0038 / 0.0035 / 0.0043 -> 0.0040 / 0.0040 / 0.0043, hall
    drifting 0.0038 / 0.0050 / 0.0367 -> 0.0041 / 0.0046 / 0.0051, office true 0.0920 /
    0.0682 / 0.0498 -> 0.1369 / 0.1704 / 0.1312, office drifting 0.1110 / 0.1225 / 0.0517
    -> 0.2594 / 0.1850 / 0.1687 (Radish not run; ``within_reach`` off, the default
    then)."""
    inliers_over: str = "seen"
    """Which end points the share that must fit is of (the correlative search's score and
    its refinement's pairs): "all", ``min_inliers`` of the scan's; or "seen": the match
    the search finds within the odometry's window (not a retry's) that fits fewer is still
    taken where ``seen_inliers`` of the end points that land, at its pose, where the local
    map's key scans looked (inside their fans, and a wall's reach beyond; never fewer than
    half of all counted, ``correlative.MIN_SEEN_SHARE``) fit, and only as refined (its
    refinement still within the odometry's window; else the odometry's increment). An end
    point where the local map never looked is no evidence against a match: after a turn
    or a long step a scan sees much the local map did not, and with "all" the match is
    refused and the odometry's increment taken (Radish's belgioioso with our harsh
    odometry, key frames a metre apart: the search put scan 205 at +6.93° from the
    odometry's guess, the truth's +6.92°, but 0.427 of its points fit, 0.77 of those
    where the local map looked, and the odometry's 7° error was kept). The default since
    stop 66. Stop 65's version broke the office world with true odometry (2.22 / 4.91 /
    1.24 m): a partial fit's posterior is flat, and ICP's refinement slid within it 17°
    from the search's pose (scan 595: search +0.62°, refined +16.7°, the odometry exact)
    and was kept, or the unrefined search's pose was. Measured at stop 66, "all" ->
    "seen", this machine, one run each (the old default: bench/configs/all_inliers.toml):
    the benchmark's raw logs, every relations row local and full identical (no scan of
    theirs falls short); Radish (seed 0) perfect / moderate / harsh ATE m, belgioioso
    0.101 / 0.313 / 0.692 -> 0.090 / 0.092 / 0.172, orebro 0.106 / 0.156 / 0.531 -> 0.110
    / 0.240 / 0.399, infinite-corridor 0.638 / 0.648 / 0.743 -> 0.566 / 0.615 / 0.923,
    intel 0.070 / 0.067 / 0.080 -> 0.083 / 0.075 / 0.077, fhw 0.152 / 0.135 / 0.124 ->
    0.141 / 0.148 / 0.148, freiburg-campus 0.317 / 0.869 / 34.3 -> 0.290 / 0.840 / 15.0,
    csail moderate 0.103 -> 0.101, the other 20 rows within 1% (geometric mean of the 39
    ratios 0.925; 28 of 39 at or below the better of Karto and GMapping, 27 with "all");
    five perturbed copies (bench/stability.py), medians (range): belgioioso moderate 0.108
    (0.086-0.158), harsh 0.203 (0.197-0.231), orebro harsh 0.229 (0.205-0.405), each copy
    below "all"'s run; worlds, pose graph on, seeds 0 / 1 / 2, true odometry: office
    0.0801 / 0.0607 / 0.0457 -> 0.0920 / 0.0682 / 0.0498 (worse), hall 0.0036 / 0.0031 /
    0.0043 -> 0.0038 / 0.0035 / 0.0043; drifting: office 0.0963 / 0.1050 / 0.0980 ->
    0.1110 / 0.1225 / 0.0517, hall 0.0051 / 0.0042 / 0.0378 -> 0.0038 / 0.0050 / 0.0367;
    corridors, arena, crowd and wards identical. Taking retries' matches too (stop 65's
    first version) broke the hall as well (seed 2: 0.388 m; the robot standing at one
    place, 35 matches taken with 0.31-0.48 of their points fitting crept 10 cm, then
    turned 8°)."""
    seen_inliers: float = 0.6
    """... (with ``inliers_over = "seen"``) this share of the end points where the local
    map looked. Above ``min_inliers``: a scan smeared by a fast turn (Radish's fhw, 48°
    between two scans) lands where the local map looked and fits it no better, and 0.54
    of such a scan's end points fitting took a match 6° off the truth, and the next
    scans' retries after it 80° off (at 0.5: ATE 0.152 -> 11.7 m)."""
    max_rms_m: float = 0.08
    """... and whose pairs lie at most this far from their lines, RMS (metres)."""
    prior_scale: float = 1.0
    """The odometry prior's standard deviations are the motion noise's times this ..."""
    prior_floor_m: float = 0.0
    """... and at least this (translation) ..."""
    prior_floor_deg: float = 5.0
    """... and this (rotation): wheel odometry of real robots slips in fast turns."""
    key_distance_m: float = 0.5
    """A scan becomes a key scan of the local map after this much motion (metres) ..."""
    key_angle_deg: float = 15.0
    """... or this much turning (degrees) since the last key scan."""
    local_map_scans: int = 64
    """Key scans in the local map each scan is matched against (1: the last key scan):
    about 32 m of travel at the default spacing, so the walls are held long enough that the
    long relations of the benchmark logs do not drift."""
    local_map_cell_m: float = 0.05
    """The local map keeps one point per square of this side (overlapping key scans)."""
    thin_to: str = "mean"
    """Which point stands for a square of the local map (and of the correlative search's
    walls): "mean", the mean of its points (a voxel grid's centroid), which moves by a
    fraction of a millimetre when a point moves by a millimetre; "first", the first point
    in it (the default before the change events counted a cell crossed while an object
    arrived again once it stood there), which may give way to another a cell away. "mean"
    wins the localization: five perturbed copies, pose graph off, medians (spread) MIT
    0.0619 (45%) -> 0.0554 (39%), Intel 0.0997 (42%) -> 0.0826 (25%), FR079 0.0796 (7%) ->
    0.0772 (14%); one run each, local / full: MIT 0.0727 / 0.0272 -> 0.0603 / 0.0265,
    Intel 0.0795 / 0.0152 -> 0.0906 / 0.0146, FR079 0.0878 / 0.0652 -> 0.0757 / 0.0647,
    Intel bag 0.1105 / 0.0151 -> 0.0922 local; perfect-odometry worlds (15 runs) 0.0229 ->
    0.0190 m with the pose graph off (worst 0.199 -> 0.142), 0.0083 -> 0.0077 with it on;
    the Radish rows (bench/radish.py --seed 0) geometric mean of the 39 ATE ratios 0.914,
    26 of 39 at or below the better of Karto and GMapping (27 with "first"). A row it
    loses: the office with true odometry and the pose graph on, seed 0 (bench/accuracy.py
    --modes S/D), ATE 0.0372 -> 0.0677 m, S precision 0.699 -> 0.479 (seeds 1 and 2: 0.0398
    -> 0.0423, 0.0779 -> 0.0534)."""
    normal_neighbours: int = 6
    """Points whose spread gives a local-map point's normal."""
    normal_gap: float = 0.0
    """Above 0: ... this side of a gap: a neighbour more than this many times as far from
    the point as the one before it lies across empty space from the rest, and it and the
    farther ones are left out; fewer than three left (itself included: a short stub seen
    from afar, a lone point) and the point has no normal, and ICP pairs nothing with it. 0
    (the default): every one of the nearest. Then a stub's normal leans toward the nearest
    wall metres away and pins the match along the wall it stands in front of: in the
    office world's hall (perfect odometry) a 0.55 m stub 8 m off, the only thing a scan of
    one wall saw across it, slides the fused match 2.5 cm back and forth for 6 scans (with
    a gap of 3, the fused steps' error 2.76 -> 1.95 mm rms). A fixed bound of 0.5 m
    (161c9aa) did as much for the stub but took the normals of a wall seen outdoors, whose
    points lie 0.5-1 m apart. Measured at dbae05f -> 161c9aa
    (0.5 m) -> with the gap, this machine, one run each: relations, pose graph off / on,
    MIT 0.0384 / 0.0266 -> 0.0342 / 0.0262 -> 0.0298 / 0.0265 m, Intel 0.0908 / 0.0138 ->
    0.0801 / 0.0138 -> 0.0948 / 0.0140, FR079 0.0724 / 0.0650 -> 0.0706 / 0.0649 -> 0.0723
    / 0.0649, Intel bag 0.0645 / 0.0142 -> 0.0812 / 0.0142 -> 0.0981 / 0.0145, FR079 bag
    0.0763 / 0.0621 -> 0.0762 / 0.0625 -> 0.0771 / 0.0626, FR079 with the original mount
    0.0377 / 0.0304 -> 0.0372 / 0.0303 -> 0.0381 / 0.0304, its bag 0.0518 / 0.0312 ->
    0.0555 / 0.0312 -> 0.0502 / 0.0311; five perturbed copies, pose graph off, median
    (spread): MIT 0.0390 (22%) -> 0.0350 (31%) -> 0.0360 (29%), Intel 0.0754 (20%) -> 0.0803
    (29%) -> 0.0894 (10%); worlds, true odometry, pose graph on, seeds 0 / 1 / 2: office
    0.0801 / 0.0607 / 0.0457 -> 0.0551 / 0.0837 / 0.0499 -> 0.0937 / 0.0702 / 0.0467,
    corridors 0.0049 / 0.0043 / 0.0051 -> 0.0043 / 0.0044 / 0.0050 -> 0.0071 / 0.0053 /
    0.0044, hall 0.0036 / 0.0031 / 0.0043 -> 0.0038 / 0.0041 / 0.0045 -> 0.0051 / 0.0034 /
    0.0045, crowd 0.0107 / 0.0067 / 0.0104 -> 0.0152 / 0.0103 / 0.0104 -> 0.0125 / 0.0085 /
    0.0091, arena 0.0028 / 0.0029 / 0.0031 -> 0.0029 / 0.0029 / 0.0029 -> 0.0033 / 0.0036 /
    0.0033, wards 0.0057 / 0.0060 / 0.0063 -> 0.0052 / 0.0052 / 0.0059 -> 0.0049 / 0.0054 /
    0.0063; drifting (seed 0) office 0.0963 -> 0.0775 -> 0.0696, corridors 0.0075 -> 0.0067
    -> 0.0073, hall 0.0051 -> 0.0039 -> 0.0044, crowd 0.0069 -> 0.0076 -> 0.0069, arena
    0.0029 -> 0.0029 -> 0.0033; Radish (seed 0) 27 of 39 rows at or below the better peer
    each time, geometric mean of the ATE ratios to dbae05f 1.103 (fhw harsh broken, 7.58 m)
    -> 0.987; freiburg-campus moderate over five perturbed copies 0.862 / 0.950 / 1.052 ->
    0.373 / 0.902 / 15.5 -> 0.823 / 0.994 / 15.1 (one copy of five broken). Off, as it
    was: the Intel log's local SLAM loses over five copies, and the full runs gain
    nothing."""
    within_reach: bool = True
    """Match only the end points the local map could have seen: within the laser's reach
    (less ``reach_margin_m``) of one of its key scans' poses, at the odometry's guess. The
    end points beyond, a band as deep as the robot moved since the last key scan, land
    where the local map has no wall yet and pull the match back (a corridor's walls seen
    up to the laser's range make every match short, and the odometry's calibration learns
    the shortfall as the odometry's: the office world's map came out 0.2% small). The
    default since stop 69: with readings matched up to 40 m (stop 68) the benchmark's
    lasers reach past the matcher's limit and it leaves their runs as they were (every
    relations row, local and full, the same to the last digit); it bites where the laser's
    range is the horizon (the worlds' 8 m lasers). Measured at stop 69, off -> on, this
    machine, one run each: worlds, pose graph on, seeds 0 / 1 / 2, true odometry: office
    0.0920 / 0.0682 / 0.0498 -> 0.0444 / 0.0433 / 0.0473 m, corridors 0.0049 / 0.0043 /
    0.0051 -> 0.0051 / 0.0037 / 0.0047, hall 0.0038 / 0.0035 / 0.0043 -> 0.0036 / 0.0049 /
    0.0044, crowd 0.0107 / 0.0067 / 0.0104 -> 0.0103 / 0.0061 / 0.0063, wards 0.0057 /
    0.0060 / 0.0063 -> 0.0058 / 0.0050 / 0.0054, arena within 0.1 mm; drifting: office
    0.1110 / 0.1225 / 0.0517 -> 0.0639 / 0.0734 / 0.0797, hall 0.0038 / 0.0050 / 0.0367 ->
    0.0037 / 0.0053 / 0.0052, corridors 0.0075 / 0.0066 / 0.0095 -> 0.0069 / 0.0064 /
    0.0088, crowd 0.0069 / 0.0065 / 0.0062 -> 0.0073 / 0.0064 / 0.0065, wards 0.0076 /
    0.0059 / 0.0097 -> 0.0098 / 0.0059 / 0.0103, arena within 0.1 mm; the corridors with
    drifting odometry find every box event either way (16 / 16 arrivals, 17 / 17
    departures); Radish (seed 0) at or below the better of Karto and GMapping on 30 of 39
    rows either way, geometric mean of the 39 ATE ratios 0.985 (edmonton harsh 0.619 ->
    0.367 m, freiburg-campus perfect 0.393 -> 0.255; infinite-corridor perfect 0.395 ->
    0.500, belgioioso moderate 0.083 -> 0.098). Off before (measured at 20 m:
    bench/configs/within_reach.toml)."""
    reach_margin_m: float = 0.3
    """How far inside a key scan's reach an end point must be to be matched (metres)."""
    clear_seen_through: bool = False
    """A key scan's end points that a later key scan saw through (its beams in that
    direction, and in the two beside, all ending more than ``SEEN_THROUGH_M`` beyond them:
    a walker who walked on, a door opened) leave the local map, as a probability grid's
    misses clear a submap: the map a scan is matched against holds what stands, not the
    trail of what moved. Off: measured with the pose graph off (one run each; a beam with
    no return then said nothing), the perfect-odometry worlds office / crowd / corridors /
    hall / arena 0.110 / 0.0145 / 0.0475 / 0.0355 / 0.0060 -> 0.209 / 0.109 / 0.0346 /
    0.0147 / 0.0065 m (the hall's walkers no longer pull the matches; the crowd and the
    office lose; with no-return beams free to the laser's reach, seeds 0-2, geometric
    mean of the 15 ATEs 0.0319 -> 0.0603), relations MIT
    0.0632 -> 0.0672, Intel 0.1115 -> 0.1276, FR079 0.0731 -> 0.0744; MIT 1.27x the
    wall time (five pairs run in turn, 8.02 against 6.30 s). Measured again at 1bcc5af
    (stop 67), off -> on, one run each: worlds, pose graph on, seeds 0 / 1 / 2, ATE m,
    true odometry office 0.0920 / 0.0682 / 0.0498 -> 0.0568 / 0.0490 / 0.0755, crowd
    0.0107 / 0.0067 / 0.0104 -> 0.0098 / 0.0062 / 0.0065, the rest within 0.6 mm;
    drifting office 0.1110 / 0.1225 / 0.0517 -> 0.0629 / 0.0596 / 0.0498, hall 0.0038 /
    0.0050 / 0.0367 -> 0.0041 / 0.0037 / 0.0059, crowd 0.0069 / 0.0065 / 0.0062 -> 0.0079 /
    0.0068 / 0.0073 (geometric mean of the 36 ratios 0.889); the crowd's steps (exact
    odometry, pose graph off, scale not learned) +0.127 -> +0.033 mm long: the walkers'
    trail no longer pulls; relations, local / full, MIT 0.0384 / 0.0266 -> 0.0498 /
    0.0264, Intel 0.0908 / 0.0138 -> 0.0504 / 0.0140, FR079 0.0724 / 0.0650 -> 0.0735 /
    0.0649, Intel bag 0.0645 / 0.0142 -> 0.0764 / 0.0144, FR079 bag 0.0763 / 0.0621 ->
    0.0770 / 0.0623; five perturbed copies, local, median (spread): MIT 0.0390 (22%) ->
    0.0352 (20%), Intel 0.0739 (17%) -> 0.0770 (31%); Radish (seed 0) 29 of 39 rows at or
    below the better peer (28), geometric mean of the 39 ratios 1.073 (0.983 without
    freiburg-campus moderate 0.84 -> 11.4 m and harsh 15.0 -> 32.6). Still off: Intel's
    copies spread past issue 36's 20% and the campus breaks (bench/configs/
    clear_seen_through.toml)."""
    skip_seen_free: bool = True
    """ICP refines the correlative search's pose without the scan's end points that land,
    at that pose, where ``seen_free_views`` key scans of the local map saw through
    (``clear_seen_through``'s test, a beam with no return free as far as the laser
    reaches): a walker where the wall behind was seen, a box brought in. The paper's own
    idea, that what stands where the map saw free space is not the map (Table 2), used
    for the match. On, with ``confirm_jumps`` (see there for the two together; alone it
    lost FR079 to one glitched scan). With the pose graph off, the perfect-odometry worlds
    (seeds 0, 1, 2; geometric mean of the 15 ATEs 0.0319 -> 0.0215 m, the worst 0.90 ->
    0.127: the hall of seed 2, where a walker beside the robot's path dragged every match
    3.5 cm, 0.90 -> 0.025); five perturbed copies of the real logs, medians MIT 0.0630 ->
    0.0545, Intel 0.1295 -> 0.0966, FR079 0.0822 -> 0.1141."""
    confirm_jumps: bool = True
    """After a scan placed against its wheel odometry (the correlative search's pose beyond
    the odometry's window: a slip, a glitch, or a scan that fits nowhere well and far off
    a little better), the next scan is also searched around the odometry since the last
    scan that agreed with it, and the better fit wins: a true glitch is confirmed (the
    next scan fits where the jump put it), a false jump is undone one scan later (FR079's
    glitched scan at 15 min, which turned the local map 20° for good in two perturbed
    copies of five). Pose graph off, five perturbed copies, medians: with
    ``skip_seen_free`` MIT 0.0545 -> 0.0619, Intel 0.0966 -> 0.0997, FR079 0.1141 -> 0.0796
    (spread 56% -> 6%); alone MIT 0.0630 -> 0.0573, Intel 0.1295 -> 0.1464, FR079 0.0822 ->
    0.0755. The two together, against the two off, five copies each,
    local MIT 0.0630 -> 0.0619, Intel 0.1295 -> 0.0997, FR079 0.0822 -> 0.0796, full
    MIT 0.0270 -> 0.0277, Intel 0.0156 -> 0.0154, FR079 0.0652 -> 0.0648; the
    perfect-odometry worlds' 15 runs 0.0319 -> 0.0229 m with the pose graph off (worst
    0.904 -> 0.199), 0.0118 -> 0.0083 with it on; the Radish rows even (geometric mean of
    the ratios 0.99; 27 of 39 at or below the better of Karto and GMapping, 25 before).
    The default since stop 54, a row lost with it: bench/sessions.py's corridors of seed 0
    no longer place the second session in the first's map (two places fit, 0.96 and 0.91:
    the ring of corridors is nearly symmetric, and seed 2 refuses either way). (Radish
    freiburg-079's two corners either side of a thin partition came 4.96 cm apart, two
    rows of the landmark map: corners closer than a map cell are one row since; the hall's
    second session reported a wall one cell thinner as a removed object: ``[changes]
    skip_wall_faces`` mends that.)"""
    seen_free_views: int = 4
    """... seen through by at least this many key scans (the real logs' own walls give no
    return now and then: one view drops a fifth of MIT CSAIL's end points, four 3%)."""
    icp: IcpConfig = field(default_factory=IcpConfig)
    """ICP's refinement of the correlative search's pose (and the whole match where
    ``method = "icp"``); ``[loop.icp]`` is the loop closures' own."""
    correlative: CorrelativeConfig = field(default_factory=CorrelativeConfig)
    """The correlative search (method = "correlative")."""

    def check(self) -> None:
        require([(self.method in ("icp", "correlative"),
                  "match.method must be icp or correlative"),
                 (self.seen_free_views >= 1, "match.seen_free_views must be >= 1"),
                 (self.normal_gap == 0 or self.normal_gap > 1,
                  "match.normal_gap must be 0 (off) or > 1"),
                 (self.thin_to in ("first", "mean"), 'match.thin_to must be "first" or "mean"'),
                 (self.inliers_over in ("all", "seen") and self.lost_over in ("all", "seen"),
                  'match.inliers_over and match.lost_over must be "all" or "seen"'),
                 (0.0 < self.seen_inliers <= 1.0, "match.seen_inliers must be in (0, 1]")])
        self.icp.check()
        self.correlative.check()


@dataclass(frozen=True)
class LoopConfig:
    """Pose-graph and loop-closure parameters (units in the names)."""

    enabled: bool = True
    """False: the EKF's estimate is the result (no pose graph)."""
    node_distance_m: float = 0.5
    """A new graph node after this much motion ..."""
    node_angle_deg: float = 15.0
    """... or this much turning."""
    min_travel_m: float = 8.0
    """Only nodes at least this far back along the path are loop candidates."""
    search_radius_m: float = 1.0
    """Candidates lie within this radius of the current estimate ..."""
    drift_per_m: float = 0.05
    """... plus this share of the graph distance between the two nodes (the driving between
    them, loop closures being shortcuts: see :meth:`BackEnd.graph_distance`) ..."""
    max_search_radius_m: float = 30.0
    """... up to this. 30 m rather than 6 (until stop 62): where the front end drifts
    metres between two passes (outdoors, few walls in reach) a 6 m window never reaches
    the place. Radish freiburg-campus with our moderate odometry (the front end 9 m and
    1.5° off at its first return, 654 m driven) closes 209 loops instead of 4, ATE 24.8 ->
    0.79 m (GMapping 1.25); the raw benchmark logs and the worlds are unchanged. A wide
    window is searched block by block (:class:`loopmatch._Blocks`), 10 times faster than
    cell by cell and with the same answer."""
    search_angle_deg: float = 10.0
    """Rotation window of the search (plus 1° per 10 m of graph distance)."""
    max_search_angle_deg: float = 30.0
    """... up to this (degrees)."""
    submap_nodes: int = 8
    """Scans of this many nodes on each side of the old node make the matched submap (none
    of the stretch just driven). 8 rather than 4: full runs Intel 0.0172 -> 0.0143 m,
    FR079 0.0702 -> 0.0659, FR079 bag 0.0694 -> 0.0622, MIT and the Intel bag equal;
    Radish's geometric mean of ATE ratios 0.959; the office world worse (0.0566 -> 0.0598
    m with true odometry) and one false vacated place in the corridors world
    (bench/configs/submap4.toml runs the old size)."""
    query_nodes: int = 0
    """The new scan plus this many earlier nodes' scans are matched."""
    min_score: float = 0.55
    """Mean likelihood of the matched points (0–1) for a closure."""
    min_constraint_ratio: float = 0.1
    """Scans that constrain their position this much less in one direction than in the other
    (a corridor's two walls) are not matched."""
    max_ambiguity_m: float = 1.0
    """A match that could slide farther than this (standard deviation of the equally good
    offsets, e.g. along a featureless corridor) is not used."""
    seen_only: bool = False
    """A closure's match is scored on the end points that land where the old submap's
    scans looked (inside their fans, and a wall's reach beyond), at least half of them:
    an end point where the old scans never looked is neither a hit nor a miss, so the
    search does not slide the new scans to overlap the old submap (a corridor's end wall
    seen now, never then). Off: it loses the worlds. With ``corridor_closures`` (the two
    together straighten the office's first pass and, seed 0, stop most of its pull along
    the corridor), true odometry, seeds 0-2, ATE m: office 0.0535 / 0.0386 / 0.0519 ->
    0.0310 / 0.0746 / 0.0745, corridors 0.0042 / 0.0045 / 0.0043 -> 0.0059 / 0.0056 /
    0.0065, hall 0.0039 / 0.0035 / 0.0042 -> 0.0053 / 0.0052 / 0.0050, crowd 0.0128 /
    0.0083 / 0.0084 -> 0.0129 / 0.0086 / 0.0087, arena 0.0028 / 0.0028 / 0.0033 -> 0.0029
    / 0.0029 / 0.0035; drifting, seed 0: office 0.2812 -> 0.2543, corridors 0.0547 ->
    0.0558, hall 0.0044 -> 0.0051, crowd 0.0075 -> 0.0083, arena 0.0030 either way. A
    score over fewer points passes ``min_score`` more often: the office's closures 97 ->
    690. Alone, seed 0: office 0.0535 -> 0.1514 (true odometry), 0.2812 -> 0.2918."""
    corridor_closures: bool = False
    """Match a corridor's scans too, and where a match could slide along one direction
    (farther than ``max_ambiguity_m``, or its equally good offsets reach the search
    window's edge) enter it with no information along that direction: it ties the two
    poses across the corridor and in heading, never along it (a closure kept there would
    hold the search's guess, and many such closures, erring alike, hold it firmly). Off:
    a corridor's scans are not matched and an ambiguous match is not used. Off by
    default: it loses the office world. With true odometry (seeds 0-2) its first pass
    down the 50 m corridor, which no closure reached, came out bent 0.21 m sideways; with
    corridor closures it lies straight, but it is then pulled 0.5-0.7 m along the corridor
    by closures whose old submap never saw the wall the new scans see (the search slides
    the scans to overlap it), ATE 0.0535 / 0.0386 / 0.0519 -> 0.1003 / 0.0823 / 0.1136 m.
    Drifting odometry (seed 0): office 0.2812 -> 0.2674, corridors 0.0547 -> 0.0545, crowd
    0.0075 -> 0.0074; the other worlds within 0.2 mm either way."""
    corridor_axis: str = "ambiguity"
    """With ``corridor_closures``, which corridor matches lose their information along the
    corridor: "ambiguity", those whose equally good offsets spread along it (as above);
    "walls", every one, along the direction the matched scans' walls leave free (the
    normals' weakest axis), however sure the search was: a search that placed the scans
    along a corridor did it on what lies beyond its walls (a door, the far end seen by
    one side only), not on the corridor. "ambiguity" kept: it loses the office world.
    Measured at 613fa90 (this option added), ATE m, pose graph on, true odometry seeds 0 /
    1 / 2 and drifting seed 0: corridor closures off (the default) 0.0920 / 0.0682 /
    0.0498 / 0.1110; on, "ambiguity" 0.1010 / 0.1236 / 0.1217 / 0.1204, "walls" 0.1490 /
    0.1983 / 0.2246 / 0.2035; "walls" with ``seen_only`` 0.0594 / 0.0798 / 0.0880 /
    0.0769, and with ``[match.correlative] seen_only`` as well 0.0802 / 0.0673 / 0.1089 /
    0.0682. With "walls" the corridor's passes lie straight (seed 0, not aligned: within 30
    mm across, up to 0.4 m with the default) but come out short: what places them along
    it is then the pose graph's chain alone, whose matches fall short where the local map
    ends (bench/configs/corridor_walls.toml)."""
    min_inliers: float = 0.65
    """The match refined by ICP must pair up this share of the points ..."""
    max_rms_m: float = 0.05
    """... at most this far from their lines, RMS (metres)."""
    attempt_every_m: float = 0.0
    """Try at most once per this much driven (0: at every node with a candidate). Every
    node rather than once a metre (1.0 until stop 58): more closures, each weighed by the
    graph (the hall driven 1 h: 3526 instead of 1505). Measured at 40416f7, one run each
    unless said: full relations MIT 0.0265 -> 0.0263 m, Intel 0.0146 -> 0.0136, FR079 with
    its original mount 0.0308 -> 0.0305, Intel bag 0.0153 -> 0.0144, FR079 bag (original
    mount) 0.0314 -> 0.0311; five perturbed copies, full, median (spread): MIT 0.0266 (3%)
    -> 0.0268 (2%), Intel 0.0144 (5%) -> 0.0138 (9%), Radish intel moderate 0.0642 (14%) ->
    0.0677 (11%), aces moderate 0.0859 (26%) -> 0.0798 (21%), seattle harsh 0.0446 (12%) ->
    0.0458 (11%); Radish seed 0, 26 of 39 rows at or below the better peer either way,
    medians 0.118 / 0.134 / 0.129 -> 0.116 / 0.132 / 0.129 m; worlds with true odometry,
    seeds 0-2, office 0.0677 / 0.0423 / 0.0534 -> 0.0535 / 0.0386 / 0.0519, every other
    world within 0.1 mm; MIT 0.96x the wall time, the 1 h hall 1.01x (pairs run in turn)."""
    prior_every_m: float = 1.0
    """With ``--prior``: the scans are matched on the prior's walls at most once per this
    much driven."""
    chain_noise_scale: float = 1.5
    """The edges between consecutive nodes are this many times less sure than
    ``chain_information`` says (standard deviations)."""
    chain_information: str = "motion"
    """What the edge between two consecutive nodes is as sure of: "motion", the EKF's motion
    noise model over the motion between them (as sure along a corridor as across it);
    "matched", the covariances of the scan-matched increments between them compounded (the
    model's where a scan was not matched), so a loop closure can move the graph along a
    corridor where the matches could not see, and not across it."""
    agree_chi2: float = 0.1
    """A closure whose error under the current estimate is below this χ² already agrees
    with the graph: the optimization waits (for the next disagreeing closure or the end),
    so revisiting a well-mapped place does not re-solve the whole graph every metre."""
    edge_sigma_m: float = 0.05
    """Added (as a standard deviation) to a loop edge's translation uncertainty."""
    consistent_chi2: float = 11.34
    """A closure within this χ² of the graph's estimate (99%, 3 dof) is added at once; any
    other waits for a second closure that agrees with it ..."""
    pair_window_m: float = 50.0
    """... made within this much driving after it (the last ``pending_closures`` wait) ..."""
    pair_min_separation_m: float = 3.0
    """... but at least this far along (two matches from nearly the same place see the same
    view, so they share its aliasing: a corridor's doors matched one door off) ..."""
    pair_tolerance_m: float = 0.15
    """... closing the loop of the two closures to this distance (metres, plus
    ``drift_per_m`` times the path between their ends) ..."""
    pair_tolerance_deg: float = 2.0
    """... and this angle (degrees) ..."""
    pair_drift_deg_per_m: float = 0.2
    """... plus this much per metre of that path (degrees per metre)."""
    pending_closures: int = 8
    """Closures waiting for a partner: at most this many, the oldest dropped first."""
    online_nodes: int = 2000
    """While the log runs, an optimization moves at most this many nodes: those nearest,
    through the graph, to the closure just made (the rest hold until the whole graph is
    optimized at the end), so a closure costs the same late in a long log as early on ..."""
    online_flops: float = 15e6
    """... and only as many of them as a factorization of about this many multiplications
    holds (a place revisited for hours ties its passes together: 2000 nodes of a hall driven
    for 4 h took a median 2.5 times the factorization work of the 1 h log's)."""
    max_range_m: float = 40.0
    """A node's readings beyond this are not matched (metres; 20 before stop 68, as
    ``[match] max_range_m``)."""
    revisit: bool = False
    """Where the robot is back on a node of the graph that a loop closure has tied to the
    rest (one ``min_travel_m`` or more back, within ``node_distance_m`` and
    ``node_angle_deg`` of its estimate), match the scan on that node's submap and, where
    the graph agrees (``consistent_chi2``), place the robot there instead of making a
    node: a place revisited for hours does not grow the graph. Each placement after the
    first is the match fused with where the last one and the motion since put the robot.
    Off: the simulated worlds, 600 s, seed 0, drifting odometry, nodes hall 651 -> 131,
    arena 660 -> 111, corridors 912 -> 545, but ATE 0.0044 -> 0.0072, 0.0030 -> 0.0034
    and 0.0547 -> 0.0526 m: a revisit places the robot by one scan's match and the motion,
    where the graph weighs many closures."""
    icp: IcpConfig = field(default_factory=IcpConfig)
    """ICP's refinement of a closure's correlative match (the front end's is
    ``[match.icp]``)."""

    def check(self) -> None:
        require([
            (self.node_distance_m > 0 and self.node_angle_deg > 0,
             "loop.node_distance_m and node_angle_deg must be > 0"),
            (self.pending_closures >= 1, "loop.pending_closures must be >= 1"),
            (self.online_nodes >= 2, "loop.online_nodes must be >= 2"),
            (self.online_flops > 0, "loop.online_flops must be > 0"),
            (self.chain_information in ("motion", "matched"),
             "loop.chain_information must be motion or matched"),
            (self.max_range_m > 0, "loop.max_range_m must be > 0"),
            (self.corridor_axis in ("ambiguity", "walls"),
             'loop.corridor_axis must be "ambiguity" or "walls"'),
        ])
        self.icp.check()


@dataclass(frozen=True)
class ChangeConfig:
    """Change events (changes.csv): objects that appeared, places vacated, movers' tracks."""

    enabled: bool = True
    """False: no change events (changes.csv has its header only)."""
    blob_gap_m: float = 0.2
    """End points of successive beams closer than this (metres) belong to one object."""
    track_gate_m: float = 0.5
    """A blob continues the track whose last blob is nearest, if within this (metres) ..."""
    track_gap_s: float = 1.0
    """... and seen at most this long ago (seconds)."""
    moving_speed_m_s: float = 0.15
    """A track whose place changes faster than this is moving (m/s; the median of its speed
    over ``still_s / 2`` at a time, so a standing object seen from another side, whose seen
    centre jumps once, stays still)."""
    moving_distance_m: float = 0.5
    """... and it must also go this far from where it was first seen (metres): further than
    the seen centre of a standing object wanders."""
    still_s: float = 3.0
    """An object counts as standing (appeared, or vacated from S) only if it was seen
    standing for this long (seconds; appeared: seen at the start and at the end of that time
    and in at least half its scans): a walker stands nowhere that long."""
    merge_distance_m: float = 0.3
    """Stationary tracks whose places lie this close (metres) are one object."""
    join_gap_s: float = 2.0
    """Two moving tracks are one mover's if the second begins at most this long after the
    first was last seen (seconds; or while it is still seen: a walker's two legs) ..."""
    walker_speed_m_s: float = 2.0
    """... no farther from the first's last place than ``track_gate_m`` plus this speed
    (m/s) times the time between: a person who stops, or is hidden a moment, and walks on
    is one track."""
    min_scans: int = 5
    """An event needs evidence from at least this many scans."""
    min_area_m2: float = 0.02
    """A vacated place needs at least this many square metres of cells gone Free."""
    skip_wall_faces: bool = True
    """A vacated place each of whose cells lies beside one S still holds Occupied is a
    wall's face seen a cell off (a second session's pose a few centimetres from the
    first's thins the wall it mapped), not an object gone. Measured (bench/accuracy.py,
    S/D, the five worlds with true and drifting odometry): two false vacated events fewer
    (corridors 17 of 18 true -> 17 of 17, office 1 of 10 -> 1 of 9), none of the 70 true
    ones lost; MIT CSAIL 23 -> 21 vacated; the hall's second session with ``[match]
    skip_seen_free`` and ``confirm_jumps``: a wall thinned by one cell no longer reported
    as removed."""
    max_object_m2: float = 4.0
    """An object that appeared or vacated its place is at most this large (square metres of
    its footprint: a pallet, a table, a parked cart): beyond, it is the map disagreeing
    with itself (a wing drawn twice, a wall seen through a doorway), not reported."""

    def check(self) -> None:
        require([
            (min(self.blob_gap_m, self.track_gate_m, self.merge_distance_m) > 0,
             "changes: blob_gap_m, track_gate_m and merge_distance_m must be > 0"),
            (min(self.track_gap_s, self.still_s, self.join_gap_s, self.walker_speed_m_s) >= 0
             and self.moving_speed_m_s > 0,
             "changes: track_gap_s, still_s, join_gap_s and walker_speed_m_s must be >= 0, "
             "moving_speed_m_s > 0"),
            (self.min_scans >= 1 and self.min_area_m2 >= 0 and self.max_object_m2 > 0,
             "changes: min_scans must be >= 1, min_area_m2 >= 0, max_object_m2 > 0"),
        ])


@dataclass(frozen=True)
class RecordConfig:
    """A recording of the run for Foxglove and RViz (``--record``; see
    dynslam_formats.recording): an MCAP file in the output folder or at a path."""

    file: str | None = None
    """The recording, ending in .mcap (``--record``): a bare file name is written in the
    output folder, a path (``~/runs/today.mcap``) there, atomically; unset: no recording."""
    period_s: float = 5.0
    """The maps, paths and landmarks are sent at most once every this many seconds of log
    time, when they changed, and once at the end (``--record-period``)."""

    def check(self) -> None:
        require([
            (self.period_s > 0, "record.period_s must be > 0"),
            (self.file is None or (self.file.endswith(".mcap") and len(Path(self.file).name) > 5),
             f"record.file must be a file name or path ending in .mcap (a bare name is written "
             f"in the output folder), not {self.file!r}"),
        ])



@dataclass(frozen=True)
class PriorConfig:
    """A log placed in an earlier session's map (``--prior DIR``): how sure the placement
    of its first scan must be (see dynslam_cli.localization.globalsearch)."""

    min_score: float = 0.5
    """The first scan's end points must lie on the prior map's walls at least this well
    (the mean of exp(−d²/2σ²) over them, d the distance to the nearest Occupied cell, σ 8
    cm; 1 is every point on a wall): a log from another building is not placed."""
    rival_evidence: float = 4.6
    """The best place must be at least e^this times as likely as any other (``rival_m``
    away, or turned ``rival_deg``), or the placement is ambiguous (a symmetric room, a row
    of like offices): an error, unless ``--initial-pose`` says which. The likelihood of a
    place: each end point near a wall with the field's spread or, with probability 0.1, an
    outlier, the points counting as at most 40 independent ones for one scan (neighbouring
    beams see the same wall) and, for the scans driven after it, as one per square metre
    of the map they cover where that is more. 4.6: a hundred times."""
    rival_share: float = 0.75
    """With ``rival_search = "score"``: other places scoring below this share of the best
    (the mean field value at the end points) are not looked for."""
    rival_search: str = "likelihood"
    """Which rival the ambiguity test weighs: "likelihood", the likeliest pose elsewhere,
    searched only down to where it could fail the test (its log-likelihood within
    ``rival_evidence`` of the best's: the rival the test means); "score", the pose
    elsewhere with the best mean field value (the default before). The same decisions on
    bench/sessions.py (seeds 0 and 1, ten second sessions) and on the MIT and Intel halves,
    and MIT CSAIL's two rival searches take 0.76 s instead of 1.72 (a rival elsewhere is
    then reported only where it came within the margin)."""
    rival_m: float = 1.0
    """How far a rival place lies from the best (metres) ..."""
    rival_deg: float = 30.0
    """... or how far it is turned (degrees)."""
    max_travel_m: float = 40.0
    """Where the first scan alone fits more than one place (a corridor), the scans driven
    after it are matched with it, put together by their odometry, up to this far (metres;
    tried at each doubling of the distance from a 16th of it). 40 rather than 10: the
    arena world's second session, refused after 10 m (its four-fold twin e^4.3 as likely
    against the bar's e^4.6), is placed right (0.0085 m in the prior's frame); a refusal
    takes longer (the corridors world: 1.06 s against 0.48), and the first retry comes
    after 2.5 m, not 0.6 (MIT CSAIL's second half: placed after 5.2 m, not 3, by two
    whole-map searches, not three)."""
    steady_s: float = 0.0
    """Once the scans put together to place a log span this long (seconds), an end point
    enters the search only where the scans saw something for at least this long (within
    one search square, 3 cells): a wall is seen scan after scan, a walker passes. 0: every
    end point. Off: measured with 1 s on bench/sessions.py, seeds 0 and 1, before the
    evidence grew with the drive (dcaad9f: 10 of 10 placed without it), it places the
    hall's second session of seed 1 (refused without: e^3.0 after 40 m) but no longer the
    corridors' (e^3.7), 8 of 10 either way; MIT CSAIL's second half is placed as without
    it (after 5.2 m, the same pose to 6 µm)."""
    initial_tolerance_m: float = 1.0
    """With ``--initial-pose``: the best place within this distance of the pose given
    (metres) ..."""
    initial_tolerance_deg: float = 30.0
    """... and this turn (degrees) is taken, if it scores ``min_score``; otherwise the whole
    map is searched, and a unique place found elsewhere is taken with a warning."""

    def check(self) -> None:
        require([
            (0 < self.min_score < 1, "prior.min_score must be in (0, 1)"),
            (0 < self.rival_share <= 1, "prior.rival_share must be in (0, 1]"),
            (self.rival_search in ("score", "likelihood"),
             'prior.rival_search must be "score" or "likelihood"'),
            (self.rival_evidence >= 0, "prior.rival_evidence must be >= 0"),
            (self.rival_m > 0 and 0 < self.rival_deg <= 180,
             "prior.rival_m must be > 0 and rival_deg in (0, 180]"),
            (self.max_travel_m >= 0 and self.steady_s >= 0,
             "prior.max_travel_m and prior.steady_s must be >= 0"),
            (self.initial_tolerance_m > 0 and 0 < self.initial_tolerance_deg <= 180,
             "prior.initial_tolerance_m must be > 0 and initial_tolerance_deg in (0, 180]"),
        ])
