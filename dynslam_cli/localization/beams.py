"""Whether a log's scans fit their laser's own beam spacing better than the one the log
states, where a converter may have got it wrong.

An even count of beams over a symmetric field of view cannot hold a beam at each end and
one straight ahead: a laser with an even count leaves one end out, its beams fov/n apart
(a SICK at 1° gives 181 beams over 180°; CARMEN keeps 180 of them). A converter that
spreads those n beams over the whole fov, fov/(n−1) apart, makes every scan 1/n too wide:
the Intel benchmark's ``.orig.bag`` says 180/179° where its Carmen log has 1°, half a
degree out at the edges, 9 cm at 10 m, and the local SLAM's error doubles. That signature
(an even count spanning a whole number of quarter turns) is what is checked: the log's
first scans are matched at both spacings, and the laser's own is taken where its matches
fit the local map better in most of them.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from dynslam_cli.localization.ekf import NoiseModel
from dynslam_cli.localization.scanmatch import MatchConfig, ScanMatcher
from dynslam_cli.types import Scan

CHECK_SCANS = 200
"""How many of the log's first scans are matched at each spacing."""
BETTER_SHARE = 2 / 3
"""The laser's own spacing is taken where its matches fit better in at least this share of
the scans matched at both (and in at least MIN_MATCHED of them). Measured (200 scans):
the Intel bag 80% for 1°; the Carmen logs, whose spacing is right, 14-60% for any other;
FR079's bag 60% (360 beams, 0.28% too wide: too little to tell)."""
MIN_MATCHED = 100
UNIFORM_RAD = 1e-6
"""Beams count as evenly spaced, and a span as a whole number of quarter turns, within
this."""


class SpacingCheck(NamedTuple):
    """The outcome of :func:`check_spacing`: the spacing the log states and the laser's own
    (radians), in how many of how many scans matched at both the laser's fitted better,
    and whether that is enough to read the log at it."""

    stated: float
    own: float
    better: int
    matched: int

    @property
    def convincing(self) -> bool:
        return self.matched >= MIN_MATCHED and self.better >= BETTER_SHARE * self.matched

    def notice(self) -> str:
        """What a user is told when the log is read at the laser's own spacing."""
        return (f"beams read {math.degrees(self.own):.5g} deg apart, not the "
                f"{math.degrees(self.stated):.5g} the log states (a converter's fov/(n-1)): "
                f"{self.better} of {self.matched} of its first scans fit the local map better "
                "so (--beam-step sets the spacing)")

    def to_dict(self) -> dict[str, float | int | bool]:
        """As summary.json's ``input.beam_spacing`` holds it (degrees)."""
        return {"stated_deg": math.degrees(self.stated), "own_deg": math.degrees(self.own),
                "scans_better": self.better, "scans_matched": self.matched,
                "taken": self.convincing}


def converter_spacing(angles: np.ndarray) -> tuple[float, float] | None:
    """The stated spacing (radians) and the laser's own, fov/n, where the beams look spread
    by a converter: an even count of them, evenly spaced, spanning a whole number of
    quarter turns from the first to the last. None otherwise."""
    n = len(angles)
    if n < 4 or n % 2:
        return None
    span = float(angles[-1] - angles[0])
    step = span / (n - 1)
    quarters = span / (math.pi / 2)
    if (abs(quarters - round(quarters)) * math.pi / 2 > UNIFORM_RAD or round(quarters) < 1
            or np.abs(angles - (angles[0] + step * np.arange(n))).max() > UNIFORM_RAD):
        return None
    return step, span / n


def match_errors(scans: Sequence[Scan], cfg: MatchConfig, noise: NoiseModel) -> np.ndarray:
    """Each scan's rms distance (m) to the local map where its match was refined, in a
    front end run over ``scans`` alone (NaN where it was not). The local map keeps the first
    point of each square whatever ``thin_to`` says: BETTER_SHARE was measured so, and a map
    of means tells the spacings apart less (the Intel bag: 89 of 198 scans fit better at 1°
    with means, 158 with first points)."""
    matcher = ScanMatcher(dataclasses.replace(cfg, thin_to="first"), noise)
    errors = np.full(len(scans), np.nan)
    for i, scan in enumerate(scans):
        matcher.increment(scan)
        if matcher.fit_rms is not None:
            errors[i] = matcher.fit_rms
    return errors


def check_spacing(scans: Sequence[Scan], cfg: MatchConfig, noise: NoiseModel
                  ) -> SpacingCheck | None:
    """The log's first ``scans`` (those with the first one's beam count) matched at the
    stated spacing and at the laser's own; None where the beams do not look spread by a
    converter."""
    if not scans:
        return None
    n = len(scans[0].angles)
    scans = [s for s in scans if len(s.angles) == n]
    spacing = converter_spacing(np.asarray(scans[0].angles, dtype=np.float64))
    if spacing is None:
        return None
    stated, own = spacing
    base = match_errors(scans, cfg, noise)
    errors = match_errors([s.respaced(own) for s in scans], cfg, noise)
    both = np.isfinite(base) & np.isfinite(errors) & (base != errors)
    return SpacingCheck(stated, own, int(np.count_nonzero(errors[both] < base[both])),
                        int(both.sum()))
