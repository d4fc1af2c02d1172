"""The searched-area map to the HQ: deltas in RESCUE_COVERAGE pieces, resent until
acknowledged, within a byte rate of their own (``[coverage] rate_bytes_s``).

On the reporter thread, after reports and pictures: every ``period_s`` it takes the
cells changed since the version the HQ acknowledged (``delta_since(acked)``), cuts
them into pieces (mavlink_io/coverage.py) and sends each, resending one not
acknowledged after ``RESEND_INITIAL_S``, doubling up to ``RESEND_MAX_S``. When every
piece of the delta is acknowledged the HQ holds the map up to its version, which is
saved (a restart sends only what changed after it). A cell that changes while a
delta is on its way is in the next one, with its newest value; a slow link sends
fewer, newer values, not a backlog. A piece the HQ REJECTED is not sent again.

Nothing here sends a report or a picture later: the reporter polls this only when
neither has anything to send at that moment, and the radio carries at most
``[pictures] rate_bytes_s`` + ``[coverage] rate_bytes_s`` besides reports.
"""

from __future__ import annotations

import logging
import secrets
import time
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from companion.config import CoverageConfig
from companion.coverage import SharedGrid
from companion.storage.store import Store, StoreError
from fusion.coverage import CoverageDelta
from mavlink_io import coverage

log = logging.getLogger(__name__)

RESEND_INITIAL_S = 2.0
RESEND_MAX_S = 10.0  # the rate bounds what resends cost; a long wait only delays the map
_RESULT_REJECTED = 2  # RESCUE_ACK_RESULT_REJECTED
# A piece in a TUNNEL on the radio: the outer frame (12) and TUNNEL's own fields (5),
# the inner frame (12), RESCUE_COVERAGE's seq and length (5), then its data; signed,
# each frame carries a 13-byte signature. MAVLink 2 drops the trailing zeros.
_PIECE_OVERHEAD = 12 + 5 + 12 + 5
_SIGNATURE = 13


def piece_wire_bytes(piece: CoverageDelta, signed: bool) -> int:
    """The bytes one piece takes on the radio, in a TUNNEL (at most)."""
    return _PIECE_OVERHEAD + coverage.piece_bytes(piece) + (2 * _SIGNATURE if signed else 0)


@dataclass
class CoverageCounters:
    deltas: int = 0  # deltas started
    delivered: int = 0  # deltas the HQ acknowledged whole
    pieces: int = 0  # pieces sent, resends included
    resends: int = 0
    rejected: int = 0  # pieces the HQ REJECTED
    bytes: int = 0  # on the radio, as piece_wire_bytes counts them


@dataclass
class _Piece:
    piece: CoverageDelta
    due_s: float  # send (again) then
    wait_s: float  # the next resend waits this long
    sent: int = 0


class CoverageSender:
    """``poll``, ``on_ack`` and ``seconds_until_due`` on the reporter thread."""

    def __init__(
        self,
        grid: SharedGrid,
        cfg: CoverageConfig,
        send: Callable[[int, CoverageDelta], None],
        *,
        acked_version: int = 0,
        on_delivered: Callable[[int], None] = lambda _v: None,
        signed: bool = False,
        clock: Callable[[], float] = time.monotonic,
        first_seq: int | None = None,
    ) -> None:
        self._grid = grid
        self.cfg = cfg
        self._send = send
        self.acked_version = acked_version  # the HQ holds the map up to this version
        self._on_delivered = on_delivered
        self._signed = signed
        self._clock = clock
        # Random: an acknowledgement meant for an earlier run never names a piece of this one.
        self._seq = secrets.randbits(32) if first_seq is None else first_seq
        self._pending: OrderedDict[int, _Piece] = OrderedDict()  # by seq, oldest first
        self._to_version = 0  # of the delta on its way
        self._next_build_s = clock()
        self._built_s = -self.cfg.period_s  # when the last delta was taken
        self._capacity = 2.0 * _PIECE_OVERHEAD + 2.0 * coverage.DATA_BYTES  # about two pieces
        self._tokens = self._capacity
        self._last_s = clock()
        self.counters = CoverageCounters()

    @property
    def pending(self) -> int:
        """Pieces not acknowledged yet."""
        return len(self._pending)

    def _next_seq(self) -> int:
        self._seq = (self._seq + 1) & coverage.MAX_SEQ
        return self._seq

    def _build(self, now: float) -> None:
        self._built_s = now
        self._next_build_s = now + self.cfg.period_s
        if self._grid.version <= self.acked_version:
            return
        delta = self._grid.delta_since(self.acked_version)
        self._to_version = delta.to_version
        parts = coverage.pieces(delta)
        if not parts:  # levels only rose back to where they were: nothing to tell
            self._delivered(now)
            return
        self.counters.deltas += 1
        for part in parts:
            self._pending[self._next_seq()] = _Piece(part, now, RESEND_INITIAL_S)
        log.debug(
            "coverage: %d cells changed since version %d, in %d pieces",
            len(delta),
            delta.from_version,
            len(parts),
        )

    def _refill(self, now: float) -> None:
        self._tokens = min(
            self._capacity, self._tokens + (now - self._last_s) * self.cfg.rate_bytes_s
        )
        self._last_s = now

    def poll(self) -> None:
        """Send what is due and what the rate allows now."""
        now = self._clock()
        self._refill(now)
        if not self._pending and now >= self._next_build_s:
            self._build(now)
        for seq, p in self._pending.items():
            if p.due_s > now:
                continue
            cost = piece_wire_bytes(p.piece, self._signed)
            if self._tokens < cost:
                return
            self._tokens -= cost
            if p.sent:
                self.counters.resends += 1
            p.sent += 1
            p.due_s = now + p.wait_s
            p.wait_s = min(RESEND_MAX_S, p.wait_s * 2.0)
            self.counters.pieces += 1
            self.counters.bytes += cost
            self._send(seq, p.piece)

    def on_ack(self, seq: int, result: int) -> None:
        """A RESCUE_ACK of a piece (one of an earlier delta or run is ignored)."""
        if self._pending.pop(seq, None) is None:
            return
        if result == _RESULT_REJECTED:
            self.counters.rejected += 1
            log.warning("coverage piece %d REJECTED by the HQ: not sent again", seq)
        if not self._pending:
            self._delivered(self._clock())

    def _delivered(self, now: float) -> None:
        self.acked_version = max(self.acked_version, self._to_version)
        self.counters.delivered += 1
        # The period counts from the last delta's start: a link slower than the map
        # changes sends the next one at once, not after an idle period.
        self._next_build_s = max(now, self._built_s + self.cfg.period_s)
        self._on_delivered(self.acked_version)

    def seconds_until_due(self) -> float:
        """When ``poll`` may have something to do."""
        now = self._clock()
        if not self._pending:
            return max(0.0, self._next_build_s - now)
        self._refill(now)
        due = min(p.due_s for p in self._pending.values())
        first = next(iter(self._pending.values()))
        lack = piece_wire_bytes(first.piece, self._signed) - self._tokens
        return max(0.0, due - now, lack / self.cfg.rate_bytes_s if lack > 0 else 0.0)


ACKED_KEY = "coverage_acked"  # the state database's kv key: the version the HQ holds


def resume(
    grid: SharedGrid,
    cfg: CoverageConfig,
    store: Store,
    send: Callable[[int, CoverageDelta], None],
    *,
    signed: bool,
) -> CoverageSender:
    """The sender, continuing from the version the HQ acknowledged before a restart
    (never beyond the restored grid's: looks after the last save were lost with it,
    and their versions are given again). An unusable saved value sends the whole map."""
    acked = 0
    try:
        saved: Any = store.get(ACKED_KEY)
    except StoreError as exc:
        log.warning(
            "%s: saved %s unreadable, the whole map is sent: %s", store.path, ACKED_KEY, exc
        )
        saved = None
    if isinstance(saved, int) and not isinstance(saved, bool) and 0 <= saved <= coverage.MAX_SEQ:
        acked = min(saved, grid.version)
    elif saved is not None:
        log.warning("%s: saved %s %r unusable, the whole map is sent", store.path, ACKED_KEY, saved)

    def delivered(version: int) -> None:
        try:
            store.set(ACKED_KEY, version)
        except StoreError as exc:  # sent again after a restart; the HQ takes it twice
            log.warning("coverage version %d acknowledged, not saved: %s", version, exc)

    return CoverageSender(
        grid, cfg, send, acked_version=acked, on_delivered=delivered, signed=signed
    )
