"""The simulated bodies lie on the floor as people do: nothing held up in the air."""

from __future__ import annotations

import math

import numpy as np
import pytest

from scenarios.body3d import DIGITS, POSTURES, Body3D, Posture, Solid, build_body


def _height_above_floor_m(solid: Solid) -> float:
    """Height of the solid's lowest point above the floor (NED: down is +z, floor 0)."""
    if solid.kind == "capsule":
        return -(max(float(solid.a[2]), float(solid.b[2])) + solid.radius_m)
    return -(float(solid.a[2]) + float(np.linalg.norm(solid.axes[2, :])))


def _solid(body: Body3D, name: str) -> Solid:
    return next(s for s in body.solids if s.name == name)


@pytest.mark.parametrize("posture", POSTURES)
def test_every_body_rests_on_the_floor(posture: Posture) -> None:
    body = build_body(0.0, 0.0, 0.3, 1.75, posture, math.radians(50), math.radians(20))
    heights = [_height_above_floor_m(s) for s in body.solids if not s.name.endswith(DIGITS)]
    assert min(heights) == pytest.approx(0.0, abs=0.005)  # touching, not floating


@pytest.mark.parametrize("arm_deg", [60.0, 80.0])
def test_a_body_on_its_side_puts_its_hands_and_legs_down(arm_deg: float) -> None:
    """Lying on the side, the lower leg lies on the floor and the upper leg on it; an
    arm reaching out forwards comes down to the floor in front of the chest, not
    held out at shoulder height (0.4 m up)."""
    arm = math.radians(arm_deg)
    body = build_body(0.0, 0.0, 0.0, 1.75, "side", arm, arm)
    for hand in ("left_palm", "right_palm"):
        assert _height_above_floor_m(_solid(body, hand)) < 0.1
    lower, upper = _solid(body, "right_shin"), _solid(body, "left_shin")
    assert _height_above_floor_m(lower) < 0.03
    # The upper shin's underside touches the lower shin's top (within 2 cm).
    lower_top = -(min(float(lower.a[2]), float(lower.b[2])) - lower.radius_m)
    assert abs(_height_above_floor_m(upper) - lower_top) < 0.02


@pytest.mark.parametrize("posture", ["back", "face_down"])
def test_a_body_on_its_back_or_front_lies_flat(posture: Posture) -> None:
    """On the back or face down, the chest, both shins, both forearms and both feet
    lie on the floor (within 3 cm). Face down, the feet once pointed into the floor
    and held the whole body up on its toes, legs and arms 0.12 m in the air: a
    plank, not a person lying there, and the rover's camera saw the floor under it."""
    body = build_body(0.0, 0.0, 0.3, 1.75, posture, math.radians(50), math.radians(20))
    for side in ("left", "right"):
        for part in ("shin", "forearm", "shoe"):
            assert _height_above_floor_m(_solid(body, f"{side}_{part}")) < 0.03, (side, part)
    assert _height_above_floor_m(_solid(body, "chest")) < 0.03
