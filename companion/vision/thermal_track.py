"""Memory of warm finds over frames: a warm imprint fades, a person does not.

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
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import numpy as np

from companion.vision.thermal_params import ThermalDetectorParams


@dataclass
class ThermalTrack:
    """One warm thing remembered: where it is and its excess over ambient in time."""

    key: tuple[float, float]  # floor (north, east) m, or pixel (u, v)
    t_last_s: float
    # (t_s, excess_k, scale: metres per pixel, or 1 in a photo)
    samples: deque[tuple[float, float, float]] = field(default_factory=deque)

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
    ) -> bool:
        """Record one find (``scale``: metres per pixel where it is; 1 in a photo);
        True when it is a fading imprint (drop it)."""
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
        slope = best.slope_k_per_s(p.fade_min_span_s, p.fade_scale_tolerance)
        return slope is not None and slope <= -p.fade_k_per_s

    def forget(self, t_s: float) -> None:
        """Drop what has not been seen for track_forget_s (or time went backwards)."""
        keep = self._p.track_forget_s
        self.tracks = [tr for tr in self.tracks if 0.0 <= t_s - tr.t_last_s <= keep]
