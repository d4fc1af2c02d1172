"""Opening the link a LinkSpec names, and keeping it open.

``ReconnectingLink`` hides breakage from its user: while the transport is down,
``read`` waits (at most ``timeout_s``) for the next reopening attempt and returns
``b""``; writes are dropped and counted. Attempts back off from
``initial_backoff_s``, doubling, capped at ``max_backoff_s``; a serial device that
comes back is therefore used again within ``max_backoff_s`` plus its open time.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

from mavlink_io.errors import LinkError
from mavlink_io.link import Link, LinkCounters
from mavlink_io.linkspec import LinkSpec
from mavlink_io.netlinks import TcpInLink, TcpLink, UdpInLink, UdpOutLink
from mavlink_io.seriallink import SerialLink

log = logging.getLogger(__name__)


def open_link(spec: LinkSpec) -> SerialLink | UdpInLink | UdpOutLink | TcpLink | TcpInLink:
    """Open the transport a LinkSpec names; raises LinkError when it cannot."""
    if spec.kind == "serial":
        return SerialLink(spec.device, spec.baud)
    if spec.kind == "udpin":
        return UdpInLink(spec.host, spec.port)
    if spec.kind == "udpout":
        return UdpOutLink(spec.host, spec.port)
    if spec.kind == "tcp":
        return TcpLink(spec.host, spec.port)
    if spec.kind == "tcpin":
        return TcpInLink(spec.host, spec.port)
    raise LinkError(f"unknown link kind {spec.kind!r}")  # pragma: no cover - LinkKind is closed


class ReconnectingLink:
    """A link that survives its transport: reopens with exponential backoff.

    ``read`` returns b"" while disconnected (after waiting for the next attempt, at
    most ``timeout_s``); ``write`` drops and counts. ``connected`` says whether a
    transport is open. Opening happens in ``read``, i.e. in the reader's thread.
    """

    def __init__(
        self,
        spec: LinkSpec,
        *,
        max_backoff_s: float = 1.0,
        initial_backoff_s: float = 0.05,
        opener: Callable[[LinkSpec], Link] = open_link,
    ) -> None:
        if initial_backoff_s <= 0 or max_backoff_s < initial_backoff_s:
            raise ValueError(
                f"backoff: need 0 < initial_backoff_s ({initial_backoff_s}) "
                f"<= max_backoff_s ({max_backoff_s})"
            )
        self.spec = spec
        self.name = str(spec)
        self.counters = LinkCounters()
        self._opener = opener
        self._initial_backoff_s = initial_backoff_s
        self._max_backoff_s = max_backoff_s
        self._backoff_s = initial_backoff_s
        self._next_attempt_mono_s = 0.0
        self._lock = threading.Lock()
        self._inner: Link | None = None
        self._ever_connected = False
        self._closed = threading.Event()
        self._last_error = ""
        self._try_open()

    @property
    def connected(self) -> bool:
        return self._inner is not None

    @property
    def inner(self) -> Link | None:
        """The open transport, or None while disconnected."""
        return self._inner

    @property
    def local_address(self) -> tuple[str, int] | None:
        """The inner link's bound address (udpin/tcpin), or None."""
        inner = self._inner
        address = getattr(inner, "local_address", None)
        return address if isinstance(address, tuple) else None

    def _try_open(self) -> None:
        if self._closed.is_set():
            return
        try:
            inner = self._opener(self.spec)
        except LinkError as exc:
            self.counters.open_failures += 1
            if str(exc) != self._last_error:
                log.warning("%s: %s; retrying every <= %.1f s", self.name, exc, self._max_backoff_s)
                self._last_error = str(exc)
            self._next_attempt_mono_s = time.monotonic() + self._backoff_s
            self._backoff_s = min(self._backoff_s * 2.0, self._max_backoff_s)
            return
        with self._lock:
            if self._closed.is_set():
                inner.close()
                return
            self._inner = inner
        if self._ever_connected:
            self.counters.reconnects += 1
            log.info("%s: reopened", self.name)
        self._ever_connected = True
        self._last_error = ""

    def _mark_broken(self, inner: Link, exc: LinkError) -> None:
        with self._lock:
            if self._inner is not inner:
                return
            self._inner = None
        inner.close()
        self.counters.breaks += 1
        log.warning("%s: link broken (%s); reopening", self.name, exc)
        self._last_error = str(exc)
        self._next_attempt_mono_s = time.monotonic() + self._backoff_s
        self._backoff_s = min(self._backoff_s * 2.0, self._max_backoff_s)

    def read(self, timeout_s: float) -> bytes:
        if self._closed.is_set():
            raise LinkError(f"{self.name}: closed")
        inner = self._inner
        if inner is None:
            wait_s = self._next_attempt_mono_s - time.monotonic()
            if wait_s > timeout_s:
                self._closed.wait(max(0.0, timeout_s))
                return b""
            if wait_s > 0:
                self._closed.wait(wait_s)
            self._try_open()
            return b""
        try:
            data = inner.read(timeout_s)
        except LinkError as exc:
            if self._closed.is_set():
                raise
            self._mark_broken(inner, exc)
            return b""
        if data:
            self._backoff_s = self._initial_backoff_s  # healthy again: fast retries next time
            self.counters.bytes_read += len(data)
        return data

    def write(self, data: bytes) -> None:
        if self._closed.is_set():
            raise LinkError(f"{self.name}: closed")
        inner = self._inner
        if inner is None:
            self.counters.writes_dropped += 1
            return
        try:
            inner.write(data)
        except LinkError as exc:
            self.counters.writes_dropped += 1
            self._mark_broken(inner, exc)
            return
        self.counters.bytes_written += len(data)

    def close(self) -> None:
        self._closed.set()
        with self._lock:
            inner, self._inner = self._inner, None
        if inner is not None:
            inner.close()
