"""Pose interpolation and the thread-safe pose history."""

from __future__ import annotations

import math
import threading

import numpy as np
import pytest

from fusion.camera import rotation_zyx
from fusion.errors import PoseUnavailable
from fusion.pose import PoseHistory, interpolate
from fusion.types import PoseSample


def _sample(t: float, north_m: float = 0.0, yaw_rad: float = 0.0, **kw: float) -> PoseSample:
    return PoseSample(
        t_boot_s=t + 50.0,
        t_mono_s=t,
        north_m=north_m,
        east_m=kw.pop("east_m", 0.0),
        down_m=kw.pop("down_m", 0.0),
        roll_rad=kw.pop("roll_rad", 0.0),
        pitch_rad=kw.pop("pitch_rad", 0.0),
        yaw_rad=yaw_rad,
        **kw,
    )


def test_interpolate_position_linear_and_attitude_slerp() -> None:
    a = _sample(1.0, north_m=0.0, yaw_rad=0.0, east_m=2.0)
    b = _sample(2.0, north_m=4.0, yaw_rad=1.0, east_m=0.0)
    p = interpolate(a, b, 1.25)
    assert p.t_mono_s == 1.25
    assert p.t_boot_s == pytest.approx(51.25, abs=1e-12)
    assert (p.north_m, p.east_m) == pytest.approx((1.0, 1.5), abs=1e-12)
    # A pure yaw rotation slerps to the proportional yaw (1e-12: float rounding).
    assert p.yaw_rad == pytest.approx(0.25, abs=1e-12)
    assert p.roll_rad == pytest.approx(0.0, abs=1e-12)


def test_interpolate_takes_short_way_through_pi() -> None:
    a = _sample(0.0, yaw_rad=math.radians(170.0))
    b = _sample(1.0, yaw_rad=math.radians(-170.0))
    mid = interpolate(a, b, 0.5)
    assert abs(abs(mid.yaw_rad) - math.pi) < 1e-9


def test_interpolate_combined_attitude_matches_rotation_geodesic() -> None:
    # The midpoint rotation R_m satisfies R_a^T R_m == R_m^T R_b (equal halves).
    a = _sample(0.0, roll_rad=0.1, pitch_rad=-0.2, yaw_rad=2.5)
    b = _sample(1.0, roll_rad=-0.3, pitch_rad=0.25, yaw_rad=-2.9)
    m = interpolate(a, b, 0.5)
    ra = rotation_zyx(a.roll_rad, a.pitch_rad, a.yaw_rad)
    rb = rotation_zyx(b.roll_rad, b.pitch_rad, b.yaw_rad)
    rm = rotation_zyx(m.roll_rad, m.pitch_rad, m.yaw_rad)
    np.testing.assert_allclose(ra.T @ rm, rm.T @ rb, atol=1e-12)
    # The endpoints come back unchanged.
    e = interpolate(a, b, 1.0)
    np.testing.assert_allclose(rotation_zyx(e.roll_rad, e.pitch_rad, e.yaw_rad), rb, atol=1e-12)


def test_history_interpolates_between_neighbours() -> None:
    h = PoseHistory(max_age_s=5.0)
    for i in range(10):
        h.add(_sample(i * 0.05, north_m=i * 0.1))
    p = h.pose_at(0.125, max_extrapolation_s=0.1)
    assert p.north_m == pytest.approx(0.25, abs=1e-12)
    assert h.pose_at(0.1, 0.1).north_m == pytest.approx(0.2, abs=1e-12)  # exact sample


def test_history_refuses_stale_and_future_poses() -> None:
    h = PoseHistory(max_age_s=5.0)
    with pytest.raises(PoseUnavailable, match="no pose received yet"):
        h.pose_at(1.0, 0.1)
    h.add(_sample(1.0, north_m=0.0, vn_m_s=2.0))
    h.add(_sample(2.0, north_m=1.0, vn_m_s=2.0))
    # Carried forward along the velocity up to the limit...
    assert h.pose_at(2.05, 0.1).north_m == pytest.approx(1.1, abs=1e-12)
    # ...and not a bit further.
    with pytest.raises(PoseUnavailable, match="after the latest pose") as exc:
        h.pose_at(2.2, 0.1)
    assert "0.200 s" in exc.value.reason
    with pytest.raises(PoseUnavailable, match="before the first pose"):
        h.pose_at(0.5, 0.1)
    # In a gap (lost messages) the frame must be near one of the two samples.
    with pytest.raises(PoseUnavailable, match=r"no pose within 0\.100 s"):
        h.pose_at(1.5, 0.1)
    assert h.pose_at(1.08, 0.1).north_m == pytest.approx(0.08, abs=1e-12)
    with pytest.raises(PoseUnavailable, match="not finite"):
        h.pose_at(float("nan"), 0.1)


def test_history_bounded_by_age_and_count() -> None:
    h = PoseHistory(max_age_s=1.0)
    for i in range(1000):
        h.add(_sample(i * 0.01))
    latest = h.latest()
    assert latest is not None and latest.t_mono_s == pytest.approx(9.99)
    assert len(h) == 101  # samples within 1.0 s of the latest, both ends included
    with pytest.raises(PoseUnavailable):
        h.pose_at(5.0, 0.1)
    small = PoseHistory(max_age_s=100.0, max_samples=5)
    for i in range(20):
        small.add(_sample(float(i)))
    assert len(small) == 5


def test_history_out_of_order_duplicates_and_clear() -> None:
    h = PoseHistory(max_age_s=10.0)
    h.add(_sample(2.0, north_m=2.0))
    h.add(_sample(1.0, north_m=1.0))  # late arrival goes in its place
    h.add(_sample(3.0, north_m=3.0))
    h.add(_sample(2.0, north_m=2.5))  # same instant: the newer message wins
    assert len(h) == 3
    assert h.pose_at(2.0, 0.1).north_m == 2.5
    assert h.pose_at(1.5, 0.5).north_m == pytest.approx(1.75)
    h.add(_sample(-20.0))  # far older than the window: ignored
    assert len(h) == 3
    h.clear()
    assert len(h) == 0 and h.latest() is None
    with pytest.raises(ValueError, match="max_age_s"):
        PoseHistory(max_age_s=0.0)


def test_history_is_thread_safe() -> None:
    h = PoseHistory(max_age_s=1e6)
    n = 2000
    start = threading.Barrier(3)
    reader_busy = threading.Event()  # writers pause half-way until reads overlap them

    def writer(offset: int) -> None:
        start.wait()
        for i in range(n):
            if i == n // 2:
                assert reader_busy.wait(10.0)
            h.add(_sample(2.0 * i + offset, north_m=2.0 * i + offset))

    threads = [threading.Thread(target=writer, args=(k,)) for k in (0, 1)]
    for t in threads:
        t.start()
    start.wait()
    reads = 0
    while any(t.is_alive() for t in threads):
        latest = h.latest()
        if latest is not None:
            p = h.pose_at(latest.t_mono_s, 0.0)
            assert p.north_m == pytest.approx(p.t_mono_s)
            reads += 1
            if reads == 50:
                reader_busy.set()
    for t in threads:
        t.join(timeout=10.0)
    assert len(h) == 2 * n
    assert reads >= 50
    # Interleaved writers still leave a strictly ordered history.
    assert h.pose_at(1234.5, 1.0).north_m == pytest.approx(1234.5)
