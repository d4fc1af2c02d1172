"""Local NED <-> WGS-84 geodetic coordinates around an EKF origin.

Exact conversion through Earth-centred, Earth-fixed (ECEF) coordinates, not a flat
approximation: NED is the tangent plane at the origin (north, east, down), and a
point is carried to ECEF and back to latitude, longitude and ellipsoidal height.
Altitudes are taken as the origin's ``alt_m`` minus ``down_m``, i.e. the origin's
altitude datum (AMSL) is used as if it were ellipsoidal: over a building the geoid
separation is constant, so it cancels.
"""

from __future__ import annotations

import math

import numpy as np

from fusion.camera import FloatArray
from fusion.types import GlobalOrigin

# WGS-84 ellipsoid.
_A_M = 6378137.0  # semi-major axis
_F = 1.0 / 298.257223563  # flattening
_E2 = _F * (2.0 - _F)  # first eccentricity squared
_B_M = _A_M * (1.0 - _F)  # semi-minor axis
_EP2 = (_A_M**2 - _B_M**2) / _B_M**2  # second eccentricity squared


def _geodetic_to_ecef(lat_deg: float, lon_deg: float, h_m: float) -> FloatArray:
    lat, lon = math.radians(lat_deg), math.radians(lon_deg)
    # N: prime-vertical radius of curvature.
    n = _A_M / math.sqrt(1.0 - _E2 * math.sin(lat) ** 2)
    return np.array(
        [
            (n + h_m) * math.cos(lat) * math.cos(lon),
            (n + h_m) * math.cos(lat) * math.sin(lon),
            (n * (1.0 - _E2) + h_m) * math.sin(lat),
        ]
    )


def _ecef_to_geodetic(p: FloatArray) -> tuple[float, float, float]:
    x, y, z = (float(v) for v in p)
    lon = math.atan2(y, x)
    r = math.hypot(x, y)
    # Bowring's parametric-latitude start, then Newton-free fixed-point refinement;
    # four passes reach far below a micrometre for points near the surface.
    beta = math.atan2(z * _A_M, r * _B_M)
    lat = 0.0
    for _ in range(4):
        lat = math.atan2(
            z + _EP2 * _B_M * math.sin(beta) ** 3, r - _E2 * _A_M * math.cos(beta) ** 3
        )
        beta = math.atan2((1.0 - _F) * math.sin(lat), math.cos(lat))
    n = _A_M / math.sqrt(1.0 - _E2 * math.sin(lat) ** 2)
    # h = r cos(lat) + z sin(lat) - a^2 / N: well conditioned at every latitude.
    h = r * math.cos(lat) + z * math.sin(lat) - _A_M**2 / n
    return math.degrees(lat), math.degrees(lon), h


def _r_ecef_from_ned(lat_deg: float, lon_deg: float) -> FloatArray:
    """Columns: the north, east and down unit vectors at the origin, in ECEF."""
    lat, lon = math.radians(lat_deg), math.radians(lon_deg)
    sl, cl = math.sin(lat), math.cos(lat)
    so, co = math.sin(lon), math.cos(lon)
    return np.array(
        [
            [-sl * co, -so, -cl * co],
            [-sl * so, co, -cl * so],
            [cl, 0.0, -sl],
        ]
    )


def ned_to_geodetic(
    origin: GlobalOrigin, north_m: float, east_m: float, down_m: float
) -> tuple[float, float, float]:
    """(lat_deg, lon_deg, alt_m) of a local NED point."""
    p0 = _geodetic_to_ecef(origin.lat_deg, origin.lon_deg, origin.alt_m)
    # p_ecef = p0 + R_ecef_from_ned @ [n, e, d]
    p = p0 + _r_ecef_from_ned(origin.lat_deg, origin.lon_deg) @ np.array([north_m, east_m, down_m])
    lat_deg, lon_deg, alt_m = _ecef_to_geodetic(p)
    return lat_deg, lon_deg, alt_m


def geodetic_to_ned(
    origin: GlobalOrigin, lat_deg: float, lon_deg: float, alt_m: float
) -> tuple[float, float, float]:
    """(north_m, east_m, down_m) of a geodetic point in the origin's NED frame."""
    p0 = _geodetic_to_ecef(origin.lat_deg, origin.lon_deg, origin.alt_m)
    p = _geodetic_to_ecef(lat_deg, lon_deg, alt_m)
    # [n, e, d] = R_ecef_from_ned^T @ (p - p0)
    ned = _r_ecef_from_ned(origin.lat_deg, origin.lon_deg).T @ (p - p0)
    return float(ned[0]), float(ned[1]), float(ned[2])
