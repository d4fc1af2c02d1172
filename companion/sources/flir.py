"""FLIR radiometric JPEGs ("R-JPEG"): the sensor's raw counts turned into °C.

A handheld FLIR camera saves, beside its false-colour picture, the sensor's raw
16-bit counts (``RawThermalImage``, a PNG or a TIFF inside the JPEG's APP1 FFF
segments) and the constants of its calibration (``PlanckR1``, ``PlanckR2``,
``PlanckB``, ``PlanckF``, ``PlanckO``) and of the scene the photographer set
(``Emissivity``, ``ObjectDistance``, ``ReflectedApparentTemperature``,
``AtmosphericTemperature``, ``RelativeHumidity``, the IR window's temperature and
transmission). exiftool (Debian ``libimage-exiftool-perl``) reads both; it runs as
a subprocess, once with ``-j`` for the constants and once with ``-b`` for the raw
image.

The counts become temperatures by FLIR's published radiometric model (as flirpy,
Thermimage and IRimage implement it): the atmosphere's transmission from distance
and humidity, then the reflected, atmospheric and window radiation subtracted in
raw units, then ``T = B / ln(R1 / (R2 (raw + O)) + F)``.

A FLIR PNG raw image stores its 16-bit words little-endian inside a PNG (which
means big-endian): they are swapped; a TIFF says its own byte order. The decoded
counts' median is checked against the ``RawValueMedian`` the camera wrote, so a
wrong byte order cannot pass as a picture of plausible temperatures.
"""

from __future__ import annotations

import json
import math
import shutil
import subprocess
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from companion.errors import CompanionError

EXIFTOOL = "exiftool"
EXIFTOOL_TIMEOUT_S = 30.0
# Temperatures a FLIR camera can report at all; anything outside is a broken file.
MIN_PLAUSIBLE_C = -60.0
MAX_PLAUSIBLE_C = 2100.0
_CONSTANTS = (
    "RawThermalImageType",
    "RawThermalImageWidth",
    "RawThermalImageHeight",
    "RawValueMedian",
    "PlanckR1",
    "PlanckR2",
    "PlanckB",
    "PlanckF",
    "PlanckO",
    "Emissivity",
    "ObjectDistance",
    "ReflectedApparentTemperature",
    "AtmosphericTemperature",
    "RelativeHumidity",
    "IRWindowTemperature",
    "IRWindowTransmission",
    "Model",
)
# FLIR's atmospheric transmission constants (the same in every camera's metadata
# that carries them; the model's published defaults).
_ATA1, _ATA2, _ATB1, _ATB2, _ATX = 0.006569, 0.01262, -0.002276, -0.00667, 1.9


class FlirError(CompanionError):
    """A FLIR radiometric JPEG that cannot be read; the message names it and says why."""


class NotRadiometric(FlirError):
    """The file is a picture without raw thermal data (false colour only)."""


class ExiftoolMissing(FlirError):
    """exiftool is not installed."""


@dataclass(frozen=True)
class FlirCalibration:
    """The constants of one photo: the camera's Planck curve and the scene's settings."""

    planck_r1: float
    planck_r2: float
    planck_b: float
    planck_f: float
    planck_o: float
    emissivity: float
    object_distance_m: float
    reflected_c: float
    atmosphere_c: float
    humidity: float  # relative, 0..1
    window_c: float
    window_transmission: float

    def check(self, where: str) -> None:
        """FlirError naming the first absurd value."""
        for name, value in vars(self).items():
            if not math.isfinite(value):
                raise FlirError(f"{where}: {name} = {value} is not a finite number")
        if self.planck_r1 <= 0.0 or self.planck_r2 <= 0.0 or self.planck_b <= 0.0:
            raise FlirError(
                f"{where}: Planck constants R1 = {self.planck_r1}, R2 = {self.planck_r2}, "
                f"B = {self.planck_b} must be > 0"
            )
        if not 0.0 <= self.planck_f <= 10.0:
            raise FlirError(f"{where}: PlanckF = {self.planck_f} outside 0..10")
        if not 0.05 <= self.emissivity <= 1.0:
            raise FlirError(f"{where}: Emissivity = {self.emissivity} outside 0.05..1")
        if not 0.0 <= self.object_distance_m <= 10000.0:
            raise FlirError(
                f"{where}: ObjectDistance = {self.object_distance_m} m outside 0..10 km"
            )
        for name, value in (
            ("ReflectedApparentTemperature", self.reflected_c),
            ("AtmosphericTemperature", self.atmosphere_c),
            ("IRWindowTemperature", self.window_c),
        ):
            if not -100.0 <= value <= 1000.0:
                raise FlirError(f"{where}: {name} = {value} °C outside -100..1000")
        if not 0.0 <= self.humidity <= 1.0:
            raise FlirError(f"{where}: RelativeHumidity = {100 * self.humidity} % outside 0..100")
        if not 0.01 <= self.window_transmission <= 1.0:
            raise FlirError(
                f"{where}: IRWindowTransmission = {self.window_transmission} outside 0.01..1"
            )


@dataclass(frozen=True)
class FlirImage:
    """Temperatures of a FLIR radiometric JPEG (float32 °C at the raw image's size)."""

    temps_c: np.ndarray
    calibration: FlirCalibration
    model: str


def _exiftool(args: list[str], path: Path) -> bytes:
    exe = shutil.which(EXIFTOOL)
    if exe is None:
        raise ExiftoolMissing(
            f"{path}: exiftool is not installed (Debian: apt install libimage-exiftool-perl)"
        )
    try:
        done = subprocess.run(
            [exe, *args, "--", str(path)],
            capture_output=True,
            timeout=EXIFTOOL_TIMEOUT_S,
            check=False,
        )
    except subprocess.TimeoutExpired:
        raise FlirError(f"{path}: exiftool took more than {EXIFTOOL_TIMEOUT_S:.0f} s") from None
    except OSError as exc:
        raise ExiftoolMissing(f"{path}: cannot run exiftool: {exc.strerror}") from None
    if done.returncode != 0 and not done.stdout:
        why = done.stderr.decode("utf-8", "replace").strip().splitlines()
        raise FlirError(f"{path}: exiftool cannot read it: {why[-1] if why else 'no reason given'}")
    return done.stdout


def _number(tags: dict[str, object], name: str, where: Path) -> float:
    value = tags.get(name)
    if isinstance(value, bool) or not isinstance(value, int | float | str):
        raise FlirError(f"{where}: no {name} in its FLIR metadata")
    try:
        return float(str(value).split()[0])  # "1.00 m", "21.0 C", "50.0 %" with -n: numbers
    except (ValueError, IndexError):
        raise FlirError(f"{where}: {name} = {value!r} is not a number") from None


def read_tags(path: Path) -> dict[str, object]:
    """The FLIR tags of ``path`` as exiftool gives them (numbers with ``-n``)."""
    out = _exiftool(["-j", "-n", *(f"-{t}" for t in _CONSTANTS)], path)
    try:
        docs = json.loads(out.decode("utf-8", "replace"))
        tags = docs[0]
    except (ValueError, IndexError, KeyError):
        raise FlirError(f"{path}: exiftool gave no metadata for it") from None
    if not isinstance(tags, dict):
        raise FlirError(f"{path}: exiftool gave no metadata for it")
    return tags


def calibration_of(tags: dict[str, object], path: Path) -> FlirCalibration:
    humidity = _number(tags, "RelativeHumidity", path) if "RelativeHumidity" in tags else 50.0
    cal = FlirCalibration(
        planck_r1=_number(tags, "PlanckR1", path),
        planck_r2=_number(tags, "PlanckR2", path),
        planck_b=_number(tags, "PlanckB", path),
        planck_f=_number(tags, "PlanckF", path),
        planck_o=_number(tags, "PlanckO", path),
        emissivity=_number(tags, "Emissivity", path),
        object_distance_m=_number(tags, "ObjectDistance", path),
        reflected_c=_number(tags, "ReflectedApparentTemperature", path),
        atmosphere_c=_number(tags, "AtmosphericTemperature", path),
        # exiftool gives a fraction with -n in recent versions, a percentage in others
        humidity=humidity / 100.0 if humidity > 1.0 else humidity,
        window_c=_number(tags, "IRWindowTemperature", path)
        if "IRWindowTemperature" in tags
        else 20.0,
        window_transmission=(
            _number(tags, "IRWindowTransmission", path) if "IRWindowTransmission" in tags else 1.0
        ),
    )
    cal.check(str(path))
    return cal


def decode_raw(data: bytes, kind: str, path: Path) -> np.ndarray:
    """The raw counts (uint16 H x W) of exiftool's ``RawThermalImage`` bytes."""
    if not data:
        raise FlirError(f"{path}: its RawThermalImage is empty")
    raw = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if raw is None:
        raise FlirError(f"{path}: its RawThermalImage ({kind}) does not decode")
    if raw.dtype != np.uint16 or raw.ndim != 2:
        raise FlirError(
            f"{path}: its RawThermalImage is {raw.dtype} {tuple(raw.shape)}, not 16-bit single-channel"
        )
    if kind.upper() == "PNG":
        raw = raw.byteswap()  # FLIR writes little-endian words into a big-endian PNG
    return raw


def raw_to_celsius(raw: np.ndarray, cal: FlirCalibration) -> np.ndarray:
    """FLIR's radiometric model: raw counts (any shape) -> object temperature °C."""
    r1, r2, b, f, o = cal.planck_r1, cal.planck_r2, cal.planck_b, cal.planck_f, cal.planck_o
    e, irt = cal.emissivity, cal.window_transmission
    t_atm = cal.atmosphere_c
    h2o = cal.humidity * math.exp(
        1.5587 + 0.06939 * t_atm - 0.00027816 * t_atm**2 + 0.00000068455 * t_atm**3
    )
    half = math.sqrt(cal.object_distance_m / 2.0)
    tau = _ATX * math.exp(-half * (_ATA1 + _ATB1 * math.sqrt(h2o))) + (1.0 - _ATX) * math.exp(
        -half * (_ATA2 + _ATB2 * math.sqrt(h2o))
    )

    def radiance(t_c: float) -> float:  # a black body at t_c in raw counts
        return r1 / (r2 * (math.exp(b / (t_c + 273.15)) - f)) - o

    refl = (1.0 - e) / e * radiance(cal.reflected_c)
    atm1 = (1.0 - tau) / e / tau * radiance(t_atm)
    window = (1.0 - irt) / e / tau / irt * radiance(cal.window_c)
    atm2 = (1.0 - tau) / e / tau / irt / tau * radiance(t_atm)
    obj = raw.astype(np.float64) / e / tau / irt / tau - atm1 - atm2 - window - refl
    with np.errstate(divide="ignore", invalid="ignore"):
        t_k = b / np.log(r1 / (r2 * (obj + o)) + f)
    return t_k - 273.15


def read_flir(path: Path) -> FlirImage:
    """Temperatures of a FLIR radiometric JPEG; FlirError (one line) if it is not one."""
    if not path.is_file():
        raise FlirError(f"{path}: no such file")
    tags = read_tags(path)
    kind = tags.get("RawThermalImageType")
    if not isinstance(kind, str) or kind.upper() not in ("PNG", "TIFF"):
        if any(k in tags for k in ("PlanckR1", "RawThermalImageWidth")):
            raise FlirError(f"{path}: FLIR metadata without a PNG or TIFF raw image ({kind!r})")
        raise NotRadiometric(
            f"{path}: not a FLIR radiometric JPEG (no raw thermal image: a false-colour "
            "picture has no temperatures)"
        )
    cal = calibration_of(tags, path)
    raw = decode_raw(_exiftool(["-b", "-RawThermalImage"], path), kind, path)
    width, height = tags.get("RawThermalImageWidth"), tags.get("RawThermalImageHeight")
    if (width, height) != (raw.shape[1], raw.shape[0]):
        raise FlirError(
            f"{path}: raw image is {raw.shape[1]}x{raw.shape[0]}, its metadata says {width}x{height}"
        )
    median = tags.get("RawValueMedian")
    if isinstance(median, int | float) and median > 0:
        got = float(np.median(raw))
        if abs(got - median) > max(0.25 * median, 500.0):
            raise FlirError(
                f"{path}: raw counts' median {got:.0f} far from the {median} the camera wrote "
                "(wrong byte order or a damaged raw image)"
            )
    temps = raw_to_celsius(raw, cal)
    finite = np.isfinite(temps)
    if not finite.all():
        raise FlirError(
            f"{path}: {int((~finite).sum())} of {temps.size} raw counts give no temperature "
            "(below the Planck curve's offset)"
        )
    lo, hi = float(temps.min()), float(temps.max())
    if lo < MIN_PLAUSIBLE_C or hi > MAX_PLAUSIBLE_C:
        raise FlirError(
            f"{path}: temperatures {lo:.0f}..{hi:.0f} °C outside what a FLIR camera measures "
            f"({MIN_PLAUSIBLE_C:.0f}..{MAX_PLAUSIBLE_C:.0f})"
        )
    model = tags.get("Model")
    return FlirImage(temps.astype(np.float32), cal, model if isinstance(model, str) else "")
