"""A mission map PNG: the route, and victims coloured by urgency with their
uncertainty ellipses (2 sigma), north up, east right, a 1 m grid, a legend; under
them, given a coverage grid, where the cameras looked (searched well, glanced at,
looked at; fusion/coverage.py: it over-claims behind tall debris); for a
simulated mission also the debris and the true victims, labelled, each joined to
the centre of its uncovered part where that lies apart from the body's centre (a
buried victim is found, and scored, where it shows); and each closer look, with
what it settled."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from fusion.coverage import GLANCED_AT_P, SEARCHED_WELL_P, CoverageGrid
from fusion.registry import Victim
from fusion.types import Cov2, TrackState, Urgency

URGENCY_BGR = {
    Urgency.LIGHT: (60, 170, 40),  # green
    Urgency.MEDIUM: (0, 140, 255),  # orange
    Urgency.CRITICAL: (40, 40, 220),  # red
}
_CANVAS_PX = 900
_MARGIN_PX = 50
_MIN_SPAN_M = 4.0
_ROUTE_BGR = (150, 110, 60)
_DEBRIS_BGR = (185, 185, 185)
_LOOK_BGR = (170, 50, 150)  # purple
_TEXT_BGR = (30, 30, 30)
_FONT = cv2.FONT_HERSHEY_SIMPLEX
# Coverage shades: searched well, glanced at, looked at (under everything else).
_WELL_BGR = (170, 215, 160)
_GLANCED_BGR = (205, 232, 200)
_LOOKED_BGR = (232, 242, 230)


@dataclass(frozen=True)
class MapVictim:
    """A reported victim as the map draws it."""

    label: str  # e.g. "#3" (companion) or "V3" (HQ)
    urgency: Urgency
    north_m: float
    east_m: float
    cov_ne_m2: Cov2
    visibility_pct: float
    confirmed: bool = True

    @classmethod
    def of(cls, v: Victim) -> MapVictim:
        confirmed = v.state in (TrackState.CONFIRMED, TrackState.NOT_SEEN_RECENTLY)
        return cls(
            f"#{v.victim_id}",
            v.urgency,
            v.north_m,
            v.east_m,
            v.cov_ne_m2,
            v.visibility_pct,
            confirmed,
        )


@dataclass(frozen=True)
class MapTruth:
    """A true victim of a simulated world."""

    label: str  # e.g. "T1"
    urgency: Urgency
    north_m: float
    east_m: float
    visible_ne_m: tuple[float, float] | None = None  # centre of its uncovered part


@dataclass(frozen=True)
class MapLook:
    """A closer look: where the route was left, the viewpoint, what it looked at, and
    what it settled (or why it was aborted)."""

    start_ne_m: tuple[float, float]
    view_ne_m: tuple[float, float]
    candidate_ne_m: tuple[float, float]
    outcome: str


_VISIBLE_APART_M = 0.2  # a visible part nearer the body's centre than this is not drawn


def _visible_apart(t: MapTruth) -> tuple[float, float] | None:
    if t.visible_ne_m is None or not all(map(math.isfinite, t.visible_ne_m)):
        return None
    apart = math.hypot(t.visible_ne_m[0] - t.north_m, t.visible_ne_m[1] - t.east_m)
    return t.visible_ne_m if apart >= _VISIBLE_APART_M else None


def draw_mission_map(
    path: Path,
    route_ne_m: Sequence[tuple[float, float]],
    victims: Sequence[MapVictim],
    truth: Sequence[MapTruth] = (),
    debris_ne_m: Sequence[np.ndarray] = (),
    extent_ne_m: tuple[float, float, float, float] | None = None,
    coverage: CoverageGrid | None = None,
    looks: Sequence[MapLook] = (),
) -> None:
    """Write the map. ``extent_ne_m`` (n0, n1, e0, e1) fixes the area shown (a
    simulated world's floor); by default it is what the route and victims span.
    ``coverage``: its cells are shaded under everything by how well they were
    searched, and the legend gives the areas. ``looks``: each closer look's
    viewpoint, joined to where the route was left and to what it looked at."""
    if extent_ne_m is not None:
        n0, n1, e0, e1 = extent_ne_m
    else:
        points = (
            list(route_ne_m)
            + [(v.north_m, v.east_m) for v in victims]
            + [(t.north_m, t.east_m) for t in truth]
            + (_looked_corners(coverage) if coverage is not None else [])
        )
        if points:
            n = np.array([p[0] for p in points])
            e = np.array([p[1] for p in points])
            n0, n1, e0, e1 = n.min() - 1, n.max() + 1, e.min() - 1, e.max() + 1
        else:
            n0, n1, e0, e1 = -2.0, 2.0, -2.0, 2.0
    span_m = max(n1 - n0, e1 - e0, _MIN_SPAN_M)
    scale = (_CANVAS_PX - 2 * _MARGIN_PX) / span_m  # px per metre
    h = int((n1 - n0) * scale) + 2 * _MARGIN_PX
    w = int((e1 - e0) * scale) + 2 * _MARGIN_PX + 190  # room on the right for the legend
    img = np.full((max(h, 260), max(w, 300), 3), 250, np.uint8)

    def px(north_m: float, east_m: float) -> tuple[int, int]:
        return (
            int(_MARGIN_PX + (east_m - e0) * scale),
            int(img.shape[0] - _MARGIN_PX - (north_m - n0) * scale),
        )

    if coverage is not None:
        _draw_coverage(img, coverage, px)
    for k in range(math.ceil(e0), math.floor(e1) + 1):  # 1 m grid
        cv2.line(img, px(n0, k), px(n1, k), (228, 228, 228), 1)
    for k in range(math.ceil(n0), math.floor(n1) + 1):
        cv2.line(img, px(k, e0), px(k, e1), (228, 228, 228), 1)
    cv2.rectangle(img, px(n1, e0), px(n0, e1), (200, 200, 200), 1)
    for poly in debris_ne_m:
        pts = np.array([px(float(n), float(e)) for n, e in poly], np.int32)
        cv2.fillPoly(img, [pts], _DEBRIS_BGR, cv2.LINE_AA)
    if len(route_ne_m) > 1:
        pts = np.array([px(n, e) for n, e in route_ne_m], np.int32)
        cv2.polylines(img, [pts], False, _ROUTE_BGR, 2, cv2.LINE_AA)
        cv2.circle(img, px(*route_ne_m[0]), 6, _ROUTE_BGR, -1)
    right_px = int(_MARGIN_PX + (e1 - e0) * scale)
    labels: list[tuple[str, tuple[int, int]]] = []
    for k, look in enumerate(looks, 1):
        view = px(*look.view_ne_m)
        cv2.line(img, px(*look.start_ne_m), view, _LOOK_BGR, 2, cv2.LINE_AA)
        cv2.arrowedLine(img, view, px(*look.candidate_ne_m), _LOOK_BGR, 1, cv2.LINE_AA, 0, 0.2)
        cv2.drawMarker(img, view, _LOOK_BGR, cv2.MARKER_TRIANGLE_UP, 12, 2, cv2.LINE_AA)
        labels.append((f"look {k}: {look.outcome}", view))
    for t in truth:
        at = px(t.north_m, t.east_m)
        cv2.drawMarker(img, at, (0, 0, 0), cv2.MARKER_TILTED_CROSS, 16, 2, cv2.LINE_AA)
        labels.append((f"{t.label} {t.urgency.name}", at))
    for v in victims:
        colour = URGENCY_BGR[v.urgency]
        (a, b), (_, d) = v.cov_ne_m2
        vals, vecs = np.linalg.eigh(np.array([[a, b], [b, d]]))
        # Axes in pixels (2 sigma); the angle is of the major axis on screen (x east, y south).
        major = vecs[:, 1]
        angle = math.degrees(math.atan2(-major[0], major[1]))
        axes = (
            max(2, int(2 * math.sqrt(max(vals[1], 0.0)) * scale)),
            max(2, int(2 * math.sqrt(max(vals[0], 0.0)) * scale)),
        )
        centre = px(v.north_m, v.east_m)
        cv2.ellipse(img, centre, axes, angle, 0, 360, colour, 2, cv2.LINE_AA)
        cv2.circle(img, centre, 7, colour, -1 if v.confirmed else 2, cv2.LINE_AA)
        labels.append((f"{v.label} {v.urgency.name} {v.visibility_pct:.0f}%", centre))
    parts = [(t, shows) for t in truth if (shows := _visible_apart(t)) is not None]
    for t, shows in parts:  # over the reports: a report on an uncovered part still shows it
        seen_at = px(*shows)
        cv2.line(img, px(t.north_m, t.east_m), seen_at, (0, 0, 0), 1, cv2.LINE_AA)
        cv2.circle(img, seen_at, 5, (0, 0, 0), 2, cv2.LINE_AA)
    # Labels last, over everything, each where it hides no marker and no other label.
    markers = [at for _text, at in labels]
    for text, (x, y), _at in place_labels(labels, markers, (0, 0, right_px, img.shape[0])):
        cv2.putText(img, text, (x, y), _FONT, 0.5, (250, 250, 250), 4, cv2.LINE_AA)  # halo
        cv2.putText(img, text, (x, y), _FONT, 0.5, _TEXT_BGR, 1, cv2.LINE_AA)
    y = _legend(img, right_px + 20, bool(truth), bool(parts), bool(debris_ne_m), bool(looks))
    if coverage is not None:
        _coverage_legend(img, right_px + 20, y, coverage)
    bar_px = int(scale)
    cv2.line(img, (20, img.shape[0] - 20), (20 + bar_px, img.shape[0] - 20), (0, 0, 0), 2)
    cv2.putText(img, "1 m", (20, img.shape[0] - 28), _FONT, 0.45, (0, 0, 0), 1)
    x = img.shape[1] - 30
    cv2.arrowedLine(
        img, (x, img.shape[0] - 30), (x, img.shape[0] - 65), (0, 0, 0), 2, tipLength=0.35
    )
    cv2.putText(img, "N", (x - 6, img.shape[0] - 12), _FONT, 0.55, (0, 0, 0), 2)
    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), img):
        raise OSError(f"cannot write {path}")


Rect = tuple[int, int, int, int]  # x0, y0, x1, y1 in pixels

_MARKER_HALF_PX = 9  # a marker's half size, kept clear of labels


def place_labels(
    labels: Sequence[tuple[str, tuple[int, int]]],
    markers: Sequence[tuple[int, int]],
    area: Rect,
) -> list[tuple[str, tuple[int, int], Rect]]:
    """Where to write each label (text, marker pixel): the text's origin and its box.

    Each label goes to the first place beside its marker (right, left, above, below,
    then farther out; shifted inside ``area``) that overlaps no marker and no label
    placed before it; if there is none, the one that overlaps least."""
    placed: list[Rect] = []
    keep_clear = [
        (x - _MARKER_HALF_PX, y - _MARKER_HALF_PX, x + _MARKER_HALF_PX, y + _MARKER_HALF_PX)
        for x, y in markers
    ]
    out = []
    for text, (mx, my) in labels:
        (tw, th), base = cv2.getTextSize(text, _FONT, 0.5, 1)
        bw, bh = tw + 4, th + 3 + base
        best: tuple[int, Rect] | None = None
        for ring in (0, 1, 2, 3):
            gap = 12 + 16 * ring
            corners = (  # the box's top left: right of, left of, above, below the marker
                (mx + gap, my - bh // 2),
                (mx - gap - bw, my - bh // 2),
                (mx - bw // 2, my - gap - bh),
                (mx - bw // 2, my + gap),
            )
            for x, y in corners:
                x0 = min(max(x, area[0]), area[2] - bw)  # shifted inside the area
                y0 = min(max(y, area[1]), area[3] - bh)
                box = (x0, y0, x0 + bw, y0 + bh)
                cost = sum(_overlap(box, r) for r in (*placed, *keep_clear))
                if best is None or cost < best[0]:
                    best = (cost, box)
                if cost == 0:
                    break
            if best is not None and best[0] == 0:
                break
        assert best is not None
        box = best[1]
        placed.append(box)
        out.append((text, (box[0] + 2, box[3] - base), box))
    return out


def _overlap(a: Rect, b: Rect) -> int:
    """The pixels two boxes share."""
    return max(0, min(a[2], b[2]) - max(a[0], b[0])) * max(0, min(a[3], b[3]) - max(a[1], b[1]))


def _looked_corners(grid: CoverageGrid) -> list[tuple[float, float]]:
    """Two corners of the box of the cells looked at (none when none was)."""
    rows, cols = np.nonzero(grid.probabilities() > 0)
    if not len(rows):
        return []
    (n0, e0), s = grid.origin_index, grid.cell_m
    return [
        ((n0 + rows.min()) * s + 1.0, (e0 + cols.min()) * s + 1.0),  # the margin is added
        ((n0 + rows.max() + 1) * s - 1.0, (e0 + cols.max() + 1) * s - 1.0),
    ]


def _draw_coverage(
    img: np.ndarray, grid: CoverageGrid, px: Callable[[float, float], tuple[int, int]]
) -> None:
    """Each looked-at cell as a filled square, shaded by its probability."""
    p = grid.probabilities()
    (n0_idx, e0_idx), s = grid.origin_index, grid.cell_m
    for threshold, colour in (
        (0.0, _LOOKED_BGR),
        (GLANCED_AT_P, _GLANCED_BGR),
        (SEARCHED_WELL_P, _WELL_BGR),
    ):
        rows, cols = np.nonzero(p >= threshold if threshold > 0 else p > 0)
        for r, c in zip(rows.tolist(), cols.tolist(), strict=True):
            n, e = (n0_idx + r) * s, (e0_idx + c) * s
            cv2.rectangle(img, px(n + s, e), px(n, e + s), colour, -1)


def _coverage_legend(img: np.ndarray, x: int, y: int, grid: CoverageGrid) -> None:
    summary = grid.summary()
    rows = (
        (_WELL_BGR, f"searched well {summary.searched_well_m2:.0f} m2"),
        (_GLANCED_BGR, f"glanced at {summary.glanced_at_m2:.0f} m2"),
        (_LOOKED_BGR, f"looked at {summary.looked_at_m2:.0f} m2"),
    )
    for colour, text in rows:
        y += 26
        cv2.rectangle(img, (x, y - 12), (x + 16, y + 2), colour, -1)
        cv2.putText(img, text, (x + 22, y), _FONT, 0.45, _TEXT_BGR, 1)
    y += 22
    cv2.putText(img, "(over-claims behind", (x, y), _FONT, 0.4, _TEXT_BGR, 1)
    cv2.putText(img, " tall debris)", (x, y + 16), _FONT, 0.4, _TEXT_BGR, 1)


def _legend(img: np.ndarray, x: int, truth: bool, parts: bool, debris: bool, looks: bool) -> int:
    y = 30
    cv2.putText(img, "Legend", (x, y), _FONT, 0.55, _TEXT_BGR, 2, cv2.LINE_AA)
    for urgency, colour in URGENCY_BGR.items():
        y += 26
        cv2.circle(img, (x + 8, y - 5), 7, colour, -1, cv2.LINE_AA)
        cv2.putText(img, f"{urgency.name} victim", (x + 22, y), _FONT, 0.5, _TEXT_BGR, 1)
    y += 26
    cv2.ellipse(img, (x + 8, y - 5), (10, 6), 0, 0, 360, (90, 90, 90), 2, cv2.LINE_AA)
    cv2.putText(img, "95 % area (2 sigma)", (x + 22, y), _FONT, 0.5, _TEXT_BGR, 1)
    y += 26
    cv2.line(img, (x, y - 5), (x + 16, y - 5), _ROUTE_BGR, 2, cv2.LINE_AA)
    cv2.putText(img, "rover path", (x + 22, y), _FONT, 0.5, _TEXT_BGR, 1)
    if truth:
        y += 26
        cv2.drawMarker(img, (x + 8, y - 5), (0, 0, 0), cv2.MARKER_TILTED_CROSS, 14, 2)
        cv2.putText(img, "true victim (sim)", (x + 22, y), _FONT, 0.5, _TEXT_BGR, 1)
    if parts:
        y += 26
        cv2.circle(img, (x + 8, y - 5), 5, (0, 0, 0), 2, cv2.LINE_AA)
        cv2.putText(img, "its uncovered part", (x + 22, y), _FONT, 0.5, _TEXT_BGR, 1)
    if debris:
        y += 26
        cv2.rectangle(img, (x, y - 12), (x + 16, y + 2), _DEBRIS_BGR, -1)
        cv2.putText(img, "debris", (x + 22, y), _FONT, 0.5, _TEXT_BGR, 1)
    if looks:
        y += 26
        cv2.drawMarker(img, (x + 8, y - 5), _LOOK_BGR, cv2.MARKER_TRIANGLE_UP, 12, 2)
        cv2.putText(img, "closer look from here", (x + 22, y), _FONT, 0.5, _TEXT_BGR, 1)
    return y
