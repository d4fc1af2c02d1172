"""Thermal device values to temperatures, and the checks every thermal frame passes.

The pure core of the thermal sources (no device, no file): each camera's raw words to
apparent temperatures in kelvin, the emissivity correction, and ``ThermalJudge``, which
refuses what is not evidence and says why in one line.

Raw words:
- FLIR Lepton 3.5 on a PureThermal board, radiometry (TLinear) on: Y16, one word per
  pixel in centi-kelvin. 160 x 122 frames carry two telemetry rows, which the
  PureThermal firmware sends as a footer: the last two rows are dropped.
- InfiRay P2 Pro / Topdon TC001: one YUYV frame of W x 2H, read with CONVERT_RGB off
  (OpenCV hands over the bytes: H x W x 2, or one flat row). Its top half is a
  false-colour picture, its bottom half the temperature, one little-endian word per
  pixel in kelvin x 64.

Emissivity: both cameras report the temperature of a black body that would send the
radiance they receive (a Lepton's default scene emissivity is 1.0; set an InfiRay's to
1.0 in its app, or it is corrected twice). The scene is taken as a grey body of
emissivity e that also reflects its surroundings, with radiance proportional to T^4
(Stefan-Boltzmann):

    T_object^4 = (T_apparent^4 - (1 - e) * T_reflected^4) / e

with T_reflected the frame's median apparent temperature (the room reflects itself).
Limits: the camera's band (8-14 um) is not a total radiance (near room temperature
the in-band radiance grows as about T^4.8, so the correction is a few percent off);
the air between camera and scene is not modelled (a few metres indoors); a reflective
surface mirroring something hotter than the room (a lamp) is wrong whatever the
correction. At e = 0.98 (skin) the correction is small: skin seen at 34 °C in a 20 °C
room is 34.3 °C.
"""

from __future__ import annotations

import logging

import numpy as np

from companion.sources.base import CameraError

log = logging.getLogger(__name__)

ZERO_C_K = 273.15
MIN_PLAUSIBLE_C = -40.0  # colder than any scene the rover works in
MAX_PLAUSIBLE_C = 400.0  # hotter than a Lepton's low-gain range tops out
TELEMETRY_ROWS = 2  # a Lepton's 160 x 122 frame: the last two rows are telemetry
# Consecutive frames whose temperatures differ by less than this on average (kelvin)
# are one frame repeated: a camera's noise alone moves them ~0.05 K (Lepton NETD), a
# frame frozen during the flat-field correction not at all.
FROZEN_MEAN_ABS_K = 0.01
# A live camera whose frames stay unusable this long has failed (a Lepton's flat-field
# correction freezes it for about a second).
GIVE_UP_AFTER_S = 3.0


def not_temperatures(image: object) -> str:
    """Why a picture is not one channel of 16-bit words ("" when it is)."""
    if not isinstance(image, np.ndarray) or image.size == 0 or image.ndim not in (2, 3):
        shape = tuple(image.shape) if isinstance(image, np.ndarray) else type(image).__name__
        return f"not a picture ({shape})"
    depth = {np.dtype(np.uint8): "8-bit", np.dtype(np.uint16): "16-bit"}.get(image.dtype)
    if depth is None:
        return f"{image.dtype} pixels where 16-bit temperatures were expected"
    if image.ndim == 3 and image.shape[2] >= 3:
        return (
            f"a false-colour ({image.shape[2]}-channel {depth}) picture where temperatures "
            "were expected"
        )
    if depth == "8-bit":
        return "an 8-bit picture where 16-bit temperatures were expected"
    if image.ndim == 3 and image.shape[2] != 1:
        return f"a {image.shape[2]}-channel 16-bit picture where one channel was expected"
    return ""


def lepton_kelvin(image: object, name: str, width_px: int, height_px: int) -> np.ndarray | str:
    """A Lepton's Y16 frame as apparent kelvin (float32 height x width), or why it is not
    one; CameraError naming both sizes for a frame of another size."""
    if why := not_temperatures(image):
        return f"{why} (is the board streaming Y16 with radiometry on?)"
    assert isinstance(image, np.ndarray)  # not_temperatures said so
    words = image.reshape(image.shape[:2])
    h, w = words.shape
    if (w, h) == (width_px, height_px + TELEMETRY_ROWS):
        words = words[:height_px]
    elif (w, h) != (width_px, height_px):
        raise CameraError(
            f"{name}: frames are {w}x{h}, [thermal] is configured for {width_px}x{height_px}"
        )
    return words.astype(np.float32) / np.float32(100.0)


def infiray_kelvin(image: object, name: str, width_px: int, height_px: int) -> np.ndarray | str:
    """The temperature half of an InfiRay's YUYV frame as apparent kelvin (float32
    height x width), or why it is not one; CameraError naming both sizes for a frame
    of another size."""
    full = (2 * height_px, width_px)
    wrong_size = (
        f"an InfiRay of [thermal] {width_px}x{height_px} sends {width_px}x{full[0]} "
        "(its picture above its temperatures)"
    )
    if (
        isinstance(image, np.ndarray)
        and image.dtype == np.uint8
        and image.ndim == 2
        and 1 in image.shape
    ):  # OpenCV handed over the buffer as one row of bytes
        if image.size != 2 * full[0] * full[1]:
            raise CameraError(f"{name}: frames are {image.size} bytes, {wrong_size} in YUYV")
        image = image.reshape(*full, 2)
    if (
        isinstance(image, np.ndarray)
        and image.dtype == np.uint8
        and image.ndim == 3
        and image.shape[2] == 2
    ):  # YUYV bytes: one little-endian word per pixel
        h, w = image.shape[:2]
        if (h, w) != full:
            raise CameraError(f"{name}: frames are {w}x{h}, {wrong_size}")
        below = np.ascontiguousarray(image[height_px:]).view("<u2")[..., 0]
        return below.astype(np.float32) / np.float32(64.0)
    if why := not_temperatures(image):
        return f"{why} (is CONVERT_RGB off?)"
    assert isinstance(image, np.ndarray)  # not_temperatures said so
    words = image.reshape(image.shape[:2])
    h, w = words.shape
    if (h, w) != full:
        raise CameraError(f"{name}: frames are {w}x{h}, {wrong_size}")
    return words[height_px:].astype(np.float32) / np.float32(64.0)


def object_temps_c(apparent_k: np.ndarray, emissivity: float) -> np.ndarray:
    """Apparent (black-body) kelvin to the scene's temperatures in °C (the module
    says which model and its limits); float32."""
    if emissivity >= 1.0:
        return (apparent_k - np.float32(ZERO_C_K)).astype(np.float32)
    a4 = np.square(np.square(apparent_k.astype(np.float32)))
    flat = a4.ravel()
    middle = flat.size // 2
    reflected4 = np.float32(np.partition(flat, middle)[middle])  # the median (np.median: 8x slower)
    e = np.float32(emissivity)
    obj4 = np.maximum((a4 - (np.float32(1.0) - e) * reflected4) / e, np.float32(0.0))
    temps_c: np.ndarray = np.sqrt(np.sqrt(obj4)) - np.float32(ZERO_C_K)
    return temps_c.astype(np.float32)


def _implausible(temps_c: np.ndarray) -> str:
    if not np.isfinite(temps_c).all():
        return "NaN or infinite temperatures"
    lo, hi = float(temps_c.min()), float(temps_c.max())
    if lo < MIN_PLAUSIBLE_C or hi > MAX_PLAUSIBLE_C:
        return (
            f"absurd temperatures ({lo:.1f} to {hi:.1f} °C, outside "
            f"{MIN_PLAUSIBLE_C:g} to {MAX_PLAUSIBLE_C:g})"
        )
    return ""


class ThermalJudge:
    """The checks every thermal frame passes after its words became kelvin.

    ``judge`` returns the frame's temperatures in °C (emissivity corrected), or None
    for a frame that is not evidence: NaN or absurd temperatures, or a frame frozen
    while the camera runs its flat-field correction (the same picture again). A run
    of skipped frames of one kind is said once in the log and held in ``status``
    until a usable frame comes; with ``give_up_after_s``, a run that lasts longer
    raises CameraError (a live camera is then reopened, its status saying why).
    """

    def __init__(self, name: str, emissivity: float, give_up_after_s: float | None) -> None:
        self.name = name
        self._emissivity = emissivity
        self._give_up_after_s = give_up_after_s
        self._previous_k: np.ndarray | None = None
        self._run_kind = ""  # the kind of skipped frames under way ("" = none)
        self._run_start_s = 0.0
        self.frames_skipped = 0
        self.status = ""  # one line: why frames are being skipped now ("" = they are not)

    def judge(self, apparent_k: np.ndarray, t_s: float) -> np.ndarray | None:
        kind, why, temps_c = self._assess(apparent_k)
        if temps_c is not None:
            if self._run_kind:
                log.info("%s: usable frames again (%s)", self.name, self._run_kind)
            self._run_kind, self.status = "", ""
            return temps_c
        self.frames_skipped += 1
        if kind != self._run_kind:
            self._run_kind, self._run_start_s, self.status = kind, t_s, why
            log.warning("%s: %s; skipped", self.name, why)
        lasted_s = t_s - self._run_start_s
        if self._give_up_after_s is not None and lasted_s > self._give_up_after_s:
            raise CameraError(f"{self.name}: {why}, for {lasted_s:.1f} s")
        return None

    def _assess(self, apparent_k: np.ndarray) -> tuple[str, str, np.ndarray | None]:
        if why := _implausible(apparent_k - np.float32(ZERO_C_K)):
            self._previous_k = None
            return "implausible", f"{why}: not radiometric values", None
        previous, self._previous_k = self._previous_k, apparent_k
        if (
            previous is not None
            and previous.shape == apparent_k.shape
            and float(np.mean(np.abs(apparent_k - previous))) < FROZEN_MEAN_ABS_K
        ):
            return "frozen", "frozen frames (flat-field correction): not evidence", None
        temps_c = object_temps_c(apparent_k, self._emissivity)
        if why := _implausible(temps_c):
            return "corrected", f"{why} after the emissivity correction", None
        return "", "", temps_c
