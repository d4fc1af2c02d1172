"""Where the robots have looked: their searched-area maps in, stored, merged, shown.

``CoverageIntake.on_piece`` (the HQ's main thread, which owns the registry) takes a
RESCUE_COVERAGE: a piece that does not decode (mavlink_io.coverage.BadPiece) is
refused in one rate-limited line and answered REJECTED (the robot does not send it
again; nothing stored is touched); one with another cell size than the HQ's 0.25 m
likewise. A good piece's cells are stored, each at the larger of what is held and
what it says (hq.registry.store_coverage), and only then acknowledged ACCEPTED; a
failed write is not acknowledged, so the robot resends it.

``merged_map`` combines every robot's map per cell as independent chances, the
probability that a person there would have been found by any of them:
``1 - prod_r (1 - p_r)``. The common frame is the one hq.merge uses for victims:
with the robots' EKF origins (GPS_GLOBAL_ORIGIN, or the operator's ``--origin``)
each robot's cells are moved into the frame of the lowest-numbered robot's origin
(to the nearest cell: 0.25 m, where a tangent plane's curvature is negligible); a
robot without an origin then cannot be placed and is left out (``unplaced``), as is
one whose origin lies more than ``MAX_SITE_M`` (2 km) from the frame's (another
site, or a wrong origin: its map would span kilometres of empty cells). With
no origin at all, every robot's local frame is taken as the same one (the
ASSUMPTION of hq.merge).

The map says what the robots claim: the camera has no depth, so floor behind tall
debris counts as seen (docs/COVERAGE.md).
"""

from __future__ import annotations

import functools
import logging
import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage

from fusion.coverage import GLANCED_AT_P, SEARCHED_WELL_P
from fusion.geodesy import geodetic_to_ned, ned_to_geodetic
from fusion.types import GlobalOrigin
from hq.merge import Origins
from hq.ratelog import RateLimitedLog
from hq.registry import Registry
from hq.registry_file import RegistryError
from mavlink_io import coverage

log = logging.getLogger(__name__)

CELL_M = 0.25  # the only cell size the HQ merges (fusion.coverage's default)
NEAR_ROBOT_M = 20.0  # unsearched places this close to a robot are pointed out
# A robot whose origin puts its map farther than this from the frame's origin is at
# another site, or its origin is wrong: its map is left out (unplaced), not drawn
# across kilometres of empty cells.
MAX_SITE_M = 2000.0
MAX_PLACES = 3
_Q_MAX = 255.0

Answer = Callable[[int, int], None]  # (seq, RESCUE_ACK result)


@dataclass
class CoverageCounters:
    pieces: int = 0  # stored
    refused: int = 0  # did not decode, or another cell size
    store_failures: int = 0  # not stored (busy, full disk): not acknowledged


class CoverageIntake:
    """RESCUE_COVERAGE in, the registry written, RESCUE_ACK out."""

    def __init__(self, registry: Registry, refusals: RateLimitedLog) -> None:
        self.registry = registry
        self.counters = CoverageCounters()
        self._refusals = refusals

    def on_piece(self, msg: Any, answer: Answer, accepted: int, rejected: int) -> bool:
        """Take one piece; True when cells were stored."""
        robot = msg.get_srcSystem()
        seq = int(msg.seq)
        try:
            piece = coverage.piece_from_msg(msg)
            if piece.cell_m != CELL_M:
                raise coverage.BadPiece(f"cells of {piece.cell_m:g} m, the HQ merges {CELL_M} m")
        except coverage.BadPiece as exc:
            self.counters.refused += 1
            self._refusals.say(
                ("coverage", robot),
                f"refused RESCUE_COVERAGE {seq} from system {robot} (nothing stored, "
                f"acknowledged REJECTED): {exc}",
            )
            answer(seq, rejected)
            return False
        cells = [(int(n), int(e), int(q)) for (n, e), q in zip(piece.cells, piece.p_q, strict=True)]
        try:
            self.registry.store_coverage(robot, cells)
        except RegistryError as exc:
            self.counters.store_failures += 1
            log.warning("coverage piece %d of robot %d not stored: %s", seq, robot, exc)
            return False
        self.counters.pieces += 1
        answer(seq, accepted)
        return bool(cells)


@dataclass(frozen=True)
class Place:
    """An unsearched place: its area, its middle, and how far it is from a robot."""

    area_m2: float
    north_m: float
    east_m: float
    robot_sysid: int | None  # the nearest robot (None: no robot's position known)
    distance_m: float | None


@dataclass(frozen=True)
class MergedMap:
    """Every robot's map in one frame: global cells (K, 2) and p (K,) per cell."""

    cells: NDArray[np.int64]
    p: NDArray[np.float64]
    origin: GlobalOrigin | None  # the frame's global origin; None: the robots' local frame
    robots: tuple[int, ...]  # the robots whose cells are in it
    # robots with cells but no origin when others have one, or an origin over 2 km off
    unplaced: tuple[int, ...]
    cell_m: float = CELL_M

    def classes(self) -> NDArray[np.int64]:
        """2 searched well, 1 glanced at, 0 looked at less (per cell)."""
        return np.where(self.p >= SEARCHED_WELL_P, 2, np.where(self.p >= GLANCED_AT_P, 1, 0))

    def box(self) -> tuple[int, int, int, int] | None:
        """The cells' bounding box (north min, north max, east min, east max), inclusive."""
        if not len(self.cells):
            return None
        lo, hi = self.cells.min(axis=0), self.cells.max(axis=0)
        return int(lo[0]), int(hi[0]), int(lo[1]), int(hi[1])

    def summary(self) -> dict[str, float]:
        """Areas (m²) searched well, glanced at (or better), looked at, and the box's,
        with the shares of the box."""
        a = self.cell_m**2
        box = self.box()
        area = 0.0 if box is None else (box[1] - box[0] + 1) * (box[3] - box[2] + 1) * a
        well = float((self.p >= SEARCHED_WELL_P).sum() * a)
        glanced = float((self.p >= GLANCED_AT_P).sum() * a)
        return {
            "area_m2": area,
            "searched_well_m2": well,
            "glanced_at_m2": glanced,
            "looked_at_m2": float(len(self.p) * a),
            "searched_well_share": well / area if area else 0.0,
            "glanced_at_share": glanced / area if area else 0.0,
        }

    def unsearched_places(
        self, robots_ne_m: Mapping[int, tuple[float, float]], near_m: float = NEAR_ROBOT_M
    ) -> list[Place]:
        """The largest connected unsearched areas (not even glanced at: never looked
        at, or p < GLANCED_AT_P) inside the map's box, biggest first; with robots'
        positions, only those within ``near_m`` of one, each with its nearest robot."""
        box = self.box()
        if box is None:
            return []
        n0, n1, e0, e1 = box
        unsearched = np.ones((n1 - n0 + 1, e1 - e0 + 1), bool)
        glanced = self.p >= GLANCED_AT_P
        unsearched[self.cells[glanced, 0] - n0, self.cells[glanced, 1] - e0] = False
        labels, count = ndimage.label(unsearched)
        if not count:
            return []
        sizes = np.bincount(labels.ravel())[1:]
        places = []
        for k in np.argsort(-sizes):
            rows, cols = np.nonzero(labels == k + 1)
            north = (rows + n0 + 0.5) * self.cell_m
            east = (cols + e0 + 0.5) * self.cell_m
            nearest: tuple[int, float] | None = None
            for sysid, (rn, re) in robots_ne_m.items():
                d = float(np.min(np.hypot(north - rn, east - re)))
                if nearest is None or d < nearest[1]:
                    nearest = (sysid, d)
            if robots_ne_m and (nearest is None or nearest[1] > near_m):
                continue
            places.append(
                Place(
                    float(len(rows) * self.cell_m**2),
                    float(north.mean()),
                    float(east.mean()),
                    None if nearest is None else nearest[0],
                    None if nearest is None else round(nearest[1], 1),
                )
            )
            if len(places) == MAX_PLACES:
                break
        return places

    def geojson(self) -> dict[str, Any]:
        """A FeatureCollection of the cells as polygons, each with p and its class: in
        lon/lat (WGS-84) when the frame has a global origin, else in local NED metres
        ([east, north], ``"crs_note"`` says so)."""
        names = ("looked at", "glanced at", "searched well")
        m = self.cell_m
        features = []
        for (n, e), p, c in zip(
            self.cells.tolist(), self.p.tolist(), self.classes().tolist(), strict=True
        ):
            corners = [(n, e), (n, e + 1), (n + 1, e + 1), (n + 1, e), (n, e)]
            ring = [self._point(cn * m, ce * m) for cn, ce in corners]
            features.append(
                {
                    "type": "Feature",
                    "geometry": {"type": "Polygon", "coordinates": [ring]},
                    "properties": {
                        "p": round(p, 3),
                        "class": names[c],
                        "north_idx": n,
                        "east_idx": e,
                    },
                }
            )
        doc: dict[str, Any] = {"type": "FeatureCollection", "features": features}
        doc["properties"] = {
            "cell_m": m,
            "robots": list(self.robots),
            "unplaced_robots": list(self.unplaced),
            "coordinates": "WGS-84 lon, lat" if self.origin is not None else "local NED metres",
            **self.summary(),
        }
        if self.origin is None:
            doc["properties"]["crs_note"] = (
                "coordinates are [east_m, north_m] in the robots' local NED frame, not lon/lat:"
                " no robot has a global origin"
            )
        return doc

    def _point(self, north_m: float, east_m: float) -> list[float]:
        if self.origin is None:
            return [east_m, north_m]
        lat0, lon0, dlat, dlon = _tangent(self.origin)
        lat = lat0 + north_m * dlat[0] + east_m * dlat[1]
        lon = lon0 + north_m * dlon[0] + east_m * dlon[1]
        return [round(lon, 8), round(lat, 8)]


@functools.cache
def _tangent(origin: GlobalOrigin) -> tuple[float, float, tuple[float, float], tuple[float, float]]:
    """Degrees of latitude and longitude per metre north and east at ``origin``: the
    tangent plane, within 3 cm of exact WGS-84 over a grid's 400 m."""
    lat0, lon0, _ = ned_to_geodetic(origin, 0.0, 0.0, 0.0)
    lat_n, lon_n, _ = ned_to_geodetic(origin, 100.0, 0.0, 0.0)
    lat_e, lon_e, _ = ned_to_geodetic(origin, 0.0, 100.0, 0.0)
    return (
        lat0,
        lon0,
        ((lat_n - lat0) / 100.0, (lat_e - lat0) / 100.0),
        ((lon_n - lon0) / 100.0, (lon_e - lon0) / 100.0),
    )


def merged_map(
    cells_by_robot: Mapping[int, Sequence[tuple[int, int, int]]], origins: Origins
) -> MergedMap:
    """The robots' maps combined per cell as independent chances (module docstring)."""
    robots = sorted(r for r, cells in cells_by_robot.items() if cells)
    with_origin = [r for r in robots if origins.for_robot(r) is not None]
    origin = origins.for_robot(with_origin[0]) if with_origin else None
    placed = with_origin if with_origin else robots
    far: list[int] = []
    keys: list[NDArray[np.int64]] = []
    misses: list[NDArray[np.float64]] = []
    for r in placed:
        a = np.asarray(cells_by_robot[r], np.int64).reshape(-1, 3)
        shift = np.zeros(2, np.int64)
        own = origins.for_robot(r)
        if origin is not None and own is not None and own != origin:
            dn, de, _ = geodetic_to_ned(origin, own.lat_deg, own.lon_deg, own.alt_m)
            if math.hypot(dn, de) > MAX_SITE_M:
                far.append(r)
                continue
            shift = np.array([round(dn / CELL_M), round(de / CELL_M)], np.int64)
        keys.append(a[:, :2] + shift)
        misses.append(1.0 - a[:, 2] / _Q_MAX)
    unplaced = tuple(sorted([r for r in robots if r not in placed] + far))
    shown = tuple(r for r in placed if r not in far)
    if not keys:
        return MergedMap(np.zeros((0, 2), np.int64), np.zeros(0), origin, (), unplaced)
    allc, allm = np.concatenate(keys), np.concatenate(misses)
    uniq, inverse = np.unique(allc, axis=0, return_inverse=True)
    prod = np.ones(len(uniq))
    np.multiply.at(prod, inverse.ravel(), allm)
    return MergedMap(uniq, 1.0 - prod, origin, shown, unplaced)


def load(registry: Registry) -> MergedMap:
    """The merged map of everything the registry holds."""
    t0 = time.monotonic()
    merged = merged_map(registry.coverage(), registry.origins())
    log.debug("coverage merged: %d cells in %.0f ms", len(merged.p), (time.monotonic() - t0) * 1e3)
    return merged


_CLASS_CHARS = np.array(list("012"))


def console_json(
    merged: MergedMap, robots_ne_m: Mapping[int, tuple[float, float]]
) -> dict[str, Any]:
    """What the console draws: the map's box, one character per cell of it, row by
    row from the southmost (``.`` never looked at, ``0`` looked at less than glanced
    at, ``1`` glanced at, ``2`` searched well), the summary and the largest
    unsearched places near the robots."""
    box = merged.box()
    out: dict[str, Any] = {
        "cell_m": merged.cell_m,
        "box": box,
        "cells": "",
        "summary": merged.summary(),
        "places": [asdict(p) for p in merged.unsearched_places(robots_ne_m)],
        "frame": "local" if merged.origin is None else "global",
        "robots": list(merged.robots),
        "unplaced": list(merged.unplaced),
        "thresholds": {"searched_well": SEARCHED_WELL_P, "glanced_at": GLANCED_AT_P},
    }
    if box is not None:
        n0, n1, e0, e1 = box
        grid = np.full((n1 - n0 + 1, e1 - e0 + 1), ".")
        grid[merged.cells[:, 0] - n0, merged.cells[:, 1] - e0] = _CLASS_CHARS[merged.classes()]
        out["cells"] = "".join(grid.ravel())
    return out
