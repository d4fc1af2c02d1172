"""A serial port as a link (pyserial; the interface is mavlink_io.link.Link)."""

from __future__ import annotations

import logging
import os
import threading

import serial

from mavlink_io.errors import LinkError
from mavlink_io.link import READ_CHUNK_BYTES, LinkCounters, wait_readable

log = logging.getLogger(__name__)

# A stalled UART (no reader, flow control): a write waits this long at most, then drops.
_SERIAL_WRITE_TIMEOUT_S = 0.5


class SerialLink:
    """A serial port through pyserial; reads select() on its file descriptor."""

    def __init__(self, device: str, baud: int) -> None:
        self.name = f"serial:{device}:{baud}"
        self.counters = LinkCounters()
        self._write_lock = threading.Lock()
        try:
            self._port = serial.Serial(
                port=device,
                baudrate=baud,
                timeout=0,
                write_timeout=_SERIAL_WRITE_TIMEOUT_S,
                exclusive=True,
            )
        except (serial.SerialException, OSError, ValueError) as exc:
            raise LinkError(f"{self.name}: cannot open: {exc}") from exc
        fd = self._port.fileno()
        self._fd: int | None = fd

    def read(self, timeout_s: float) -> bytes:
        fd = self._fd
        if fd is None:
            raise LinkError(f"{self.name}: closed")
        if not wait_readable(fd, timeout_s):
            return b""
        try:
            data = os.read(fd, READ_CHUNK_BYTES)
        except BlockingIOError:
            return b""
        except OSError as exc:  # EIO/ENXIO: the device went away (unplugged, pty closed)
            raise LinkError(f"{self.name}: read failed: {exc}") from exc
        if not data:  # readable but empty: end of file, the device is gone
            raise LinkError(f"{self.name}: device disconnected")
        self.counters.bytes_read += len(data)
        return data

    def write(self, data: bytes) -> None:
        if self._fd is None:
            raise LinkError(f"{self.name}: closed")
        with self._write_lock:
            try:
                self._port.write(data)
            except serial.SerialTimeoutException:
                self.counters.writes_dropped += 1
                log.debug("%s: write stalled, %d bytes dropped", self.name, len(data))
                return
            except (serial.SerialException, OSError, TypeError) as exc:
                raise LinkError(f"{self.name}: write failed: {exc}") from exc
        self.counters.bytes_written += len(data)

    def close(self) -> None:
        if self._fd is None:
            return
        self._fd = None
        try:
            self._port.close()
        except (serial.SerialException, OSError) as exc:  # closing a vanished device
            log.debug("%s: close: %s", self.name, exc)
