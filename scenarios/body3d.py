"""A person lying on the floor as a solid, articulated body.

The body is built from capsules (neck, limbs) and ellipsoids (head, ears, chest,
belly, pelvis, hands, shoes) around a skeleton, for four postures: on the ``back``,
on the ``side``, ``face_down`` and ``curled`` (on the side, knees and arms drawn
in). The renderer (scenarios.render) intersects the camera's rays with these
solids, so a body has volume, shading, perspective and self-occlusion from the
rover's low camera; its face (eyes, brows, nose, mouth), hair, clothing pattern,
sleeves (long, or short with bare forearms) and dust are painted on the surface.

Body frame before posture: x along the body from the feet to the head, y to the
body's left, z up out of its chest (a body on its back). A posture rolls the body
about x (side: 90 degrees, face down: 180) and lifts it so that it rests on the
floor; face down, the limbs rest on the floor on their fronts and the feet lie
stretched, so that the body lies flat on its chest, as a person does.
``heading_rad`` is the NED yaw of the x axis; (north_m, east_m) is the centre of
its floor footprint (feet to crown, side to side).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import cv2
import numpy as np
from numpy.typing import NDArray

from scenarios import shapes

F = NDArray[np.float64]

Posture = Literal["back", "side", "face_down", "curled"]
POSTURES: tuple[Posture, ...] = ("back", "side", "face_down", "curled")
Pattern = Literal["plain", "stripes", "check", "hivis", "camo"]
PATTERNS: tuple[Pattern, ...] = ("plain", "stripes", "check", "hivis", "camo")
Sleeves = Literal["long", "short"]  # short: bare forearms (skin), as in a T-shirt
SLEEVES: tuple[Sleeves, ...] = ("long", "short")

# A hand's fingers and thumb: they bend against the floor and do not hold a body up.
DIGITS = ("_thumb", "_finger0", "_finger1", "_finger2", "_finger3")

# Material ids (a body's surfaces); 0 is "not this body".
SKIN, TOP, TROUSERS, SHOES, HAIR = 1, 2, 3, 4, 5


@dataclass(frozen=True)
class Solid:
    kind: Literal["capsule", "ellipsoid"]
    material: int
    a: F  # capsule end / ellipsoid centre (NED, m)
    b: F  # capsule other end / unused
    radius_m: float  # capsule radius / bounding radius of the ellipsoid
    axes: F  # ellipsoid semi-axes as columns (NED); unused for capsules
    name: str

    def bound(self) -> tuple[F, float]:
        if self.kind == "capsule":
            return 0.5 * (self.a + self.b), 0.5 * float(np.linalg.norm(self.b - self.a)) + (
                self.radius_m
            )
        return self.a, self.radius_m

    def intersect(self, o: F, d: F) -> tuple[F, F]:
        if self.kind == "capsule":
            return shapes.capsule(o, d, self.a, self.b, self.radius_m)
        return shapes.ellipsoid(o, d, self.a, self.axes)


@dataclass(frozen=True)
class Body3D:
    solids: tuple[Solid, ...]
    head_centre: F  # NED
    face_axis: F  # unit NED vector out of the face
    up_axis: F  # unit NED vector from the chin to the crown
    to_body: F  # 3x3: NED offset -> body frame (x to the head, y left, z front)
    centre: F  # NED
    bound_radius_m: float
    scale: float  # height / 1.7 m: the body's size relative to an adult's


# The chest's centre above the back and its half depth, in the supine body frame (z
# out of the chest, times the body's scale).
_CHEST_Z, _CHEST_DEPTH = 0.11, 0.105
# Face down, the floor is where the chest's front is: the chest is the body's lowest
# part, and the limbs rest on the floor at this level, not at z = 0.
PRONE_FLOOR_Z = _CHEST_Z + _CHEST_DEPTH


def _rot_x(angle: float) -> F:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]], float)


def _skeleton(
    height_m: float,
    posture: Posture,
    left_arm_rad: float,
    right_arm_rad: float,
    leg_spread_rad: float,
    sleeves: Sleeves,
) -> list[tuple[str, int, str, F, F, float | F]]:
    """Solids in the supine body frame (m): (name, material, kind, a, b, radius|axes)."""
    k = height_m / 1.7
    out: list[tuple[str, int, str, F, F, float | F]] = []

    def v(x: float, y: float, z: float) -> F:
        return np.array([x, y, z]) * k

    def ell(name: str, mat: int, c: F, ax: float, ay: float, az: float) -> None:
        out.append((name, mat, "ellipsoid", c, c, np.diag([ax, ay, az]) * k))

    def cap(name: str, mat: int, a: F, b: F, r: float) -> None:
        out.append((name, mat, "capsule", a, b, r * k))

    curled = posture == "curled"
    ell("head", SKIN, v(0.73, 0, 0.105), 0.115, 0.085, 0.1)
    for side, sign in (("left", 1.0), ("right", -1.0)):  # ears break the ball's outline
        ell(f"{side}_ear", SKIN, v(0.725, sign * 0.083, 0.10), 0.032, 0.012, 0.02)
    cap("neck", SKIN, v(0.57, 0, 0.1), v(0.65, 0, 0.1), 0.052)
    ell("chest", TOP, v(0.40, 0, _CHEST_Z), 0.17, 0.185, _CHEST_DEPTH)
    ell("belly", TOP, v(0.17, 0, 0.1), 0.15, 0.16, 0.095)
    ell("pelvis", TROUSERS, v(-0.02, 0, 0.095), 0.12, 0.175, 0.095)
    for side, sign, arm in (("left", 1.0, left_arm_rad), ("right", -1.0, right_arm_rad)):
        shoulder = v(0.50, sign * 0.19, 0.1)
        if curled:
            # Arms drawn in front of the chest.
            elbow = shoulder + v(-0.12, -sign * 0.02, 0.25)
            wrist = elbow + v(0.22, -sign * 0.05, 0.05)
        else:
            # On the back or face down the arms open sideways; on the side, forwards
            # (out of the chest). The lower arm then lies on the floor; the upper one
            # (the left: up after the roll) drapes down in front of the chest the
            # further it reaches, so its hand comes to the floor and the arm is not
            # held out in the air at shoulder height.
            if posture == "side":
                drop = 0.8 * math.sin(arm) if sign > 0 else 0.0
                direction = np.array([-math.cos(arm), -drop, math.sin(arm)])
                direction /= float(np.linalg.norm(direction))
            else:
                direction = np.array([-math.cos(arm), sign * math.sin(arm), 0.0])
            elbow = shoulder + direction * 0.29 * k
            wrist = elbow + direction * 0.26 * k
            if posture == "back":  # the arm rests on the floor from the shoulder out
                elbow[2], wrist[2] = 0.052 * k, 0.042 * k
            elif posture == "face_down":  # the same, on the front of the arm
                elbow[2], wrist[2] = (PRONE_FLOOR_Z - 0.052) * k, (PRONE_FLOOR_Z - 0.042) * k
        cap(f"{side}_upper_arm", TOP, shoulder, elbow, 0.047)
        cap(f"{side}_forearm", SKIN if sleeves == "short" else TOP, elbow, wrist, 0.038)
        hand_dir = (wrist - elbow) / max(float(np.linalg.norm(wrist - elbow)), 1e-9)
        out += _hand(side, sign, wrist, hand_dir, k)
        hip = v(-0.05, sign * 0.095, 0.09)
        if curled:
            knee = hip + v(0.30, sign * 0.02, 0.30)
            ankle = knee + v(-0.36, 0.0, 0.05)
        else:
            direction = np.array([-math.cos(leg_spread_rad), sign * math.sin(leg_spread_rad), 0])
            knee = hip + direction * 0.43 * k
            ankle = knee + direction * 0.42 * k
            knee[2], ankle[2] = 0.078 * k, 0.06 * k  # the leg rests on the floor
            if posture == "face_down":  # on the front of the thigh and shin
                knee[2], ankle[2] = (PRONE_FLOOR_Z - 0.077) * k, (PRONE_FLOOR_Z - 0.06) * k
            if posture == "side":
                # The lower leg lies on the floor (the body rests on its lower arm and
                # shoulder, 0.24 m below the spine) and the upper leg on the lower one.
                knee[1], ankle[1] = -0.175 * k, -0.18 * k
                if sign > 0:
                    knee[1], ankle[1] = knee[1] + 0.13 * k, ankle[1] + 0.112 * k
        cap(f"{side}_thigh", TROUSERS, hip, knee, 0.075)
        cap(f"{side}_shin", TROUSERS, knee, ankle, 0.056)
        shin_dir = (ankle - knee) / max(float(np.linalg.norm(ankle - knee)), 1e-9)
        # The foot points out of the front of the body (toes up on the back); face
        # down it is stretched along the shin, its top on the floor (pointing into
        # the floor it held the whole body up on its toes, 0.12 m above the floor).
        stretched = curled or posture == "face_down"
        foot_dir = -np.array([1.0, 0.0, 0.0]) if stretched else np.array([0.0, 0.0, 1.0])
        sc = ankle + shin_dir * 0.03 * k + foot_dir * 0.06 * k
        out.append(
            (
                f"{side}_shoe",
                SHOES,
                "ellipsoid",
                sc,
                sc,
                _frame_axes(foot_dir, 0.13, 0.05, 0.055) * k,
            )
        )
    return out


def _hand(
    side: str, sign: float, wrist: F, direction: F, k: float
) -> list[tuple[str, int, str, F, F, float | F]]:
    """A palm and five fingers, lying flat, the thumb towards the body's front."""
    axes = _frame_axes(direction, 0.05, 0.043, 0.018)
    across = axes[:, 1] / max(float(np.linalg.norm(axes[:, 1])), 1e-9)
    palm = wrist + direction * 0.045 * k
    parts: list[tuple[str, int, str, F, F, float | F]] = [
        (f"{side}_palm", SKIN, "ellipsoid", palm, palm, axes * k)
    ]
    for i, offset in enumerate((-0.027, -0.009, 0.009, 0.027)):
        base = palm + direction * 0.045 * k + across * offset * k
        spread = direction + across * offset * 1.5
        spread /= float(np.linalg.norm(spread))
        length = (0.065, 0.078, 0.072, 0.058)[i] * k
        parts.append(
            (f"{side}_finger{i}", SKIN, "capsule", base, base + spread * length, 0.0085 * k)
        )
    thumb_base = palm + across * sign * 0.035 * k
    thumb_dir = direction + across * sign * 0.9
    thumb_dir /= float(np.linalg.norm(thumb_dir))
    parts.append(
        (
            f"{side}_thumb",
            SKIN,
            "capsule",
            thumb_base,
            thumb_base + thumb_dir * 0.055 * k,
            0.0105 * k,
        )
    )
    return parts


def _frame_axes(main: F, a_main: float, a_side: float, a_third: float) -> F:
    """Semi-axes as columns: ``a_main`` along ``main``, the others perpendicular."""
    m = main / max(float(np.linalg.norm(main)), 1e-9)
    helper = np.array([0.0, 0.0, 1.0]) if abs(m[2]) < 0.9 else np.array([0.0, 1.0, 0.0])
    s = np.cross(m, helper)
    s /= float(np.linalg.norm(s))
    t = np.cross(m, s)
    return np.column_stack([m * a_main, s * a_side, t * a_third])


def build_body(
    north_m: float,
    east_m: float,
    heading_rad: float,
    height_m: float,
    posture: Posture = "back",
    left_arm_rad: float = 0.15,
    right_arm_rad: float = 0.15,
    leg_spread_rad: float = 0.05,
    sleeves: Sleeves = "long",
) -> Body3D:
    roll = {"back": 0.0, "side": math.pi / 2, "face_down": math.pi, "curled": math.pi / 2}[posture]
    r_roll = _rot_x(roll)
    parts = _skeleton(height_m, posture, left_arm_rad, right_arm_rad, leg_spread_rad, sleeves)
    # Lowest point after the roll, to rest the body on the floor; not a finger or
    # thumb (a side-lying body's lower thumb, pointing down, held it 4 cm up).
    lowest = math.inf
    for name, _mat, kind, a, b, size in parts:
        if name.endswith(DIGITS):
            continue
        if kind == "capsule":
            assert isinstance(size, float)
            for p in (a, b):
                lowest = min(lowest, float((r_roll @ p)[2]) - size)
        else:
            assert isinstance(size, np.ndarray)
            axes = r_roll @ size
            lowest = min(lowest, float((r_roll @ a)[2]) - float(np.linalg.norm(axes[2, :])))
    lift = np.array([0.0, 0.0, -lowest])
    mid = np.array([-0.07 * height_m / 1.7, 0.0, 0.0])  # the centre of the footprint
    # Body frame (x head, y left, z up) -> NED: x -> (cos h, sin h, 0), z up -> -down.
    c, s = math.cos(heading_rad), math.sin(heading_rad)
    r_ned = np.array([[c, s, 0.0], [s, -c, 0.0], [0.0, 0.0, -1.0]])
    # Columns: the images of the body axes x, y, z. y (left) is x turned by +90 deg
    # seen from above, which in NED (east clockwise from north) is (sin h, -cos h).
    origin = np.array([north_m, east_m, 0.0])

    def to_ned(p: F) -> F:
        q = r_roll @ (p - mid) + lift
        return np.asarray(origin + r_ned @ q, dtype=np.float64)

    solids = []
    for name, mat, kind, a, b, size in parts:
        if kind == "capsule":
            assert isinstance(size, float)
            solids.append(Solid("capsule", mat, to_ned(a), to_ned(b), size, np.eye(3), name))
        else:
            assert isinstance(size, np.ndarray)
            axes = r_ned @ r_roll @ size
            bound = float(np.linalg.norm(axes, axis=0).max())
            solids.append(Solid("ellipsoid", mat, to_ned(a), to_ned(a), bound, axes, name))
    head = next(x for x in solids if x.name == "head")
    rot = r_ned @ r_roll
    centre = to_ned(mid)
    radius = max(
        float(np.linalg.norm(sb[0] - centre)) + sb[1] for sb in (x.bound() for x in solids)
    )
    return Body3D(
        tuple(solids),
        head.a,
        rot @ np.array([0.0, 0.0, 1.0]),
        rot @ np.array([1.0, 0.0, 0.0]),
        rot.T,
        centre,
        radius,
        height_m / 1.7,
    )


def intersect(body: Body3D, o: F, d: F) -> tuple[F, F, NDArray[np.int8]]:
    """Distance, normal and material of the first hit of each ray (inf/0: miss)."""
    n = len(d)
    t_best = np.full(n, np.inf)
    normal = np.zeros((n, 3))
    material = np.zeros(n, np.int8)
    for solid in body.solids:
        c, r = solid.bound()
        oc = c - o
        dist = float(np.linalg.norm(oc))
        along = d @ oc
        if dist > r:
            sel = np.nonzero((along > 0) & (along * along >= dist * dist - r * r))[0]
        else:
            sel = np.arange(n)
        if len(sel) == 0:
            continue
        t, nrm = solid.intersect(o, d[sel])
        better = t < t_best[sel]
        idx = sel[better]
        t_best[idx] = t[better]
        normal[idx] = nrm[better]
        material[idx] = solid.material
    return t_best, normal, material


@dataclass(frozen=True)
class Look:
    """How a body is painted: colours (RGB), clothing pattern and dust (0..1)."""

    skin_rgb: tuple[int, int, int]
    top_rgb: tuple[int, int, int]
    trousers_rgb: tuple[int, int, int]
    shoes_rgb: tuple[int, int, int]
    hair_rgb: tuple[int, int, int]
    pattern: Pattern = "plain"
    dust: float = 0.0


_DUST_BGR = np.array([150.0, 165.0, 175.0])
_HIVIS_BGR = np.array([20.0, 230.0, 235.0])  # fluorescent yellow
_BAND_BGR = np.array([200.0, 200.0, 200.0])  # retro-reflective band


def _bgr(rgb: tuple[int, int, int]) -> F:
    return np.array(rgb[::-1], float)


def paint(body: Body3D, look: Look, p: F, material: NDArray[np.int8]) -> F:
    """Albedo (BGR, 0..255) at surface points ``p`` (N, 3 NED) of the given materials."""
    out = np.zeros((len(p), 3))
    for mat, rgb in (
        (SKIN, look.skin_rgb),
        (TOP, look.top_rgb),
        (TROUSERS, look.trousers_rgb),
        (SHOES, look.shoes_rgb),
    ):
        out[material == mat] = _bgr(rgb)
    local = (p - body.centre) @ body.to_body.T  # body frame: x to the head, y left, z front
    cloth = (material == TOP) | (material == TROUSERS)
    x, y, z = local[:, 0], local[:, 1], local[:, 2]
    if look.pattern == "stripes":
        out[cloth & (np.sin(x * 2 * math.pi / 0.07) > 0.3)] *= 0.55
    elif look.pattern == "check":
        a = np.sin(x * 2 * math.pi / 0.12) * np.sin((y + z) * 2 * math.pi / 0.12)
        out[cloth & (a > 0)] *= 0.6
        out[cloth & (np.abs(np.sin(x * 2 * math.pi / 0.12)) < 0.08)] = _bgr((200, 40, 40))
    elif look.pattern == "camo":
        a = np.sin(x * 17.0 + 2 * np.sin(y * 11.0)) + np.sin((y + z) * 13.0 + x * 5.0)
        out[cloth & (a > 0.6)] *= 0.55
        out[cloth & (a < -0.7)] = out[cloth & (a < -0.7)] * 0.5 + np.array([40.0, 70.0, 60.0])
    elif look.pattern == "hivis":
        top = material == TOP
        out[top] = _HIVIS_BGR
        out[top & (np.abs(((x + 0.6) % 0.25) - 0.125) < 0.02)] = _BAND_BGR
    _paint_head(body, look, p, material, out)
    if look.dust > 0:
        blot = 0.5 + 0.5 * np.sin(x * 23.0 + np.sin(y * 31.0) * 2) * np.sin(z * 19.0 + x * 7.0)
        w = np.clip(look.dust * (0.4 + 0.6 * blot), 0.0, 0.9)[:, None]
        out = out * (1 - w) + _DUST_BGR * w
    return out


def _paint_head(body: Body3D, look: Look, p: F, material: NDArray[np.int8], out: F) -> None:
    """Hair, eyes, brows, nose and mouth on the head's surface.

    The hair covers the crown, the back and the sides down to the ears, with strands
    (a bald painted ball is what the first bodies had: from a low camera a lying
    person's head is mostly hair, and the person detector keys on the head). The eyes
    sit in darker sockets and the features are large enough to survive a few metres;
    measured on the rover's views (bench/sim_burial.py's bodies, 16 of them, 192 views),
    the person detector then scores 0.5 or more on 128 views instead of 117."""
    q = p - body.head_centre
    side = np.cross(body.face_axis, body.up_axis)
    k = body.scale
    fx = q @ body.face_axis / (0.1 * k)
    ux = q @ body.up_axis / (0.115 * k)
    sx = q @ side / (0.085 * k)
    head = (material == SKIN) & (np.linalg.norm(q, axis=1) < 0.17 * k)
    hairline = 0.45 - 0.5 * np.clip(-fx, 0.0, 1.0)  # lower towards the back of the head
    hair = head & ((ux > hairline) | (fx < -0.05)) & ~((fx > 0.55) & (ux < 0.55))
    strands = 0.75 + 0.25 * np.sin(sx * 40.0 + ux * 6.0) * np.sin(fx * 30.0)
    out[hair] = _bgr(look.hair_rgb) * strands[hair, None]
    face = head & ~hair & (fx > 0.3)
    for s in (-0.38, 0.38):
        socket = face & (((sx - s) / 0.24) ** 2 + ((ux - 0.14) / 0.14) ** 2 < 1)
        out[socket] *= 0.72
        eye = face & (((sx - s) / 0.19) ** 2 + ((ux - 0.15) / 0.09) ** 2 < 1)
        out[eye] = (200.0, 205.0, 210.0)
        iris = face & (((sx - s) / 0.09) ** 2 + ((ux - 0.15) / 0.09) ** 2 < 1)
        out[iris] = (25.0, 30.0, 40.0)
        brow = face & (np.abs(ux - 0.34) < 0.07) & (np.abs(sx - s) < 0.25)
        out[brow] = _bgr(look.hair_rgb) * 0.8
    mouth = face & (np.abs(ux + 0.5) < 0.08) & (np.abs(sx) < 0.32)
    out[mouth] = _bgr(look.skin_rgb) * 0.45 + np.array([20.0, 20.0, 70.0])
    nose = face & (np.abs(ux + 0.2) < 0.08) & (np.abs(sx) < 0.14)
    out[nose] *= 0.65


def footprint(body: Body3D) -> list[tuple[str, int, F]]:
    """Each solid's outline seen from straight above: (name, material, polygon (N, 2) NE)."""
    out = []
    t = np.linspace(0.0, 2 * math.pi, 24, endpoint=False)
    circle = np.column_stack([np.cos(t), np.sin(t)])
    for s in body.solids:
        if s.kind == "capsule":
            a, b = s.a[:2], s.b[:2]
            pts = np.vstack([a + circle * s.radius_m, b + circle * s.radius_m])
        else:
            m = s.axes[:2, :]  # the shadow of {A u : |u| <= 1} is {M u}, an ellipse
            u, sv, _ = np.linalg.svd(m)
            pts = s.a[:2] + (circle * sv) @ u.T
        hull = cv2.convexHull(pts.astype(np.float32)).reshape(-1, 2).astype(float)
        out.append((s.name, s.material, hull))
    return out
