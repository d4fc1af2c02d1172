"""Which robots' victims are the same person: gating and fusion in a common frame.

Each robot reports its victims with a 2x2 (north, east) covariance. Two reports,
from two different robots, are taken as the same victim when the squared
Mahalanobis distance of their positions

    d² = Δᵀ (P_a + P_b)⁻¹ Δ        Δ = position_b - position_a (north, east)

is inside the chi-square gate for 2 degrees of freedom at 99 % (9.21): if both were
the same point, d² would exceed 9.21 only 1 % of the time.

The common frame:
- both positions have latitude/longitude (the robot reported them, or the HQ knows
  that robot's EKF origin): b is carried into the tangent (NED) plane at a with
  exact WGS-84 geodesy; covariances are already in north/east axes;
- neither has latitude/longitude: the local NED positions are compared directly.
  ASSUMPTION: robots without a global origin share one EKF origin (they were set
  up with the same SET_GPS_GLOBAL_ORIGIN, or started from the same marked spot
  with the same heading). Robots with different local frames must be given an
  origin (GPS_GLOBAL_ORIGIN from the vehicle, or ``--origin``), or they never merge
  wrongly only by luck;
- one with and one without: no common frame, never merged.

A robot's own victims are never merged by the HQ (the robot's tracker saw them at
once and knows better); an HQ victim holds at most one victim per robot.

Fusion of a group is the information-weighted mean (P = (Σ Pᵢ⁻¹)⁻¹, x = P Σ Pᵢ⁻¹ xᵢ);
what saw the person is the union of the robots' cues (one robot's colour camera and
another's thermal camera: colour body · warm).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from fusion.geodesy import geodetic_to_ned, ned_to_geodetic
from fusion.kalman import mahalanobis2 as fusion_mahalanobis2
from fusion.types import NO_CUES, Cov2, Cue, GlobalOrigin, VictimReport

CHI2_GATE_2DOF_99 = 9.2103  # scipy.stats.chi2.ppf(0.99, df=2)

Geo = tuple[float, float, float]  # lat_deg, lon_deg, alt_m


@dataclass(frozen=True)
class Placed:
    """A victim report's position as the merger sees it."""

    robot_sysid: int
    victim_id: int
    north_m: float
    east_m: float
    cov_ne_m2: Cov2
    geo: Geo | None  # reported, or computed from the robot's origin


@dataclass(frozen=True)
class Fused:
    north_m: float
    east_m: float
    cov_ne_m2: Cov2
    geo: Geo | None


def _cov(c: Cov2) -> np.ndarray:
    return np.array(c, dtype=float)


def _as_cov2(p: np.ndarray) -> Cov2:
    off = float(0.5 * (p[0, 1] + p[1, 0]))  # keep it exactly symmetric
    return ((float(p[0, 0]), off), (off, float(p[1, 1])))


def _origin(geo: Geo) -> GlobalOrigin:
    return GlobalOrigin(geo[0], geo[1], geo[2])


def delta_ne(a: Placed | Fused, b: Placed | Fused) -> np.ndarray | None:
    """b - a in metres (north, east) in a common frame, or None if there is none."""
    if a.geo is not None and b.geo is not None:
        n, e, _d = geodetic_to_ned(_origin(a.geo), *b.geo)
        return np.array([n, e])
    if a.geo is None and b.geo is None:
        return np.array([b.north_m - a.north_m, b.east_m - a.east_m])
    return None


def mahalanobis2(a: Placed | Fused, b: Placed | Fused) -> float | None:
    """Squared Mahalanobis distance between two positions; None without a common frame."""
    delta = delta_ne(a, b)
    if delta is None:
        return None
    s = _cov(a.cov_ne_m2) + _cov(b.cov_ne_m2)  # S: covariance of the difference
    d2, _det = fusion_mahalanobis2(np.asarray(delta, float), s)
    return float(d2)


def fuse(members: Sequence[Placed]) -> Fused:
    """The information-weighted position of a non-empty group."""
    if not members:
        raise ValueError("fuse: empty group")
    if len(members) == 1:
        m = members[0]
        return Fused(m.north_m, m.east_m, m.cov_ne_m2, m.geo)
    # Geo members define the fused geo position (in the tangent plane at the first one).
    geo_members = [m for m in members if m.geo is not None]
    geo: Geo | None = None
    p_geo: np.ndarray | None = None
    if geo_members:
        ref = geo_members[0].geo
        assert ref is not None  # narrowed by the filter above
        xs = [np.array(geodetic_to_ned(_origin(ref), *m.geo)[:2]) for m in geo_members if m.geo]
        x, p_geo = _information_mean(xs, [_cov(m.cov_ne_m2) for m in geo_members])
        alt = float(np.mean([m.geo[2] for m in geo_members if m.geo]))
        lat, lon, _ = ned_to_geodetic(_origin(ref), float(x[0]), float(x[1]), ref[2] - alt)
        geo = (lat, lon, alt)
    xs_ned = [np.array([m.north_m, m.east_m]) for m in members]
    x_ned, p_ned = _information_mean(xs_ned, [_cov(m.cov_ne_m2) for m in members])
    cov = _as_cov2(p_geo if p_geo is not None else p_ned)
    return Fused(float(x_ned[0]), float(x_ned[1]), cov, geo)


def union_cues(reports: Sequence[VictimReport]) -> Cue:
    """Every sensing that saw the person, on any robot (none: not known)."""
    out = NO_CUES
    for r in reports:
        out |= r.cues
    return Cue(out)


def _information_mean(
    xs: Sequence[np.ndarray], ps: Sequence[np.ndarray]
) -> tuple[np.ndarray, np.ndarray]:
    # Y = Σ Pᵢ⁻¹ (information), y = Σ Pᵢ⁻¹ xᵢ; P = Y⁻¹, x = P y
    infos = [np.linalg.inv(p) for p in ps]
    y_mat = sum(infos, np.zeros((2, 2)))
    y_vec = sum((i @ x for i, x in zip(infos, xs, strict=True)), np.zeros(2))
    p = np.linalg.inv(y_mat)
    return p @ y_vec, p


def assign(
    candidate: Placed,
    current_hq_id: int | None,
    groups: Mapping[int, Sequence[Placed]],
    gate: float = CHI2_GATE_2DOF_99,
) -> int | None:
    """The HQ victim ``candidate`` belongs to (None: a new one).

    ``groups`` maps HQ victim IDs to their members (the candidate may be among
    them). A source stays where it is while it is inside the gate of the rest of
    its group; otherwise it joins the nearest gated group without its robot.
    """
    key = (candidate.robot_sysid, candidate.victim_id)
    if current_hq_id is not None:
        others = [m for m in groups.get(current_hq_id, ()) if (m.robot_sysid, m.victim_id) != key]
        if not others:
            return current_hq_id
        d2 = mahalanobis2(fuse(others), candidate)
        if d2 is not None and d2 <= gate:
            return current_hq_id
    best: tuple[float, int] | None = None
    for hq_id, members in groups.items():
        if hq_id == current_hq_id:
            continue
        rest = [m for m in members if (m.robot_sysid, m.victim_id) != key]
        if not rest or any(m.robot_sysid == candidate.robot_sysid for m in rest):
            continue
        d2 = mahalanobis2(fuse(rest), candidate)
        if d2 is not None and d2 <= gate and (best is None or d2 < best[0]):
            best = (d2, hq_id)
    return best[1] if best is not None else None


@dataclass(frozen=True)
class Origins:
    """EKF origins the HQ knows: per robot (GPS_GLOBAL_ORIGIN) and the operator's default."""

    per_robot: dict[int, GlobalOrigin]
    default: GlobalOrigin | None

    def for_robot(self, sysid: int) -> GlobalOrigin | None:
        return self.per_robot.get(sysid, self.default)


def geo_of(report: VictimReport, origins: Origins) -> Geo | None:
    """A report's (lat, lon, alt): as reported, else from its robot's EKF origin, else None."""
    if report.lat_deg is not None and report.lon_deg is not None and report.alt_m is not None:
        return (report.lat_deg, report.lon_deg, report.alt_m)
    origin = origins.for_robot(report.robot_sysid)
    if origin is None:
        return None
    return ned_to_geodetic(origin, report.north_m, report.east_m, report.down_m)


def placed(report: VictimReport, origins: Origins) -> Placed:
    return Placed(
        report.robot_sysid,
        report.victim_id,
        report.north_m,
        report.east_m,
        report.cov_ne_m2,
        geo_of(report, origins),
    )
