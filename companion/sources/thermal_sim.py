"""The simulated thermal camera: a TCP client of the simulator's thermal camera server.

Wire format, per frame, as the colour ``sim`` source's (``sim.py``): a 4-byte
big-endian length N of what follows, an 8-byte big-endian capture time in Unix
microseconds, then N - 8 bytes of a 16-bit single-channel PNG whose words are
centi-kelvin (°C = value / 100 - 273.15), as a recorded thermal frames folder holds.
The words are what the simulated Lepton reports (a black body's temperature, as a
real one with radiometry on): the configured emissivity is applied as for a Lepton.

A closed connection or a length that cannot be a frame is CameraError (the
ReopeningThermalSource reconnects with backoff); a payload that does not decode is
skipped and counted (``frames_corrupt``); an 8-bit or false-colour picture, or a
frame of another size than configured, is CameraError saying so in one line; frames
that are not evidence (frozen by the flat-field correction, absurd values) are
skipped by ``ThermalJudge`` as a Lepton's are, and fail the camera when they last.
"""

from __future__ import annotations

import cv2
import numpy as np

from companion.sources.base import CameraError, _Grabbed, truncation
from companion.sources.sim import SimStream
from companion.sources.thermal import ThermalFrame
from companion.sources.thermal_raw import GIVE_UP_AFTER_S, ThermalJudge, not_temperatures


class ThermalSimSource(SimStream[ThermalFrame]):
    """Thermal frames from the simulator at host:port; ``read`` returns ThermalFrames."""

    def __init__(
        self, host: str, port: int, width_px: int, height_px: int, emissivity: float
    ) -> None:
        self._size = (width_px, height_px)
        self._judge = ThermalJudge(f"sim:{host}:{port}", emissivity, GIVE_UP_AFTER_S)
        super().__init__(host, port)

    @property
    def status(self) -> str:
        """One line: what is wrong with the frames now ("ok" when nothing)."""
        return self._judge.status or "ok"

    @property
    def frames_skipped(self) -> int:
        return self._judge.frames_skipped

    def _decode(self, payload: bytes) -> np.ndarray | None:
        """The frame's apparent kelvin (float32 H x W); None for a payload that does
        not decode; CameraError for one that is not temperatures of the right size."""
        if truncation(payload) is not None:
            return None
        try:
            image = cv2.imdecode(np.frombuffer(payload, np.uint8), cv2.IMREAD_UNCHANGED)
        except cv2.error:
            image = None
        if image is None or not image.size:
            return None
        if why := not_temperatures(image):
            raise CameraError(f"{self.name}: {why}")
        words = image.reshape(image.shape[:2])
        h, w = words.shape
        if (w, h) != self._size:
            raise CameraError(
                f"{self.name}: frames are {w}x{h}, [thermal] is configured for "
                f"{self._size[0]}x{self._size[1]}"
            )
        kelvin: np.ndarray = words.astype(np.float32) / np.float32(100.0)
        return kelvin

    def _frame(self, decoded: np.ndarray, grabbed: _Grabbed[bytes]) -> ThermalFrame | None:
        temps_c = self._judge.judge(decoded, grabbed.t_mono_s)
        if temps_c is None:
            return None  # not evidence (the judge said why, once)
        return ThermalFrame(temps_c, grabbed.t_mono_s, grabbed.t_unix_s, grabbed.index)
