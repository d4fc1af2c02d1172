"""A contact sheet of a world: a top-down map and sample camera frames, as one PNG.

The map is north-up: the route in cyan (start marked), victims outlined in their
urgency colour (LIGHT green, MEDIUM orange, CRITICAL red) with id and visibility,
and the rover's place for each sample frame numbered in yellow; warm objects that
are not people outlined in magenta with their kind and temperature. The frames are
the best view of each victim along the route (most uncovered pixels), then evenly
spaced frames to fill six, each with the thermal camera's frame inset in false colour
(ambient - 2 to ambient + 20 degrees C, black to white).
"""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np

from fusion.camera import CameraModel
from fusion.types import Urgency
from scenarios.motion import Trajectory, TruePose, route_of
from scenarios.raster import top_down_bgr
from scenarios.render import Renderer
from scenarios.thermal import ThermalRenderer
from scenarios.world import World

URGENCY_BGR = {
    Urgency.LIGHT: (60, 200, 60),
    Urgency.MEDIUM: (0, 150, 255),
    Urgency.CRITICAL: (40, 40, 230),
}
_PX_PER_M = 60.0
_TILE = (320, 240)
_SCAN_STEP_S = 1.0
_GOOD_VIEW_PX = 12000
_FONT = cv2.FONT_HERSHEY_SIMPLEX
_WARM_BGR = (230, 80, 230)
_INSET = (128, 96)


def _to_map(n: float, e: float, rows: int) -> tuple[int, int]:
    return round(e * _PX_PER_M), round(rows - 1 - n * _PX_PER_M)


def _pick_frames(
    renderer: Renderer, traj: Trajectory, duration_s: float, count: int
) -> list[TruePose]:
    best: dict[int, tuple[int, float]] = {}
    times = np.arange(0.0, duration_s, _SCAN_STEP_S)
    for t in times:
        pose = traj.pose_at(float(t))
        for vid, px in renderer.render(pose).visible_px.items():
            # A victim filling the frame (the rover on top of it) is no view: cap the
            # pixel count so the earliest good approach view wins.
            px = min(px, _GOOD_VIEW_PX)
            if px > best.get(vid, (0, 0.0))[0]:
                best[vid] = (px, float(t))
    chosen = sorted(t for _, t in best.values())[:count]
    for t in np.linspace(0.0, duration_s, count + 2)[1:-1]:
        if len(chosen) >= count:
            break
        if all(abs(t - c) > 3.0 for c in chosen):
            chosen.append(float(t))
    return [traj.pose_at(t) for t in sorted(chosen)]


def _map(
    world: World, renderer: Renderer, traj: Trajectory, duration_s: float, shots: list[TruePose]
) -> np.ndarray:
    img = top_down_bgr(renderer.raster, _PX_PER_M)
    rows = img.shape[0]
    path = [traj.pose_at(t) for t in np.arange(0.0, duration_s, 0.5)]
    pts = np.array([_to_map(p.north_m, p.east_m, rows) for p in path], np.int32)
    cv2.polylines(img, [pts], False, (230, 220, 60), 1, cv2.LINE_AA)
    cv2.circle(img, tuple(int(x) for x in pts[0]), 6, (230, 220, 60), 2, cv2.LINE_AA)
    for v in world.victims:
        colour = URGENCY_BGR[v.urgency]
        for part in v.parts():
            poly = np.array([_to_map(n, e, rows) for n, e in part.polygon_ne_m], np.int32)
            cv2.polylines(img, [poly], True, colour, 2, cv2.LINE_AA)
        x, y = _to_map(v.north_m, v.east_m, rows)
        label = f"#{v.victim_id} {v.urgency.name} {v.visibility_pct:.0f}%"
        cv2.putText(img, label, (x - 40, y - 30), _FONT, 0.42, (0, 0, 0), 3, cv2.LINE_AA)
        cv2.putText(img, label, (x - 40, y - 30), _FONT, 0.42, colour, 1, cv2.LINE_AA)
    for w in world.warm_objects:
        poly = np.array([_to_map(n, e, rows) for n, e in w.polygon], np.int32)
        cv2.polylines(img, [poly], True, _WARM_BGR, 2, cv2.LINE_AA)
        x, y = _to_map(w.north_m, w.east_m, rows)
        label = f"{w.kind} {w.temperature_c:.0f}C"
        cv2.putText(img, label, (x - 30, y + 4), _FONT, 0.38, (0, 0, 0), 3, cv2.LINE_AA)
        cv2.putText(img, label, (x - 30, y + 4), _FONT, 0.38, _WARM_BGR, 1, cv2.LINE_AA)
    for k, p in enumerate(shots, start=1):
        x, y = _to_map(p.north_m, p.east_m, rows)
        tip = _to_map(
            p.north_m + 0.5 * math.cos(p.yaw_rad), p.east_m + 0.5 * math.sin(p.yaw_rad), rows
        )
        cv2.arrowedLine(img, (x, y), tip, (0, 230, 255), 2, cv2.LINE_AA, tipLength=0.35)
        cv2.putText(img, str(k), (x + 6, y + 14), _FONT, 0.5, (0, 230, 255), 2, cv2.LINE_AA)
    bar = round(_PX_PER_M)
    cv2.line(img, (10, rows - 12), (10 + bar, rows - 12), (255, 255, 255), 2)
    cv2.putText(img, "1 m", (14 + bar, rows - 8), _FONT, 0.4, (255, 255, 255), 1, cv2.LINE_AA)
    cv2.putText(img, "N ^", (img.shape[1] - 40, 18), _FONT, 0.5, (255, 255, 255), 1, cv2.LINE_AA)
    return img


def contact_sheet(
    world: World, camera: CameraModel | None = None, *, frames: int = 6, speed_m_s: float = 0.4
) -> np.ndarray:
    """The sheet as a BGR image."""
    renderer = Renderer(world, camera)
    traj = Trajectory(
        world.start_ne_m,
        world.start_heading_rad,
        route_of(world),
        speed_m_s=speed_m_s,
        seed=world.seed,
    )
    duration = traj.duration_s()
    shots = _pick_frames(renderer, traj, duration, frames)
    left = _map(world, renderer, traj, duration, shots)
    thermal = ThermalRenderer(world)
    lo_c = world.floor.temperature_c - 2.0
    tiles = []
    for k, pose in enumerate(shots, start=1):
        res = renderer.render(pose, frame_key=k)
        tile = cv2.resize(res.image, _TILE, interpolation=cv2.INTER_AREA)
        temps = thermal.render(pose, pose.t_s, frame_key=k).temps_c
        grey = np.clip((temps - lo_c) * (255.0 / 22.0), 0, 255).astype(np.uint8)
        inset = cv2.resize(cv2.applyColorMap(grey, cv2.COLORMAP_INFERNO), _INSET)
        tile[-_INSET[1] :, -_INSET[0] :] = inset
        seen = (
            ", ".join(f"#{vid} {px}px" for vid, px in sorted(res.visible_px.items())) or "no victim"
        )
        caption = f"{k}: t={pose.t_s:.0f}s  {seen}"
        cv2.putText(tile, caption, (6, 16), _FONT, 0.42, (0, 0, 0), 3, cv2.LINE_AA)
        cv2.putText(tile, caption, (6, 16), _FONT, 0.42, (0, 230, 255), 1, cv2.LINE_AA)
        tiles.append(tile)
    while len(tiles) % 2:
        tiles.append(np.zeros((_TILE[1], _TILE[0], 3), np.uint8))
    grid = (
        np.vstack([np.hstack(tiles[i : i + 2]) for i in range(0, len(tiles), 2)]) if tiles else None
    )
    height = max(left.shape[0], grid.shape[0] if grid is not None else 0) + 30
    width = left.shape[1] + (grid.shape[1] if grid is not None else 0) + 10
    sheet = np.full((height, width, 3), 30, np.uint8)
    sheet[30 : 30 + left.shape[0], : left.shape[1]] = left
    if grid is not None:
        sheet[30 : 30 + grid.shape[0], left.shape[1] + 10 :] = grid
    counts = {u: sum(1 for v in world.victims if v.urgency is u) for u in Urgency}
    title = (
        f"world '{world.name}' seed {world.seed}: {world.size_m[0]:.0f} x {world.size_m[1]:.0f} m, "
        f"victims {len(world.victims)} (L {counts[Urgency.LIGHT]}, M {counts[Urgency.MEDIUM]}, "
        f"C {counts[Urgency.CRITICAL]}), route {duration:.0f} s"
    )
    cv2.putText(sheet, title, (8, 20), _FONT, 0.55, (240, 240, 240), 1, cv2.LINE_AA)
    return sheet


def write_sheet(world: World, path: Path, camera: CameraModel | None = None) -> Path:
    path = Path(path)
    if not cv2.imwrite(str(path), contact_sheet(world, camera)):
        raise OSError(f"{path}: cannot write the PNG")
    return path
