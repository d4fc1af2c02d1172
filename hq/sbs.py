"""The victims as ADS-B traffic for a stock QGroundControl: an SBS-1 (BaseStation) TCP server.

QGC's ADS-B layer connects, as a client, to an SBS-1 server (its "ADSB Server"
setting: host and port, default 127.0.0.1:30003, the port dump1090 serves) and
draws every track it hears whichever vehicle is active. rescue-hq is that server:
one track per confirmed HQ victim (every robot's, merged), placed at its latitude
and longitude, labelled with a callsign that says urgency and HQ ID (``CRIT07``,
``MED12``, ``LIGHT03``), with the emergency flag set for CRITICAL (QGC draws an
alert icon).

What QGC reads (src/ADSB, read in its source): a line starting ``MSG``, the
message type at character 4, fields split on ``,`` (0-based below); the ICAO
address in field 4 as hex. ``MSG,3`` (airborne position) creates a track: the
altitude in feet (an integer) in field 11, latitude 14, longitude 15, and the
emergency flag 19, which QGC takes as "alert" when it reads exactly ``1``.
``MSG,1`` (identification) gives the callsign in field 10; QGC ignores it for a
track it has not created yet, so each refresh sends MSG,3 before MSG,1 (older QGC
releases read the callsign from MSG,3's field 10 too, so it is there as well).
Lines end in CRLF, like dump1090's. QGC drops a track it has not heard of for its
expiry (120 s in current releases, 25 s in older ones): every live track is sent
again every ``refresh_s`` (1 s) and at once when it changes.

SBS-1 has no "remove" message. A victim the operator marks rescued or a false
alarm (or a robot reports so) gets one last update at once, relabelled ``RESC07`` /
``FALSE07`` with the emergency flag cleared, and is then no longer refreshed, so QGC
drops it at its expiry. A victim without latitude/longitude (no EKF origin for its
robot and no ``--origin``) cannot be placed and is not sent; ``rescue-hq list``
shows it.

The server runs one thread (``hq-sbs``) over a selector (epoll: a client's file
descriptor may be above 1023, as with many console connections open): it accepts
clients and writes to each through its own output buffer, as much as the socket
takes, the rest when the socket is writable again, so a snapshot of hundreds of
tracks reaches a client on a slow or small-window link. A client whose buffer
grows beyond ``max_client_buffer_bytes`` (several whole refreshes: it does not
read) is dropped with a log line; it reconnects and gets every track again. The
HQ's main thread calls ``publish`` with the current victims; it never blocks:
changes are kept per track and the thread is woken by one byte on a non-blocking
socket pair, only when no wake-up is pending. Should the thread fail, it logs the
error (the first with its traceback), closes its clients, and serves again a second
later; ``failure`` says so for the HQ's status line.
"""

from __future__ import annotations

import contextlib
import logging
import selectors
import socket
import threading
import time
from collections.abc import Iterable
from dataclasses import dataclass, field
from datetime import UTC, datetime

from fusion.types import TrackState, Urgency
from hq.view import HqVictim
from mavlink_io.statustext import RETIRED_LABEL, URGENCY_LABEL, callsign

log = logging.getLogger(__name__)

DEFAULT_PORT = 30003  # dump1090's SBS-1 port, and QGC's default ADSB server port
DEFAULT_ADDRESS = ("127.0.0.1", DEFAULT_PORT)
REFRESH_S = 1.0
_ICAO_BASE = 0xF00000  # our tracks' 24-bit addresses: 0xF00000 + HQ ID
_FEET_PER_M = 1.0 / 0.3048
_LIVE_STATES = (TrackState.CONFIRMED, TrackState.NOT_SEEN_RECENTLY)
_RETIRED_LABEL = RETIRED_LABEL
_URGENCY_LABEL = URGENCY_LABEL
MAX_CLIENT_BUFFER_BYTES = 16 * 1024 * 1024  # ~80 refreshes of 1000 tracks: a client not reading
_SEND_CHUNK_BYTES = 256 * 1024  # at most this much per send() call
_RESTART_DELAY_S = 1.0  # after a failure of the thread, serve again this much later
_FAILURE_REPEAT_S = 60.0  # the same failure again is logged at most this often
_ACCEPT_PAUSE_S = 1.0  # accept() failing (no file descriptors left): try again this much later


@dataclass(frozen=True)
class SbsTrack:
    icao: int  # 24-bit address, unique per HQ victim
    callsign: str  # at most 8 characters, [A-Z0-9]
    lat_deg: float
    lon_deg: float
    alt_ft: int
    emergency: bool


def _track(v: HqVictim, label: str, emergency: bool) -> SbsTrack:
    assert v.lat_deg is not None and v.lon_deg is not None and v.alt_m is not None
    return SbsTrack(
        icao=(_ICAO_BASE + v.hq_id) & 0xFFFFFF,
        callsign=callsign(label, v.hq_id),
        lat_deg=v.lat_deg,
        lon_deg=v.lon_deg,
        alt_ft=round(v.alt_m * _FEET_PER_M),
        emergency=emergency,
    )


def tracks(victims: Iterable[HqVictim]) -> tuple[list[SbsTrack], list[SbsTrack]]:
    """(live, retired): live tracks of the confirmed victims with lat/lon; retired
    ones (rescued, false alarm) with their last label."""
    live, retired = [], []
    for v in victims:
        if not v.has_global:
            continue
        if v.state in _LIVE_STATES:
            label = _URGENCY_LABEL[v.urgency]
            live.append(_track(v, label, v.urgency is Urgency.CRITICAL))
        elif v.state in _RETIRED_LABEL:
            retired.append(_track(v, _RETIRED_LABEL[v.state], False))
    return live, retired


def lines(track: SbsTrack, now_unix_s: float) -> bytes:
    """MSG,3 (position, altitude, emergency) then MSG,1 (callsign), CRLF-terminated."""
    t = datetime.fromtimestamp(now_unix_s, UTC)
    date = t.strftime("%Y/%m/%d")
    clock = t.strftime("%H:%M:%S.") + f"{t.microsecond // 1000:03d}"
    head = f"1,1,{track.icao:06X},1,{date},{clock},{date},{clock}"
    position = (
        f"MSG,3,{head},{track.callsign},{track.alt_ft},,,"
        f"{track.lat_deg:.7f},{track.lon_deg:.7f},,,0,{1 if track.emergency else 0},0,0"
    )
    ident = f"MSG,1,{head},{track.callsign},,,,,,,,,,,"
    return f"{position}\r\n{ident}\r\n".encode("ascii")


@dataclass
class _Client:
    sock: socket.socket
    peer: str
    out: bytearray = field(default_factory=bytearray)  # accepted, not yet taken by the socket
    writing: bool = False  # registered for EVENT_WRITE too


class SbsServer:
    """An SBS-1 feed on a TCP port. ``OSError`` from the constructor when the port
    cannot be bound (in use, no such address)."""

    def __init__(
        self,
        host: str,
        port: int,
        refresh_s: float = REFRESH_S,
        *,
        max_client_buffer_bytes: int = MAX_CLIENT_BUFFER_BYTES,
    ) -> None:
        self.refresh_s = refresh_s
        self.max_client_buffer_bytes = max_client_buffer_bytes
        self._listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        try:
            self._listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            self._listener.bind((host, port))
            self._listener.listen(8)
        except OSError:
            self._listener.close()
            raise
        self._listener.setblocking(False)
        self._wake_r, self._wake_w = socket.socketpair()
        self._wake_r.setblocking(False)
        self._wake_w.setblocking(False)
        self._lock = threading.Lock()
        self._live: dict[int, SbsTrack] = {}
        self._pending: dict[int, SbsTrack] = {}  # changed or retired, by address: sent at once
        self._wake_pending = False  # a wake-up byte is on its way: publish sends no other
        self._clients: dict[int, _Client] = {}  # by file descriptor; only the thread changes it
        try:
            self._selector: selectors.BaseSelector | None = self._new_selector()
        except OSError:
            for s in (self._listener, self._wake_r, self._wake_w):
                s.close()
            raise
        self._failures = 0
        self._last_failure = ""
        self._accept_failing = False  # said once, until a client is accepted again
        self._failure_said_mono_s = 0.0  # when a failure was last logged (a loop stays readable)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="hq-sbs", daemon=True)
        self._thread.start()

    @property
    def address(self) -> tuple[str, int]:
        host, port = self._listener.getsockname()[:2]
        return (str(host), int(port))

    @property
    def client_count(self) -> int:
        with self._lock:
            return len(self._clients)

    @property
    def failure(self) -> str | None:
        """What went wrong with the feed's thread (it was restarted), None when nothing."""
        with self._lock:
            if not self._failures:
                return None
            times = "once" if self._failures == 1 else f"{self._failures} times"
            return f"SBS-1 feed failed {times}, restarted (last: {self._last_failure})"

    def publish(self, victims: Iterable[HqVictim]) -> None:
        """The current HQ victims: new or changed tracks go out at once. Never blocks."""
        live, retired = tracks(victims)
        with self._lock:
            changed = [t for t in live if self._live.get(t.icao) != t]
            gone = [t for t in retired if t.icao in self._live]
            self._live = {t.icao: t for t in live}
            for t in changed + gone:
                self._pending[t.icao] = t
            wake = bool(changed or gone) and not self._wake_pending
            self._wake_pending = self._wake_pending or wake
        if wake:
            self._wake()

    def _wake(self) -> None:
        with contextlib.suppress(OSError):  # full or closed: the thread wakes anyway
            self._wake_w.send(b"x")

    def close(self) -> None:
        """Stop the thread and close every socket; safe twice."""
        if self._stop.is_set():
            return
        self._stop.set()
        self._wake()
        self._thread.join(timeout=2.0)
        with self._lock:
            clients, self._clients = list(self._clients.values()), {}
        for s in [self._listener, self._wake_r, self._wake_w, *(c.sock for c in clients)]:
            s.close()
        if self._selector is not None:
            self._selector.close()

    def __enter__(self) -> SbsServer:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()

    # -- the server thread -------------------------------------------------------------

    def _run(self) -> None:
        """Serve until closed; a failure is logged, the clients closed, and it serves again."""
        while not self._stop.is_set():
            try:
                self._serve()
            except Exception as exc:  # a bug must not end the feed for the rest of the night
                self._failed(exc)
                self._stop.wait(_RESTART_DELAY_S)

    def _failed(self, exc: Exception) -> None:
        text = f"{type(exc).__name__}: {exc}"
        now = time.monotonic()
        with self._lock:
            self._failures += 1
            first, same = self._failures == 1, text == self._last_failure
            self._last_failure = text
            clients, self._clients = list(self._clients.values()), {}
        if first:
            log.exception("SBS-1 feed thread failed; its clients are closed and it serves again")
            self._failure_said_mono_s = now
        elif not same or now - self._failure_said_mono_s >= _FAILURE_REPEAT_S:
            log.error("SBS-1 feed thread failed again (%d times in all): %s", self._failures, text)
            self._failure_said_mono_s = now
        for c in clients:
            c.sock.close()
        if self._selector is not None:
            self._selector.close()
            self._selector = None

    def _new_selector(self) -> selectors.BaseSelector:
        selector = selectors.DefaultSelector()
        selector.register(self._listener, selectors.EVENT_READ)
        selector.register(self._wake_r, selectors.EVENT_READ)
        return selector

    def _serve(self) -> None:
        if self._selector is None:  # a new one after a failure
            self._selector = self._new_selector()
        with self._lock:  # a wake-up lost in a failure: the first refresh sends what is pending
            self._wake_pending = False
        accept_paused_until: float | None = None
        next_refresh = time.monotonic()
        while not self._stop.is_set():
            now = time.monotonic()
            if now >= next_refresh:
                next_refresh = now + self.refresh_s
                with self._lock:
                    pending, self._pending = self._pending, {}
                    due = list(self._live.values())
                    due += [t for t in pending.values() if t.icao not in self._live]
                self._send_all(due)
            if accept_paused_until is not None and now >= accept_paused_until:
                accept_paused_until = None
                self._selector.register(self._listener, selectors.EVENT_READ)
            wait_s = next_refresh - now
            if accept_paused_until is not None:
                wait_s = min(wait_s, accept_paused_until - now)
            for key, events in self._selector.select(max(0.0, wait_s)):
                if key.fileobj is self._listener:
                    if not self._accept():  # no descriptor left: do not spin on it
                        self._selector.unregister(self._listener)
                        accept_paused_until = time.monotonic() + _ACCEPT_PAUSE_S
                elif key.fileobj is self._wake_r:
                    self._woken()
                else:
                    self._serve_client(key.fd, events)

    def _woken(self) -> None:
        try:
            while self._wake_r.recv(4096):
                pass
        except BlockingIOError:
            pass
        with self._lock:
            self._wake_pending = False
            pending, self._pending = self._pending, {}
        self._send_all(list(pending.values()))

    def _accept(self) -> bool:
        """Accept one client and queue every live track for it; False when accept failed."""
        try:
            sock, peer = self._listener.accept()
        except BlockingIOError:
            return True
        except OSError as exc:
            if not self._accept_failing:
                log.warning(
                    "SBS-1 feed cannot accept a client: %s; trying again every %.0f s",
                    exc,
                    _ACCEPT_PAUSE_S,
                )
            self._accept_failing = True
            return False
        if self._accept_failing:
            log.warning("SBS-1 feed accepts clients again")
            self._accept_failing = False
        sock.setblocking(False)
        client = _Client(sock, f"{peer[0]}:{peer[1]}")
        log.info("SBS-1 client %s connected", client.peer)
        assert self._selector is not None
        self._selector.register(sock, selectors.EVENT_READ)
        with self._lock:
            self._clients[sock.fileno()] = client
            snapshot = list(self._live.values())
        self._queue(client, _encode(snapshot))
        return True

    def _serve_client(self, fd: int, events: int) -> None:
        client = self._clients.get(fd)
        if client is None:
            return
        if events & selectors.EVENT_READ:
            self._read_client(client)
        if events & selectors.EVENT_WRITE and fd in self._clients:
            self._flush(client)

    def _read_client(self, client: _Client) -> None:
        """Clients send nothing we use; an empty read is a closed connection."""
        try:
            data = client.sock.recv(4096)
        except BlockingIOError:
            return
        except OSError:
            data = b""
        if not data:
            self._drop(client, "closed the connection")

    def _send_all(self, due: list[SbsTrack]) -> None:
        data = _encode(due)
        if not data:
            return
        for client in list(self._clients.values()):
            self._queue(client, data)

    def _queue(self, client: _Client, data: bytes) -> None:
        """Append ``data`` to the client's buffer and send what the socket takes now."""
        if not data:
            return
        client.out += data
        if len(client.out) > self.max_client_buffer_bytes:
            self._drop(
                client,
                f"not reading: {len(client.out)} bytes waiting, more than "
                f"{self.max_client_buffer_bytes} (it gets every track again when it reconnects)",
            )
            return
        self._flush(client)

    def _flush(self, client: _Client) -> None:
        while client.out:
            try:
                sent = client.sock.send(client.out[:_SEND_CHUNK_BYTES])
            except BlockingIOError:
                break
            except OSError as exc:
                self._drop(client, str(exc))
                return
            del client.out[:sent]
        want_write = bool(client.out)
        if want_write != client.writing:
            client.writing = want_write
            events = selectors.EVENT_READ | (selectors.EVENT_WRITE if want_write else 0)
            assert self._selector is not None
            self._selector.modify(client.sock, events)

    def _drop(self, client: _Client, why: str) -> None:
        fd = client.sock.fileno()
        with self._lock:
            if self._clients.get(fd) is not client:
                return
            del self._clients[fd]
        log.info("SBS-1 client %s dropped: %s", client.peer, why)
        if self._selector is not None:
            self._selector.unregister(client.sock)
        client.sock.close()


def _encode(due: Iterable[SbsTrack]) -> bytes:
    now_unix_s = time.time()
    return b"".join(lines(t, now_unix_s) for t in due)
