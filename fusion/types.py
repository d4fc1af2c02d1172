"""Core value types shared between packages.

Frozen dataclasses, SI units in the field names, validated on construction. They
carry no behaviour beyond validation and small derived properties, so every package
(mavlink_io, fusion, companion, scenarios, hq) can exchange them without importing
each other's machinery.

Frames and clocks:
- Local NED: north/east/down in metres from the vehicle's EKF origin.
- Body FRD: forward/right/down from the vehicle's reference point.
- ``t_boot_s``: the autopilot's time since boot (``time_boot_ms`` / 1000).
- ``t_mono_s``: the companion's ``time.monotonic()``.
- ``*_unix_s``: wall time (seconds since the Unix epoch), for people and files.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum, IntFlag, StrEnum

Cov2 = tuple[tuple[float, float], tuple[float, float]]
"""A 2x2 covariance in m^2 as nested tuples (hashable, immutable)."""

# How far from the EKF origin a local NED position can lie: a search area, not a
# continent. Beyond it a value is corrupt or forged, wherever it enters (a vehicle
# message, a report, a saved state).
MAX_LOCAL_M = 100_000.0


class Urgency(IntEnum):
    """Urgency class of a victim from the visible share of the body.

    Values match the dialect's RESCUE_URGENCY enum.
    """

    LIGHT = 1  # more than 50 % visible: low priority
    MEDIUM = 2  # 10 % to 50 % visible: partly buried
    CRITICAL = 3  # under 10 % visible: immediate help

    @classmethod
    def from_visibility(cls, visibility_pct: float) -> Urgency:
        """Class for a visibility in percent (>50 LIGHT, 10..50 MEDIUM, <10 CRITICAL)."""
        if not 0.0 <= visibility_pct <= 100.0 or math.isnan(visibility_pct):
            raise ValueError(f"visibility_pct must be in [0, 100], got {visibility_pct!r}")
        if visibility_pct > 50.0:
            return cls.LIGHT
        if visibility_pct >= 10.0:
            return cls.MEDIUM
        return cls.CRITICAL


class Cue(IntFlag):
    """Which sensing saw a victim, as a bitmask. Values match the dialect's RESCUE_CUE."""

    COLOUR_BODY = 1  # the colour camera's person models saw a body
    COLOUR_PART = 2  # ...or only an exposed part (a hand, a face)
    WARM = 4  # the thermal camera saw its warmth

    def names(self) -> list[str]:
        """The cues set, as lower-case words ("colour_body", "warm")."""
        return [c.name.lower() for c in Cue if c & self and c.name is not None]

    @property
    def cameras(self) -> str:
        """Which camera saw it, in a word: "colour", "thermal", "both" or "" (none)."""
        colour = bool(self & (Cue.COLOUR_BODY | Cue.COLOUR_PART))
        warm = bool(self & Cue.WARM)
        return {(True, True): "both", (True, False): "colour", (False, True): "thermal"}.get(
            (colour, warm), ""
        )


NO_CUES = Cue(0)  # nothing has seen it yet (a report from before the cues were kept)


class Sensor(StrEnum):
    """The camera an observation comes from."""

    COLOUR = "colour"
    THERMAL = "thermal"


class TrackState(IntEnum):
    """Life-cycle state of a victim track. Values match RESCUE_TRACK_STATE."""

    TENTATIVE = 0  # seen, not yet enough support
    CONFIRMED = 1  # enough support: a victim, reported
    NOT_SEEN_RECENTLY = 2  # confirmed, out of sight for a while; never deleted
    MERGED = 3  # merged into an older confirmed track
    RESCUED = 4  # operator marked it rescued
    FALSE_ALARM = 5  # operator marked it a false alarm


def _check_finite(owner: object, **values: float) -> None:
    for name, value in values.items():
        if not math.isfinite(value):
            raise ValueError(f"{type(owner).__name__}.{name} must be finite, got {value!r}")


def _check_cov2(owner: object, name: str, cov: Cov2) -> None:
    (a, b), (c, d) = cov
    _check_finite(owner, **{f"{name}[0][0]": a, f"{name}[0][1]": b, f"{name}[1][1]": d})
    if abs(b - c) > 1e-9 * max(1.0, abs(b)):
        raise ValueError(f"{type(owner).__name__}.{name} must be symmetric, got {cov!r}")
    if a <= 0.0 or d <= 0.0 or a * d - b * c <= 0.0:
        raise ValueError(f"{type(owner).__name__}.{name} must be positive definite, got {cov!r}")


@dataclass(frozen=True)
class GlobalOrigin:
    """The EKF origin of the local NED frame (WGS-84)."""

    lat_deg: float
    lon_deg: float
    alt_m: float  # AMSL

    def __post_init__(self) -> None:
        _check_finite(self, lat_deg=self.lat_deg, lon_deg=self.lon_deg, alt_m=self.alt_m)
        if not -90.0 <= self.lat_deg <= 90.0 or not -180.0 <= self.lon_deg <= 180.0:
            raise ValueError(f"GlobalOrigin out of range: {self.lat_deg}, {self.lon_deg}")
        if self.lat_deg == 0.0 and self.lon_deg == 0.0:
            # ArduPilot reports 0/0 before it has a fix or an origin: not an origin.
            raise ValueError("GlobalOrigin of exactly 0/0 means 'no origin yet'")


@dataclass(frozen=True)
class PoseSample:
    """The vehicle's pose at one instant, in the local NED frame."""

    t_boot_s: float  # autopilot time since boot
    t_mono_s: float  # the same instant on the companion's monotonic clock
    north_m: float
    east_m: float
    down_m: float
    roll_rad: float
    pitch_rad: float
    yaw_rad: float
    vn_m_s: float = 0.0
    ve_m_s: float = 0.0
    vd_m_s: float = 0.0

    def __post_init__(self) -> None:
        _check_finite(
            self,
            t_boot_s=self.t_boot_s,
            t_mono_s=self.t_mono_s,
            north_m=self.north_m,
            east_m=self.east_m,
            down_m=self.down_m,
            roll_rad=self.roll_rad,
            pitch_rad=self.pitch_rad,
            yaw_rad=self.yaw_rad,
            vn_m_s=self.vn_m_s,
            ve_m_s=self.ve_m_s,
            vd_m_s=self.vd_m_s,
        )
        if self.t_boot_s < 0.0:
            raise ValueError(f"PoseSample.t_boot_s must be >= 0, got {self.t_boot_s}")


@dataclass(frozen=True)
class Detection:
    """A victim candidate in one camera frame (pixels; before geolocation)."""

    t_mono_s: float  # capture time of the frame on the companion's monotonic clock
    u_px: float  # the pixel that touches the floor (centre of the visible body part)
    v_px: float
    bbox_xywh_px: tuple[int, int, int, int]
    visible_area_px: float  # pixels of the segmentation mask
    score: float  # detector confidence in [0, 1]
    source: str = ""  # which detector backend produced it
    cues: tuple[str, ...] = ()  # the evidence behind it: "person", "landmarks", "mask", ...
    # The detector's own estimate of a whole body's pixels, for images without a
    # camera geometry (photos); with a geometry the floor's size prior is used.
    expected_area_px: float | None = None
    # The body's axis (NED yaw, feet to head) where the detector can tell it; the
    # floor's size prior then uses that heading instead of the mean over headings.
    body_heading_rad: float | None = None
    # The most of the body the detector saw, 0..1, from evidence other than its mask
    # (the person models' joint heatmaps: a mask fills in a covered body). It caps
    # the visible share the mask gives; None: the mask alone.
    seen_share_max: float | None = None
    # Where a whole body with the joints seen would lie (the pixel of its floor
    # centre), for the floor's size prior, when the body is placed elsewhere (a mostly
    # hidden body is placed where it shows); None: at (u_px, v_px).
    whole_uv_px: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        if self.whole_uv_px is not None and not all(map(math.isfinite, self.whole_uv_px)):
            raise ValueError(f"Detection.whole_uv_px must be finite, got {self.whole_uv_px}")
        if self.seen_share_max is not None and not 0.0 <= self.seen_share_max <= 1.0:
            raise ValueError(
                f"Detection.seen_share_max must be in [0, 1], got {self.seen_share_max}"
            )
        if self.body_heading_rad is not None and not math.isfinite(self.body_heading_rad):
            raise ValueError(
                f"Detection.body_heading_rad must be finite, got {self.body_heading_rad}"
            )
        if self.expected_area_px is not None and not (
            math.isfinite(self.expected_area_px) and self.expected_area_px > 0.0
        ):
            raise ValueError(
                f"Detection.expected_area_px must be finite and > 0, got {self.expected_area_px}"
            )
        _check_finite(
            self,
            t_mono_s=self.t_mono_s,
            u_px=self.u_px,
            v_px=self.v_px,
            visible_area_px=self.visible_area_px,
            score=self.score,
        )
        _x, _y, w, h = self.bbox_xywh_px
        if w <= 0 or h <= 0:
            raise ValueError(f"Detection.bbox_xywh_px must have a positive size, got {w}x{h}")
        if self.visible_area_px < 0:
            raise ValueError(f"Detection.visible_area_px must be >= 0, got {self.visible_area_px}")
        if not 0.0 <= self.score <= 1.0:
            raise ValueError(f"Detection.score must be in [0, 1], got {self.score}")


@dataclass(frozen=True)
class Observation:
    """A detection placed on the floor of the local NED frame, ready for the tracker.

    Stamped in wall time: the tracker and its saved registry must outlive a restart,
    which resets the monotonic clock.
    """

    t_unix_s: float  # capture time of the frame, wall clock
    north_m: float
    east_m: float
    cov_ne_m2: Cov2  # covariance of (north, east)
    visibility_pct: float
    quality: float  # weight of this observation's visibility in [0, 1]
    range_m: float  # camera-to-point distance
    # Only an exposed part was seen (a lone hand or face, no body): where the part
    # is, and how much of a body it shows, but not where a body seen whole lies.
    part_only: bool = False
    sensor: Sensor = Sensor.COLOUR
    # It counts towards confirming a victim: not a warm find whose height the rover's
    # motion has not shown yet (it may be warmth flat on the floor; issue 41).
    supports: bool = True

    @property
    def cue(self) -> Cue:
        """What this observation says saw the victim."""
        if self.sensor == Sensor.THERMAL:
            return Cue.WARM
        return Cue.COLOUR_PART if self.part_only else Cue.COLOUR_BODY

    def __post_init__(self) -> None:
        _check_finite(
            self,
            t_unix_s=self.t_unix_s,
            north_m=self.north_m,
            east_m=self.east_m,
            visibility_pct=self.visibility_pct,
            quality=self.quality,
            range_m=self.range_m,
        )
        _check_cov2(self, "cov_ne_m2", self.cov_ne_m2)
        if not 0.0 <= self.visibility_pct <= 100.0:
            raise ValueError(
                f"Observation.visibility_pct must be in [0, 100], got {self.visibility_pct}"
            )
        if not 0.0 <= self.quality <= 1.0:
            raise ValueError(f"Observation.quality must be in [0, 1], got {self.quality}")
        if self.range_m < 0.0:
            raise ValueError(f"Observation.range_m must be >= 0, got {self.range_m}")


@dataclass(frozen=True)
class VictimReport:
    """Everything the HQ is told about one victim: the payload of the dialect report."""

    victim_id: int
    robot_sysid: int
    state: TrackState
    urgency: Urgency
    visibility_pct: float
    north_m: float
    east_m: float
    down_m: float
    cov_ne_m2: Cov2
    observations: int
    first_seen_unix_s: float
    last_seen_unix_s: float
    lat_deg: float | None = None
    lon_deg: float | None = None
    alt_m: float | None = None
    cues: Cue = NO_CUES  # which sensing has seen it

    def __post_init__(self) -> None:
        _check_finite(
            self,
            visibility_pct=self.visibility_pct,
            north_m=self.north_m,
            east_m=self.east_m,
            down_m=self.down_m,
            first_seen_unix_s=self.first_seen_unix_s,
            last_seen_unix_s=self.last_seen_unix_s,
        )
        _check_cov2(self, "cov_ne_m2", self.cov_ne_m2)
        if not 1 <= self.victim_id <= 0xFFFFFFFF:
            raise ValueError(f"VictimReport.victim_id must be in [1, 2^32-1], got {self.victim_id}")
        if not 1 <= self.robot_sysid <= 255:
            raise ValueError(
                f"VictimReport.robot_sysid must be in [1, 255], got {self.robot_sysid}"
            )
        if not 0.0 <= self.visibility_pct <= 100.0:
            raise ValueError(
                f"VictimReport.visibility_pct must be in [0, 100], got {self.visibility_pct}"
            )
        if self.observations < 0:
            raise ValueError(f"VictimReport.observations must be >= 0, got {self.observations}")
        if self.last_seen_unix_s < self.first_seen_unix_s:
            raise ValueError("VictimReport.last_seen_unix_s is before first_seen_unix_s")
        given = [v is not None for v in (self.lat_deg, self.lon_deg, self.alt_m)]
        if any(given) and not all(given):
            raise ValueError("VictimReport lat_deg, lon_deg and alt_m come together or not at all")

    @property
    def sigma_m(self) -> float:
        """One-sigma horizontal uncertainty: the root of the larger covariance eigenvalue."""
        (a, b), (_, d) = self.cov_ne_m2
        half_trace = 0.5 * (a + d)
        return math.sqrt(half_trace + math.sqrt(max(0.0, (0.5 * (a - d)) ** 2 + b * b)))

    @property
    def has_global(self) -> bool:
        return self.lat_deg is not None
