"""Thermal cameras: frames of temperatures, one interface for every kind of source.

A thermal frame is a float32 H x W array of temperatures in degrees Celsius, every
value finite, with its capture time on both clocks (as a colour ``Frame``).

=========================  ==========================================================
``[thermal] source``       camera
=========================  ==========================================================
``lepton``                 the first FLIR Lepton on a PureThermal board, found by its
                           V4L2 card name (``/sys/class/video4linux/*/name``)
``lepton:/dev/videoN``     that PureThermal board (UVC, Y16 centi-kelvin, TLinear)
``infiray:/dev/videoN``    an InfiRay P2 Pro / Topdon TC001 (YUYV, picture above,
                           kelvin x 64 below)
``frames:DIR``             recorded ``<unix_time_us>.png`` (16-bit centi-kelvin)
``sim:HOST:PORT``          the simulator's thermal camera (TCP, see ``thermal_sim``)
=========================  ==========================================================

The modules beside this one: ``thermal_raw`` (device values to temperatures, the
emissivity correction, and the checks every frame passes), ``thermal_live`` (the two
USB cameras), ``thermal_folder`` (the recorded folder and its writer),
``thermal_sim`` (the simulator's camera server) and ``thermal_open`` (``open_thermal``: the configured camera, reopened with backoff).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal, Protocol

import numpy as np

from companion.sources.base import CameraError


@dataclass(frozen=True)
class ThermalFrame:
    """One thermal picture: temperatures with their capture time on both clocks."""

    temps_c: np.ndarray = field(repr=False)  # float32 H x W, degrees Celsius, finite
    t_mono_s: float  # capture time on the companion's time.monotonic()
    t_unix_s: float  # capture time on the wall clock
    index: int  # frame number from the source

    def __post_init__(self) -> None:
        t = self.temps_c
        if t.dtype != np.float32 or t.ndim != 2 or t.size == 0:
            raise ValueError(
                f"ThermalFrame.temps_c must be float32 H x W, got {t.dtype} {tuple(t.shape)}"
            )


class ThermalSource(Protocol):
    """A thermal camera. ``read`` raises CameraTimeout, CameraError or EndOfStream."""

    name: str

    def read(self, timeout_s: float) -> ThermalFrame: ...

    def close(self) -> None: ...


ThermalKind = Literal["lepton", "infiray", "frames", "sim"]


@dataclass(frozen=True)
class ThermalSpec:
    kind: ThermalKind
    target: str  # "/dev/videoN", a folder, a host, or "" for the first PureThermal found
    port: int = 0  # sim only


def parse_thermal_source(source: str) -> ThermalSpec:
    """Understand a ``[thermal] source`` string; CameraError names what is wrong."""
    text = source.strip()
    if text == "lepton":
        return ThermalSpec("lepton", "")
    for kind in ("lepton", "infiray"):
        prefix = f"{kind}:"
        if text.startswith(prefix):
            device = text[len(prefix) :]
            if not (device.startswith("/dev/video") and device[10:].isdigit()):
                raise CameraError(f"source {source!r}: expected {kind}:/dev/videoN")
            return ThermalSpec("lepton" if kind == "lepton" else "infiray", device)
    if text.startswith("frames:") and text[7:]:
        return ThermalSpec("frames", text[7:])
    if text.startswith("sim:"):
        host, sep, port = text[4:].rpartition(":")
        if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
            raise CameraError(f"source {source!r}: expected sim:HOST:PORT (port 1..65535)")
        return ThermalSpec("sim", host, int(port))
    raise CameraError(
        f"source {source!r}: not understood; use lepton, lepton:/dev/videoN, "
        "infiray:/dev/videoN, frames:DIR or sim:HOST:PORT"
    )
