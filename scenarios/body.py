"""The top-down silhouette of a person lying on the floor.

A victim is drawn as flat polygons on the floor: head, neck, torso, two arms with
hands, two legs with shoes. The same polygons give the rendered image and the
ground-truth visibility, so the two can never disagree.

Body frame: x along the body from the feet to the head, y across it; (0, 0) is the
body centre (about the navel). ``heading_rad`` is the NED yaw of the body's x axis
(0: head towards north). Arm angles are measured from "along the body, towards the
feet" and open outwards; the leg spread likewise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray

Role = Literal["skin", "top", "trousers", "shoes"]
"""Which of the victim's colours a part is painted with."""

_ELLIPSE_POINTS = 24


@dataclass(frozen=True)
class Part:
    name: str
    role: Role
    polygon_ne_m: NDArray[np.float64]  # (N, 2) north, east in metres


def _ellipse(cx: float, cy: float, ax: float, ay: float, angle_rad: float = 0.0) -> np.ndarray:
    t = np.linspace(0.0, 2.0 * math.pi, _ELLIPSE_POINTS, endpoint=False)
    x, y = ax * np.cos(t), ay * np.sin(t)
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    return np.column_stack([cx + c * x - s * y, cy + s * x + c * y])


def _limb(
    x0: float, y0: float, angle_rad: float, length: float, w0: float, w1: float
) -> tuple[np.ndarray, tuple[float, float], tuple[float, float]]:
    """A tapered quad from (x0, y0) along angle (0 = towards the feet), and its end point."""
    dx, dy = -math.cos(angle_rad), math.sin(angle_rad)  # angle 0 points to -x (the feet)
    nx, ny = -dy, dx
    x1, y1 = x0 + dx * length, y0 + dy * length
    quad = np.array(
        [
            [x0 + nx * w0 / 2, y0 + ny * w0 / 2],
            [x1 + nx * w1 / 2, y1 + ny * w1 / 2],
            [x1 - nx * w1 / 2, y1 - ny * w1 / 2],
            [x0 - nx * w0 / 2, y0 - ny * w0 / 2],
        ]
    )
    return quad, (x1, y1), (dx, dy)


def body_parts_local(
    height_m: float, left_arm_rad: float, right_arm_rad: float, leg_spread_rad: float
) -> list[tuple[str, Role, np.ndarray]]:
    """Parts in the body frame (x to the head, y to one side), metres."""
    h = height_m
    parts: list[tuple[str, Role, np.ndarray]] = []
    # Legs first: the torso and shoes are drawn over their ends.
    for side, sign in (("left", 1.0), ("right", -1.0)):
        quad, (fx, fy), (dx, dy) = _limb(
            -0.02 * h, sign * 0.05 * h, sign * leg_spread_rad, 0.44 * h, 0.095 * h, 0.055 * h
        )
        parts.append((f"{side}_leg", "trousers", quad))
        ang = math.atan2(dy, dx)
        parts.append(
            (
                f"{side}_shoe",
                "shoes",
                _ellipse(fx + dx * 0.03 * h, fy + dy * 0.03 * h, 0.06 * h, 0.032 * h, ang),
            )
        )
    torso = np.array(
        [
            [0.33 * h, 0.125 * h],
            [0.36 * h, 0.06 * h],
            [0.36 * h, -0.06 * h],
            [0.33 * h, -0.125 * h],
            [0.05 * h, -0.09 * h],
            [-0.06 * h, -0.105 * h],
            [-0.06 * h, 0.105 * h],
            [0.05 * h, 0.09 * h],
        ]
    )
    parts.append(("torso", "top", torso))
    for side, sign, angle in (("left", 1.0, left_arm_rad), ("right", -1.0, right_arm_rad)):
        quad, (wx, wy), (dx, dy) = _limb(
            0.31 * h, sign * 0.13 * h, sign * angle, 0.33 * h, 0.06 * h, 0.045 * h
        )
        parts.append((f"{side}_arm", "top", quad))
        ang = math.atan2(dy, dx)
        parts.append(
            (
                f"{side}_hand",
                "skin",
                _ellipse(wx + dx * 0.045 * h, wy + dy * 0.045 * h, 0.05 * h, 0.027 * h, ang),
            )
        )
    parts.append(
        (
            "neck",
            "skin",
            np.array(
                [
                    [0.35 * h, 0.03 * h],
                    [0.39 * h, 0.03 * h],
                    [0.39 * h, -0.03 * h],
                    [0.35 * h, -0.03 * h],
                ]
            ),
        )
    )
    parts.append(("head", "skin", _ellipse(0.44 * h, 0.0, 0.065 * h, 0.047 * h)))
    return parts


def body_parts(
    north_m: float,
    east_m: float,
    heading_rad: float,
    height_m: float,
    left_arm_rad: float,
    right_arm_rad: float,
    leg_spread_rad: float,
) -> list[Part]:
    """The parts placed on the floor (north, east in metres), in drawing order."""
    c, s = math.cos(heading_rad), math.sin(heading_rad)
    # Body x maps to (cos h, sin h) in (north, east); body y to (-sin h, cos h).
    rot = np.array([[c, s], [-s, c]])
    out = []
    for name, role, local in body_parts_local(
        height_m, left_arm_rad, right_arm_rad, leg_spread_rad
    ):
        ne = local @ rot + np.array([north_m, east_m])
        out.append(Part(name, role, ne))
    return out
