"""The vehicle's pose at a camera frame's capture time.

``interpolate`` blends two pose samples: position, velocity and boot time linearly,
attitude by spherical linear interpolation (slerp) of unit quaternions, so a yaw
that wraps through +-180 degrees takes the short way round.

``PoseHistory`` keeps the recent samples in time order (by ``t_mono_s``); the link
thread adds, the processing thread asks for the pose at a frame's time. A frame
further than ``max_extrapolation_s`` from every real sample gets no pose: a stale
pose must never produce a confident position.
"""

from __future__ import annotations

import bisect
import logging
import math
import threading
from dataclasses import replace

from fusion.errors import PoseUnavailable
from fusion.types import PoseSample

log = logging.getLogger(__name__)

Quaternion = tuple[float, float, float, float]  # (w, x, y, z), unit norm


def quaternion_from_euler(roll_rad: float, pitch_rad: float, yaw_rad: float) -> Quaternion:
    """Unit quaternion of ZYX Euler angles (the same rotation as camera.rotation_zyx)."""
    cr, sr = math.cos(roll_rad / 2.0), math.sin(roll_rad / 2.0)
    cp, sp = math.cos(pitch_rad / 2.0), math.sin(pitch_rad / 2.0)
    cy, sy = math.cos(yaw_rad / 2.0), math.sin(yaw_rad / 2.0)
    return (
        cr * cp * cy + sr * sp * sy,
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
    )


def euler_from_quaternion(q: Quaternion) -> tuple[float, float, float]:
    """(roll_rad, pitch_rad, yaw_rad) of a unit quaternion, ZYX convention."""
    w, x, y, z = q
    roll = math.atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2.0 * (w * y - z * x))))
    yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return roll, pitch, yaw


def slerp(q0: Quaternion, q1: Quaternion, s: float) -> Quaternion:
    """Spherical linear interpolation, s in [0, 1], along the shorter arc."""
    dot = sum(a * b for a, b in zip(q0, q1, strict=True))
    if dot < 0.0:  # q and -q are the same rotation: take the short way
        q1 = (-q1[0], -q1[1], -q1[2], -q1[3])
        dot = -dot
    if dot > 0.9995:  # nearly equal: linear blend, then renormalise
        w0, w1 = 1.0 - s, s
    else:
        theta = math.acos(dot)
        w0 = math.sin((1.0 - s) * theta) / math.sin(theta)
        w1 = math.sin(s * theta) / math.sin(theta)
    q = tuple(w0 * a + w1 * b for a, b in zip(q0, q1, strict=True))
    norm = math.sqrt(sum(c * c for c in q))
    return (q[0] / norm, q[1] / norm, q[2] / norm, q[3] / norm)


def _lerp(a: float, b: float, s: float) -> float:
    return a + (b - a) * s


def interpolate(a: PoseSample, b: PoseSample, t_mono_s: float) -> PoseSample:
    """The pose at ``t_mono_s`` between samples ``a`` and ``b`` (any order of a, b).

    Outside [a, b] the same formulas extrapolate; callers limit how far.
    """
    if b.t_mono_s < a.t_mono_s:
        a, b = b, a
    span_s = b.t_mono_s - a.t_mono_s
    if span_s <= 0.0:
        return replace(a, t_mono_s=t_mono_s)
    s = (t_mono_s - a.t_mono_s) / span_s
    q = slerp(
        quaternion_from_euler(a.roll_rad, a.pitch_rad, a.yaw_rad),
        quaternion_from_euler(b.roll_rad, b.pitch_rad, b.yaw_rad),
        s,
    )
    roll, pitch, yaw = euler_from_quaternion(q)
    return PoseSample(
        t_boot_s=max(0.0, _lerp(a.t_boot_s, b.t_boot_s, s)),
        t_mono_s=t_mono_s,
        north_m=_lerp(a.north_m, b.north_m, s),
        east_m=_lerp(a.east_m, b.east_m, s),
        down_m=_lerp(a.down_m, b.down_m, s),
        roll_rad=roll,
        pitch_rad=pitch,
        yaw_rad=yaw,
        vn_m_s=_lerp(a.vn_m_s, b.vn_m_s, s),
        ve_m_s=_lerp(a.ve_m_s, b.ve_m_s, s),
        vd_m_s=_lerp(a.vd_m_s, b.vd_m_s, s),
    )


def _hold(sample: PoseSample, t_mono_s: float) -> PoseSample:
    """One sample carried to a nearby time: position moves with its velocity,
    attitude is held."""
    dt = t_mono_s - sample.t_mono_s
    return replace(
        sample,
        t_mono_s=t_mono_s,
        t_boot_s=max(0.0, sample.t_boot_s + dt),
        north_m=sample.north_m + sample.vn_m_s * dt,
        east_m=sample.east_m + sample.ve_m_s * dt,
        down_m=sample.down_m + sample.vd_m_s * dt,
    )


class PoseHistory:
    """Recent pose samples in time order, bounded by age and count. Thread-safe."""

    def __init__(self, max_age_s: float, max_samples: int = 10_000) -> None:
        if not max_age_s > 0.0:
            raise ValueError(f"max_age_s must be > 0, got {max_age_s!r}")
        if max_samples < 2:
            raise ValueError(f"max_samples must be >= 2, got {max_samples!r}")
        self._max_age_s = max_age_s
        self._max_samples = max_samples
        self._lock = threading.Lock()
        self._times: list[float] = []  # t_mono_s of each sample, ascending
        self._samples: list[PoseSample] = []

    def add(self, sample: PoseSample) -> None:
        """Insert a sample in time order.

        A sample with the same ``t_mono_s`` as a stored one replaces it (the newer
        message wins); one older than the age window is ignored.
        """
        with self._lock:
            t = sample.t_mono_s
            if self._times and t < self._times[-1] - self._max_age_s:
                log.debug("pose at %.3f s is older than the %.1f s window", t, self._max_age_s)
                return
            i = bisect.bisect_left(self._times, t)
            if i < len(self._times) and self._times[i] == t:
                self._samples[i] = sample
                return
            self._times.insert(i, t)
            self._samples.insert(i, sample)
            self._trim()

    def _trim(self) -> None:
        cutoff = self._times[-1] - self._max_age_s
        drop = bisect.bisect_left(self._times, cutoff)
        drop = max(drop, len(self._times) - self._max_samples)
        if drop > 0:
            del self._times[:drop]
            del self._samples[:drop]

    def latest(self) -> PoseSample | None:
        """The newest sample, or None when the history is empty."""
        with self._lock:
            return self._samples[-1] if self._samples else None

    def clear(self) -> None:
        """Forget every sample (the autopilot rebooted: its frame may have changed)."""
        with self._lock:
            self._times.clear()
            self._samples.clear()

    def __len__(self) -> int:
        with self._lock:
            return len(self._samples)

    def pose_at(self, t_mono_s: float, max_extrapolation_s: float) -> PoseSample:
        """The pose at ``t_mono_s``.

        Between two samples: interpolated, as long as one of them is within
        ``max_extrapolation_s``. Before the first or after the last sample: that
        sample carried over (position along its velocity, attitude held) up to
        ``max_extrapolation_s``. Otherwise PoseUnavailable with the reason.
        """
        if not math.isfinite(t_mono_s):
            raise PoseUnavailable(f"requested time {t_mono_s!r} is not finite")
        with self._lock:
            if not self._samples:
                raise PoseUnavailable("no pose received yet")
            i = bisect.bisect_left(self._times, t_mono_s)
            n = len(self._times)
            if i < n and self._times[i] == t_mono_s:
                return self._samples[i]
            if i == 0:
                return self._carry(self._samples[0], t_mono_s, max_extrapolation_s, "first")
            if i == n:
                return self._carry(self._samples[-1], t_mono_s, max_extrapolation_s, "latest")
            a, b = self._samples[i - 1], self._samples[i]
        gap_s = min(t_mono_s - a.t_mono_s, b.t_mono_s - t_mono_s)
        if gap_s > max_extrapolation_s:
            raise PoseUnavailable(
                f"no pose within {max_extrapolation_s:.3f} s of t={t_mono_s:.3f} s "
                f"(samples at {a.t_mono_s:.3f} s and {b.t_mono_s:.3f} s)"
            )
        return interpolate(a, b, t_mono_s)

    @staticmethod
    def _carry(
        sample: PoseSample, t_mono_s: float, max_extrapolation_s: float, which: str
    ) -> PoseSample:
        gap_s = abs(t_mono_s - sample.t_mono_s)
        if gap_s > max_extrapolation_s:
            direction = "after" if t_mono_s > sample.t_mono_s else "before"
            raise PoseUnavailable(
                f"t={t_mono_s:.3f} s is {gap_s:.3f} s {direction} the {which} pose "
                f"(limit {max_extrapolation_s:.3f} s)"
            )
        return _hold(sample, t_mono_s)
