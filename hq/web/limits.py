"""How many connections the console serves at once, and what it says beyond that.

A laptop's rescue-hq has 1024 file descriptors by default, shared with the radio
links, the SBS-1 feed for QGC and SQLite. Without a cap, ~1100 held console
connections take them all: asyncio's accept loop then fails and logs a traceback
for every try (thousands a second), and no new browser or QGC can connect.

So the console keeps well below the limit: at most ``max_connections`` open
sockets (a quarter of the descriptor limit, at most 256); one more is answered
503 at once and closed, before its request is read. At most ``max_streams`` of
them are live event streams (/api/events); one more gets 503 with a line that
says why. Each overload is said once in the log (at most once a minute, and once
when there is room again), and an accept that fails for want of descriptors is
said once, not once per try.
"""

from __future__ import annotations

import asyncio
import logging
import resource
import time
from typing import Any

from uvicorn.protocols.http.h11_impl import H11Protocol

log = logging.getLogger(__name__)

MAX_CONNECTIONS = 256  # open console sockets (pages, requests, event streams)
MAX_STREAMS = 64  # open event streams: a page each
_FD_SHARE = 4  # the console takes at most a quarter of the descriptor limit
_RESAY_S = 60.0  # an overload is said at most once a minute


def _fd_limit() -> int:
    soft, _hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    return soft if soft != resource.RLIM_INFINITY else 1 << 20


def _busy_response(text: str) -> bytes:
    body = text.encode() + b"\n"
    head = (
        "HTTP/1.1 503 Service Unavailable\r\n"
        "content-type: text/plain; charset=utf-8\r\n"
        "retry-after: 5\r\n"
        "connection: close\r\n"
        f"content-length: {len(body)}\r\n\r\n"
    )
    return head.encode() + body


class _Overload:
    """One overload said once: when it starts, and when there is room again (below
    half the cap, so a crowd at the door is not a line per arrival); a new one
    within a minute of the last is not said again."""

    def __init__(self) -> None:
        self._full = False
        self._said = False
        self._said_at = -_RESAY_S

    def full(self, line: str) -> None:
        if self._full:
            return
        self._full = True
        now = time.monotonic()
        self._said = now - self._said_at >= _RESAY_S
        if self._said:
            self._said_at = now
            log.warning(line)

    def room(self, line: str) -> None:
        if self._full:
            self._full = False
            if self._said:
                log.warning(line)


class ConnectionLimits:
    """The caps and the once-per-overload log lines; used in the event loop only."""

    def __init__(self, max_connections: int | None = None, max_streams: int | None = None) -> None:
        fd_share = max(8, _fd_limit() // _FD_SHARE)
        self.max_connections = min(max_connections or MAX_CONNECTIONS, fd_share)
        self.max_streams = min(max_streams or MAX_STREAMS, self.max_connections)
        self.streams = 0
        self.refused_connections = 0
        self.refused_streams = 0
        self._connections = _Overload()
        self._streams = _Overload()
        self._accept_failing = False
        self.busy_connection = _busy_response(
            f"rescue-hq console: {self.max_connections} connections open, the most it "
            "serves; try again when a page is closed"
        )
        self.busy_stream_text = (
            f"rescue-hq console: {self.max_streams} pages open, the most it serves live; "
            "close one and reload"
        )

    # -- open sockets ------------------------------------------------------------

    def connection_refused(self) -> None:
        self.refused_connections += 1
        self._connections.full(
            f"console: {self.max_connections} connections open, the most it serves: "
            "new ones get 503 until some close"
        )

    def connection_room(self, open_now: int) -> None:
        if open_now <= self.max_connections // 2:
            self._connections.room(
                f"console: room for connections again ({self.refused_connections} refused so far)"
            )

    # -- event streams -----------------------------------------------------------

    def open_stream(self) -> bool:
        """Count a new event stream in; False (said once) when there is no room."""
        if self.streams >= self.max_streams:
            self.refused_streams += 1
            self._streams.full(
                f"console: {self.max_streams} live pages open, the most it serves: "
                "new ones get 503 until one closes"
            )
            return False
        self.streams += 1
        return True

    def close_stream(self) -> None:
        self.streams -= 1
        if self.streams <= self.max_streams // 2:
            self._streams.room(
                f"console: room for live pages again ({self.refused_streams} refused so far)"
            )

    # -- accept failures -----------------------------------------------------------

    def loop_exception(self, loop: asyncio.AbstractEventLoop, context: dict[str, Any]) -> None:
        """The event loop's exception handler: a failed accept (no descriptors left,
        whoever holds them) is said once per episode, not once per try."""
        if context.get("message", "").startswith("socket.accept() out of system resource"):
            if not self._accept_failing:
                self._accept_failing = True
                exc = context.get("exception")
                log.error(
                    "console: cannot accept connections: %s (rescue-hq is out of file "
                    "descriptors; said once until one is accepted again)",
                    getattr(exc, "strerror", None) or exc,
                )
            return
        loop.default_exception_handler(context)

    def accepted(self) -> None:
        if self._accept_failing:
            self._accept_failing = False
            log.warning("console: accepting connections again")


def capped_protocol(limits: ConnectionLimits) -> type[H11Protocol]:
    """uvicorn's h11 protocol, refusing a connection beyond ``limits.max_connections``
    with 503 before reading it (the socket is closed at once, its descriptor freed)."""

    class Capped(H11Protocol):
        _refused = False

        def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
            limits.accepted()
            if len(self.connections) >= limits.max_connections:
                self._refused = True
                limits.connection_refused()
                transport.write(limits.busy_connection)
                transport.close()
                return
            super().connection_made(transport)

        def data_received(self, data: bytes) -> None:
            if not self._refused:
                super().data_received(data)

        def connection_lost(self, exc: Exception | None) -> None:
            if self._refused:
                return
            super().connection_lost(exc)
            limits.connection_room(len(self.connections))

        def pause_writing(self) -> None:
            if not self._refused:
                super().pause_writing()

        def resume_writing(self) -> None:
            if not self._refused:
                super().resume_writing()

    return Capped
