"""NED <-> WGS-84 around an EKF origin."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fusion.geodesy import geodetic_to_ned, ned_to_geodetic
from fusion.types import GlobalOrigin


@settings(max_examples=200, deadline=None, derandomize=True)
@given(
    lat=st.floats(-89.0, 89.0).filter(lambda x: abs(x) > 1e-6),
    lon=st.floats(-180.0, 180.0),
    alt=st.floats(-400.0, 5000.0),
    ned=st.tuples(st.floats(-500, 500), st.floats(-500, 500), st.floats(-50, 50)),
)
def test_round_trip(lat: float, lon: float, alt: float, ned: tuple[float, float, float]) -> None:
    # 1e-6 m: ECEF coordinates are ~6.4e6 m, so double rounding is ~1e-9 m per step.
    origin = GlobalOrigin(lat, lon, alt)
    back = geodetic_to_ned(origin, *ned_to_geodetic(origin, *ned))
    assert back == pytest.approx(ned, abs=1e-6)


def test_known_distances() -> None:
    # At 45 deg latitude the meridian radius of curvature is 6367381.8 m and the
    # prime-vertical radius 6388838.3 m (WGS-84): 10 m north / east map to these
    # angles within 1e-9 deg (second-order terms over 10 m are ~1e-11 deg).
    origin = GlobalOrigin(45.0, 7.0, 300.0)
    lat, lon, alt = ned_to_geodetic(origin, 10.0, 0.0, 0.0)
    assert lat - 45.0 == pytest.approx(math.degrees(10.0 / (6367381.8 + 300.0)), abs=1e-9)
    assert lon == pytest.approx(7.0, abs=1e-12)
    lat, lon, alt = ned_to_geodetic(origin, 0.0, 10.0, -2.0)
    radius = (6388838.3 + 300.0) * math.cos(math.radians(45.0))
    assert lon - 7.0 == pytest.approx(math.degrees(10.0 / radius), abs=1e-9)
    # Down is negative altitude; 10 m off the tangent point the Earth drops by
    # d^2 / 2R ~ 8e-6 m, so the altitude is 302 m within 1e-4 m.
    assert alt == pytest.approx(302.0, abs=1e-4)
    assert ned_to_geodetic(origin, 0.0, 0.0, 0.0) == pytest.approx((45.0, 7.0, 300.0), abs=1e-8)
