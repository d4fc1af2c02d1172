"""Tuning parameters of the fusion core, one frozen dataclass per concern.

These are the config file's [geolocation] and [tracker] sections as they are: the
config loader builds them from TOML and reports a bad value by key. Every field has
a unit in its name (or is a dimensionless count/probability/log-odds) and a default
that suits a small rover with a forward camera on a warehouse floor.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields


def _require(cond: bool, owner: object, name: str, what: str) -> None:
    if not cond:
        value = getattr(owner, name)
        raise ValueError(f"{name} = {value!r}: {what}")


def _all_finite(owner: object) -> None:
    for f in fields(owner):  # type: ignore[arg-type]
        value = getattr(owner, f.name)
        if isinstance(value, float) and not math.isfinite(value):
            raise ValueError(f"{f.name} = {value!r}: must be a finite number")


@dataclass(frozen=True)
class GeolocationParams:
    """How pixels become floor points, and how uncertain they are."""

    floor_down_m: float = 0.10  # the floor's depth below the vehicle reference point (body z)
    max_range_m: float = 8.0  # farther floor points are rejected
    min_range_m: float = 0.2  # nearer ones (the rover's own bumper) too
    pixel_sigma_px: float = 3.0  # 1-sigma of the detected floor-contact pixel
    attitude_sigma_deg: float = 1.0  # 1-sigma of roll/pitch/yaw
    position_sigma_m: float = 0.10  # 1-sigma of the vehicle's local position
    # 1-sigma added across the ray (on the floor) for a body cut by the frame's left or
    # right edge: the part beyond the edge is unknown, so its centre may lie that way,
    # beyond the edge's plane, which holds the ray (fusion.geolocate). On a
    # recorded 10-minute e2e mission one pass saw the whole body `mixed` T1 cut by the
    # left edge on 12 frames, 0.8 m off, and the victim's reported position followed
    # it (mean error over the mission 0.32 m; with 0.3 m here 0.17 m, 2026-11-27).
    frame_cut_sigma_m: float = 0.3
    max_pose_extrapolation_s: float = 0.10  # a frame further than this from any pose is refused
    body_length_m: float = 1.7  # a lying adult, for the expected image area
    body_width_m: float = 0.45
    body_height_m: float = 0.18  # its mean thickness: from a low camera its side shows

    def __post_init__(self) -> None:
        _all_finite(self)
        _require(
            self.max_range_m > self.min_range_m >= 0.0,
            self,
            "max_range_m",
            "must exceed min_range_m >= 0",
        )
        _require(self.pixel_sigma_px > 0.0, self, "pixel_sigma_px", "must be > 0")
        _require(self.attitude_sigma_deg >= 0.0, self, "attitude_sigma_deg", "must be >= 0")
        _require(self.position_sigma_m >= 0.0, self, "position_sigma_m", "must be >= 0")
        _require(self.frame_cut_sigma_m >= 0.0, self, "frame_cut_sigma_m", "must be >= 0")
        _require(
            self.max_pose_extrapolation_s >= 0.0, self, "max_pose_extrapolation_s", "must be >= 0"
        )
        _require(self.body_length_m > 0.0, self, "body_length_m", "must be > 0")
        _require(self.body_width_m > 0.0, self, "body_width_m", "must be > 0")
        _require(self.body_height_m >= 0.0, self, "body_height_m", "must be >= 0")


@dataclass(frozen=True)
class TrackerParams:
    """Association, life cycle and urgency of victim tracks."""

    gate_chi2: float = 9.21  # Mahalanobis gate, chi-square with 2 dof (9.21 = 99 %)
    process_noise_m2_s: float = 0.002  # position random walk of a static victim, m^2 per second
    hit_log_odds: float = 0.85  # support added by a detection
    # Support added when in view and not detected. The people detector finds a body
    # in view on about a third of the frames (its extra passes take turns): at -0.4 a
    # whole body in plain view lost more than it gained (0.3 x 0.85 < 0.7 x 0.4) and
    # was never confirmed (scenario suite, 2026-11-26: recall 0.375 -> 0.5 at -0.2,
    # no more false victims). A one-frame phantom in view still dies after 12 frames.
    miss_log_odds: float = -0.2
    # A miss counts only where the detector would likely have seen a body: within this
    # range (m). On the simulator's uncovered bodies the person detector finds 26 of
    # 32 views at 2.5 m and 14 of 32 at 3.5 m; farther, not seeing a body is no
    # evidence against it (suite 2026-11-26: 12 -> 13 of 24 found, false victims same).
    miss_max_range_m: float = 3.5
    # Tentative -> confirmed at or above this: three detections with at most two
    # misses between them (3 x 0.85 - 2 x 0.2 = 2.15; three misses leave 1.95), or
    # more detections with more misses. Until 2026-11-27 it was 2.5, three detections
    # with no miss between: the person detector finds a body in view on about a third
    # of the frames, and two people in plain view were seen on three of five frames
    # and never confirmed (a child at 2 m, a face-down body at 1.5 m). At 2.1 the
    # suite found 16 of 24 instead of 14 with no more false victims; at 1.9 (three
    # misses) 16 with 7 false victims (cached suite replay, 2026-11-27).
    # Demanding also a spread of viewing directions (5 or 10 degrees, seen from the
    # track) lost 2 of seed1's 4 victims, seen in bursts from one side, and at 5
    # degrees kept its false one (suite, 2026-11-26): not done.
    confirm_log_odds: float = 2.1
    # Nor is a tentative track confirmed within this distance (m) of a confirmed
    # victim, whatever the chi-square says, unless the two were detected in the
    # same frame (two people side by side): one body's fixes scatter that far (a
    # lone face or hand of it, its near edge seen from either side, a frame-cut
    # view) and never come together.
    # In the 20-minute chaos mission the rover's passes over the people confirmed a
    # second ID for one of them 8 times, each merged seconds later and announced
    # twice (suite and a replay of the chaos patrol, 2026-11-27: 4 such merges -> 0;
    # at 0.8 m, 2 were left).
    same_victim_m: float = 1.0
    delete_log_odds: float = -1.5  # tentative tracks die below this
    max_log_odds: float = 8.0  # clamp, so a long-seen track can still lose support
    tentative_timeout_s: float = 20.0  # a tentative track not seen this long dies
    not_seen_recently_s: float = 30.0  # a confirmed victim out of sight this long is flagged
    # Two confirmed tracks closer than this (95 %, 2 dof) merge. Fixes seen from one
    # side share that side's floor-point error, which the filter takes for
    # independent noise: on a 10-minute recording of the e2e mission a ghost of one
    # body, 0.32 m from its victim after 47 fixes, confirmed as a second ID and merged
    # later. Widening both covariances by 0.15 m (1-sigma) for this test removed that
    # ID, but then two people lying 0.6 m apart merge (2026-11-27): not done.
    merge_chi2: float = 5.99
    urgency_window: int = 15  # recent visibility observations used for the class
    # A victim only the thermal camera has found, which the colour camera has looked
    # at this many times (lit, within miss_max_range_m) and never seen, shows nothing
    # of its body to the eye: its warmth comes through cover (a blanket, dust), and
    # its visibility is at most covered_visibility_pct (CRITICAL). The thermal
    # camera alone cannot tell a body under dust from a clothed one (docs/VISION.md).
    covered_after_looks: int = 5
    covered_visibility_pct: float = 5.0
    urgency_hysteresis_pct: float = 3.0  # a class boundary must be crossed by this much
    # An unmatched observation this close (chi-square, 2 dof; 18.42 = 99.99 %) to an
    # existing track is an outlier or duplicate of it and starts no new track.
    new_track_exclusion_chi2: float = 18.42
    # A victim under rubble does not move: its uncertainty grows by process noise only
    # for this long after its last detection, however long it stays out of view.
    max_unseen_growth_s: float = 60.0
    # Never associate, exclude or merge beyond this distance, whatever the chi-square
    # says: a person (1.7 m long) and the fix error of a partly buried one at range
    # stay within it (2 m split one victim of the guard mission seed:2 in two).
    max_match_distance_m: float = 3.0
    # A victim's reported position is the geometric median of the newest this many
    # fixes its filter took (fusion.track): on the scenario suite 30, 60, 100 and 200
    # gave the same median error (0.141-0.150 m); on a recorded 10-minute mission
    # 0.05, 0.03, 0.03 and 0.04 m (2026-11-28).
    position_fixes: int = 100

    def __post_init__(self) -> None:
        _all_finite(self)
        _require(self.gate_chi2 > 0.0, self, "gate_chi2", "must be > 0")
        _require(self.process_noise_m2_s >= 0.0, self, "process_noise_m2_s", "must be >= 0")
        _require(self.hit_log_odds > 0.0, self, "hit_log_odds", "must be > 0")
        _require(self.miss_log_odds <= 0.0, self, "miss_log_odds", "must be <= 0")
        _require(self.miss_max_range_m > 0.0, self, "miss_max_range_m", "must be > 0")
        _require(self.confirm_log_odds > 0.0, self, "confirm_log_odds", "must be > 0")
        _require(self.same_victim_m >= 0.0, self, "same_victim_m", "must be >= 0")
        _require(self.delete_log_odds < 0.0, self, "delete_log_odds", "must be < 0")
        _require(
            self.max_log_odds >= self.confirm_log_odds,
            self,
            "max_log_odds",
            "must be >= confirm_log_odds",
        )
        _require(self.tentative_timeout_s > 0.0, self, "tentative_timeout_s", "must be > 0")
        _require(self.not_seen_recently_s > 0.0, self, "not_seen_recently_s", "must be > 0")
        _require(self.merge_chi2 > 0.0, self, "merge_chi2", "must be > 0")
        _require(self.urgency_window >= 1, self, "urgency_window", "must be >= 1")
        _require(self.covered_after_looks >= 1, self, "covered_after_looks", "must be >= 1")
        _require(
            0.0 <= self.covered_visibility_pct < 10.0,
            self,
            "covered_visibility_pct",
            "must be in [0, 10): a covered body reads CRITICAL",
        )
        _require(
            self.new_track_exclusion_chi2 >= self.gate_chi2,
            self,
            "new_track_exclusion_chi2",
            "must be >= gate_chi2",
        )
        _require(self.max_unseen_growth_s >= 0.0, self, "max_unseen_growth_s", "must be >= 0")
        _require(self.max_match_distance_m > 0.0, self, "max_match_distance_m", "must be > 0")
        _require(self.position_fixes >= 1, self, "position_fixes", "must be >= 1")
        _require(
            0.0 <= self.urgency_hysteresis_pct < 10.0,
            self,
            "urgency_hysteresis_pct",
            "must be in [0, 10)",
        )
