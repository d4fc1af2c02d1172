"""Memory of warm finds over frames: a warm imprint fades, a person does not; warmth
in the floor lies flat, a person does not.

A person who lay on a floor and moved leaves a warm imprint of their shape; it
cools towards the ambient level frame after frame (minutes), where a person stays
warm. Each remembered warm thing is keyed by where it is (its floor point in metres
with a geometry, its pixel in a photo or a fixed camera) and keeps its excess over
the ambient level for the last ``fade_window_s``. One whose excess falls by at least
``fade_k_per_s`` (a least-squares slope over at least ``fade_min_span_s``) is fading.

Only views at a similar scale are compared (metres per pixel within
``fade_scale_tolerance`` of the latest): a person's face and hands read cooler from
farther, where they fill fewer pixels and blend with the floor, so a rover driving
away from a person would otherwise see a "cooling" person.

Height from the rover's motion (``height``): with a geometry each view also keeps
the camera's floor position and where the find's top row meets the floor. Warmth in
the floor (floor heating, a sun-warmed patch, an imprint) has its top row on its own
far edge, which stays where it is from every viewpoint. A body's top row is its
upper side, ``h`` above the floor: seen from a camera ``H`` up it meets the floor at
``k = H / (H - h)`` times its range, a point that moves ``1 - k`` times as far as
the rover does towards it (0.2 m up from 0.3 m: twice as far, the other way), or
meets no floor in range at all. Along the line of sight, over the views of the last
``shape_window_s`` whose top rows meet the floor, the least-squares slope of that
point against the camera's position gives ``k``, once the camera has moved
``flat_motion_m`` along it: under the ``k`` of ``flat_max_height_m`` is flat;
raised only when ``k`` is above it by twice its standard error (the far edge of a
patch 5 m out moves a third of a metre with one pixel); unknown otherwise.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from enum import Enum

import numpy as np

from companion.vision.thermal_params import ThermalDetectorParams


class Shape(Enum):
    UNKNOWN = "unknown"  # too few views on the floor, too little motion, or in doubt
    FLAT = "flat"
    RAISED = "raised"


@dataclass(frozen=True)
class View:
    """Where the camera was and where a find's top row met the floor (None: it meets
    no floor in range, or the frame cuts the find's top), floor metres."""

    camera_ne: tuple[float, float]
    camera_up_m: float
    top_ne: tuple[float, float] | None


@dataclass(frozen=True)
class Height:
    """What the views say of a find's height: its shape, the height the slope gives
    (m, None while unknown) and how far the camera moved along the line of sight."""

    shape: Shape
    height_m: float | None = None
    moved_m: float = 0.0


@dataclass
class ThermalTrack:
    """One warm thing remembered: where it is and its excess over ambient in time."""

    key: tuple[float, float]  # floor (north, east) m, or pixel (u, v)
    t_last_s: float
    # (t_s, excess_k, scale: metres per pixel, or 1 in a photo)
    samples: deque[tuple[float, float, float]] = field(default_factory=deque)
    views: deque[tuple[float, View]] = field(default_factory=deque)  # (t_s, view)
    flat_seen: bool = False  # once found flat while larger than a part

    def height(self, p: ThermalDetectorParams) -> Height:
        """See the module docstring."""
        on_floor = [(v.camera_ne, v.top_ne) for _, v in self.views if v.top_ne is not None]
        if len(on_floor) < 4:
            return Height(Shape.UNKNOWN)
        cam = np.array([c for c, _ in on_floor])
        top = np.array([t for _, t in on_floor])
        sight = np.asarray(self.key) - cam[-1]
        norm = float(np.hypot(*sight))
        if norm < 1e-6:
            return Height(Shape.UNKNOWN)
        along_cam, along_top = cam @ (sight / norm), top @ (sight / norm)
        moved = float(along_cam.max() - along_cam.min())
        if moved < p.flat_motion_m:
            return Height(Shape.UNKNOWN, moved_m=moved)
        c = along_cam - along_cam.mean()
        slope = float((c * (along_top - along_top.mean())).sum() / (c * c).sum())
        residual = along_top - along_top.mean() - slope * c
        slope_se = float(np.sqrt((residual**2).sum() / (len(c) - 2) / (c * c).sum()))
        k = 1.0 - slope
        up = self.views[-1][1].camera_up_m
        height = up * (1.0 - 1.0 / k) if k > 1.0 else 0.0
        flat_k = up / max(up - p.flat_max_height_m, 1e-6)
        if k < flat_k:
            return Height(Shape.FLAT, height, moved)
        if k - 2.0 * slope_se > flat_k:
            return Height(Shape.RAISED, height, moved)
        return Height(Shape.UNKNOWN, height, moved)

    def slope_k_per_s(self, min_span_s: float, scale_tolerance: float) -> float | None:
        """The excess's trend over the samples at the latest one's scale (within the
        tolerance), None while they span less than min_span_s."""
        txs = np.array(self.samples)
        same = np.abs(txs[:, 2] / txs[-1, 2] - 1.0) <= scale_tolerance
        t, x = txs[same, 0], txs[same, 1]
        if t.size < 3 or t[-1] - t[0] < min_span_s:
            return None
        t = t - t.mean()
        return float((t * (x - x.mean())).sum() / (t * t).sum())


class ThermalMemory:
    """Matches each frame's finds to the warm things of earlier frames."""

    def __init__(self, params: ThermalDetectorParams) -> None:
        self._p = params
        self.tracks: list[ThermalTrack] = []

    def observe(
        self,
        key: tuple[float, float],
        in_metres: bool,
        excess_k: float,
        t_s: float,
        scale: float = 1.0,
        view: View | None = None,
    ) -> tuple[bool, ThermalTrack]:
        """Record one find (``scale``: metres per pixel where it is; 1 in a photo;
        ``view``: with a geometry); (whether it is a fading imprint, its track)."""
        p = self._p
        radius = p.track_radius_m if in_metres else p.track_radius_px
        best: ThermalTrack | None = None
        best_d = radius
        for tr in self.tracks:
            d = float(np.hypot(tr.key[0] - key[0], tr.key[1] - key[1]))
            if d <= best_d and tr.t_last_s < t_s:
                best, best_d = tr, d
        if best is None:
            best = ThermalTrack(key, t_s)
            self.tracks.append(best)
        best.key, best.t_last_s = key, t_s
        best.samples.append((t_s, excess_k, scale))
        while best.samples and best.samples[0][0] < t_s - p.fade_window_s:
            best.samples.popleft()
        if view is not None:
            best.views.append((t_s, view))
        while best.views and best.views[0][0] < t_s - p.shape_window_s:
            best.views.popleft()
        slope = best.slope_k_per_s(p.fade_min_span_s, p.fade_scale_tolerance)
        return slope is not None and slope <= -p.fade_k_per_s, best

    def forget(self, t_s: float) -> None:
        """Drop what has not been seen for track_forget_s (or time went backwards)."""
        keep = self._p.track_forget_s
        self.tracks = [tr for tr in self.tracks if 0.0 <= t_s - tr.t_last_s <= keep]
