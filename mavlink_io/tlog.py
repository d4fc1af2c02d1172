"""Telemetry logs in the standard .tlog format, and a reader that survives corruption.

A .tlog is a sequence of records: an 8-byte big-endian timestamp (microseconds since
the Unix epoch) followed by one raw MAVLink packet. pymavlink's ``mavlogdump.py`` and
``mavutil.mavlink_connection(path)``, MAVProxy and Mission Planner read it.

``TlogWriter`` records every packet received and sent. Files are named
``rescue-YYYYmmdd-HHMMSS-NNN.tlog`` and rotate when the next record would pass
``max_bytes``. Any OSError while writing (a full disk, ENOSPC; a removed USB
stick, EIO) stops the recording with one warning; the program goes on.
"""

from __future__ import annotations

import logging
import struct
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import BinaryIO

from mavlink_io.codec import Codec, MavMessage
from mavlink_io.errors import TlogError

log = logging.getLogger(__name__)

_STAMP = struct.Struct(">Q")
_FLUSH_PERIOD_S = 1.0
# Timestamps a record may plausibly carry: 2001 .. 2100, in microseconds.
_MIN_PLAUSIBLE_US = 978_307_200 * 1_000_000
_MAX_PLAUSIBLE_US = 4_102_444_800 * 1_000_000


class TlogWriter:
    """Writes packets to size-rotated .tlog files. Thread-safe; never raises on write."""

    def __init__(self, directory: Path, max_bytes: int, prefix: str = "rescue") -> None:
        if max_bytes < 1024:
            raise TlogError(f"tlog max_bytes must be >= 1024, got {max_bytes}")
        self.directory = Path(directory)
        self.max_bytes = max_bytes
        self._prefix = prefix
        self._lock = threading.Lock()
        self._file: BinaryIO | None = None
        self._size = 0
        self._index = 0
        self._last_flush_s = time.monotonic()
        self.recording = True
        self.error: str | None = None
        self.records = 0
        self.files: list[Path] = []

    @property
    def path(self) -> Path | None:
        """The file being written, or None before the first record or after a stop."""
        return self.files[-1] if self._file is not None else None

    def write(self, packet: bytes, t_unix_s: float | None = None) -> None:
        """Append one packet, stamped with ``t_unix_s`` (default: now)."""
        if not self.recording:
            return
        stamp = _STAMP.pack(max(0, round((time.time() if t_unix_s is None else t_unix_s) * 1e6)))
        with self._lock:
            if not self.recording:
                return
            try:
                out = self._file
                if out is None or self._size + len(stamp) + len(packet) > self.max_bytes:
                    out = self._rotate()
                out.write(stamp + packet)
                self._size += len(stamp) + len(packet)
                self.records += 1
                now = time.monotonic()
                if now - self._last_flush_s >= _FLUSH_PERIOD_S:
                    out.flush()
                    self._last_flush_s = now
            except OSError as exc:
                self._stop(exc)

    def _rotate(self) -> BinaryIO:
        if self._file is not None:
            self._file.close()
            self._file = None
        self.directory.mkdir(parents=True, exist_ok=True)
        self._index += 1
        name = f"{self._prefix}-{time.strftime('%Y%m%d-%H%M%S')}-{self._index:03d}.tlog"
        path = self.directory / name
        out = open(path, "ab")  # noqa: SIM115 - kept open across writes
        self._file = out
        self._size = 0
        self.files.append(path)
        log.info("recording telemetry to %s", path)
        return out

    def _stop(self, exc: OSError) -> None:
        self.recording = False
        self.error = f"{exc.strerror or exc} ({self.directory})"
        log.warning("telemetry recording stopped: %s", self.error)
        if self._file is not None:
            try:
                self._file.close()
            except OSError:
                log.debug("closing the tlog after a write error failed too")
            self._file = None

    def flush(self) -> None:
        with self._lock:
            if self._file is not None:
                try:
                    self._file.flush()
                except OSError as exc:
                    self._stop(exc)

    def close(self) -> None:
        """Flush and close; safe twice. Later writes are ignored."""
        with self._lock:
            self.recording = False
            if self._file is not None:
                try:
                    self._file.close()
                except OSError as exc:
                    log.warning("closing the tlog failed: %s", exc.strerror or exc)
                self._file = None


def read_tlog(path: Path, codec: Codec | None = None) -> Iterator[tuple[float, MavMessage]]:
    """(t_unix_s, message) for every valid record; corrupt bytes are skipped.

    A record is believed when its timestamp is plausible and a frame starts right
    after it that decodes (CRC checked); otherwise the reader moves on one byte.
    Messages of IDs the dialect does not know are skipped. Raises TlogError only
    when the file cannot be read at all.
    """
    try:
        data = Path(path).read_bytes()
    except OSError as exc:
        raise TlogError(f"cannot read tlog {path}: {exc.strerror or exc}") from None
    dec = codec if codec is not None else Codec(255, 190)
    pos = 0
    end = len(data)
    while pos + 8 + 8 <= end:
        (usec,) = _STAMP.unpack_from(data, pos)
        marker = data[pos + 8]
        if _MIN_PLAUSIBLE_US <= usec <= _MAX_PLAUSIBLE_US and marker in (0xFD, 0xFE):
            length = _frame_length(data, pos + 8)
            if pos + 8 + length <= end:
                msg = dec.decode_frame(data[pos + 8 : pos + 8 + length])
                if msg is not None:
                    yield usec / 1e6, msg
                    pos += 8 + length
                    continue
        pos += 1


def _frame_length(data: bytes, start: int) -> int:
    if data[start] == 0xFD:
        signed = data[start + 2] & 0x01
        return 10 + data[start + 1] + 2 + (13 if signed else 0)
    return 6 + data[start + 1] + 2
