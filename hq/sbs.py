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

The server runs one thread: it accepts clients, writes to them without blocking
(a client that does not read is dropped, it reconnects), and refreshes. The HQ's
main thread calls ``publish`` with the current victims.
"""

from __future__ import annotations

import logging
import select
import socket
import threading
import time
from collections.abc import Iterable
from dataclasses import dataclass
from datetime import UTC, datetime

from fusion.types import TrackState, Urgency
from hq.view import HqVictim

log = logging.getLogger(__name__)

DEFAULT_PORT = 30003  # dump1090's SBS-1 port, and QGC's default ADSB server port
DEFAULT_ADDRESS = ("127.0.0.1", DEFAULT_PORT)
REFRESH_S = 1.0
CALLSIGN_MAX = 8  # an ADS-B callsign holds 8 characters
_ICAO_BASE = 0xF00000  # our tracks' 24-bit addresses: 0xF00000 + HQ ID
_FEET_PER_M = 1.0 / 0.3048
_LIVE_STATES = (TrackState.CONFIRMED, TrackState.NOT_SEEN_RECENTLY)
_RETIRED_LABEL = {TrackState.RESCUED: "RESC", TrackState.FALSE_ALARM: "FALSE"}
_URGENCY_LABEL = {Urgency.CRITICAL: "CRIT", Urgency.MEDIUM: "MED", Urgency.LIGHT: "LIGHT"}


@dataclass(frozen=True)
class SbsTrack:
    icao: int  # 24-bit address, unique per HQ victim
    callsign: str  # at most 8 characters, [A-Z0-9]
    lat_deg: float
    lon_deg: float
    alt_ft: int
    emergency: bool


def callsign(label: str, hq_id: int) -> str:
    """``label`` + ID (two digits at least) within 8 characters (``CRIT07``); the
    label's first letter when the ID is too long for the whole word (``C123456``)."""
    text = f"{label}{hq_id:02d}"
    return text if len(text) <= CALLSIGN_MAX else f"{label[0]}{hq_id}"[:CALLSIGN_MAX]


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


class SbsServer:
    """An SBS-1 feed on a TCP port. ``OSError`` from the constructor when the port
    cannot be bound (in use, no such address)."""

    def __init__(self, host: str, port: int, refresh_s: float = REFRESH_S) -> None:
        self.refresh_s = refresh_s
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
        self._lock = threading.Lock()
        self._live: dict[int, SbsTrack] = {}
        self._pending: list[SbsTrack] = []  # changed or retired: sent at the next wake
        self._clients: list[socket.socket] = []
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

    def publish(self, victims: Iterable[HqVictim]) -> None:
        """The current HQ victims: new or changed tracks go out at once."""
        live, retired = tracks(victims)
        with self._lock:
            now_live = {t.icao: t for t in live}
            changed = [t for t in live if self._live.get(t.icao) != t]
            gone = [t for t in retired if t.icao in self._live]
            self._live = now_live
            self._pending += changed + gone
            wake = bool(changed or gone)
        if wake:
            self._wake_w.send(b"x")

    def close(self) -> None:
        """Stop the thread and close every socket; safe twice."""
        if self._stop.is_set():
            return
        self._stop.set()
        self._wake_w.send(b"x")
        self._thread.join(timeout=2.0)
        for s in [self._listener, self._wake_r, self._wake_w, *self._clients]:
            s.close()
        self._clients = []

    def __enter__(self) -> SbsServer:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()

    # -- the server thread -------------------------------------------------------------

    def _run(self) -> None:
        next_refresh = time.monotonic()
        while not self._stop.is_set():
            now = time.monotonic()
            if now >= next_refresh:
                next_refresh = now + self.refresh_s
                with self._lock:
                    pending, self._pending = self._pending, []
                    due = list(self._live.values())
                    due += [t for t in pending if t.icao not in self._live]
                self._send_all(b"".join(lines(t, time.time()) for t in due))
            with self._lock:
                clients = list(self._clients)
            readable, _, _ = select.select(
                [self._listener, self._wake_r, *clients], [], [], max(0.0, next_refresh - now)
            )
            for sock in readable:
                if sock is self._listener:
                    self._accept()
                elif sock is self._wake_r:
                    self._wake_r.recv(4096)
                    with self._lock:
                        pending, self._pending = self._pending, []
                    self._send_all(b"".join(lines(t, time.time()) for t in pending))
                else:
                    self._read_client(sock)

    def _accept(self) -> None:
        try:
            client, peer = self._listener.accept()
        except OSError:
            return
        client.setblocking(False)
        log.info("SBS-1 client %s:%d connected", *peer[:2])
        with self._lock:
            self._clients.append(client)
            data = b"".join(lines(t, time.time()) for t in self._live.values())
        self._send(client, data)

    def _read_client(self, client: socket.socket) -> None:
        """Clients send nothing we use; an empty read is a closed connection."""
        try:
            data = client.recv(4096)
        except BlockingIOError:
            return
        except OSError:
            data = b""
        if not data:
            self._drop(client, "closed the connection")

    def _send_all(self, data: bytes) -> None:
        if not data:
            return
        with self._lock:
            clients = list(self._clients)
        for client in clients:
            self._send(client, data)

    def _send(self, client: socket.socket, data: bytes) -> None:
        """All of ``data`` at once, or the client goes: a client whose socket buffer
        is full is not reading (it reconnects and gets every track again)."""
        if not data:
            return
        try:
            sent = client.send(data)
        except OSError as exc:
            self._drop(client, str(exc))
            return
        if sent != len(data):
            self._drop(client, "not reading")

    def _drop(self, client: socket.socket, why: str) -> None:
        with self._lock:
            if client not in self._clients:
                return
            self._clients.remove(client)
        log.info("SBS-1 client dropped: %s", why)
        client.close()
