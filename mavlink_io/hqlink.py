"""The companion's optional direct link to rescue-hq (UDP over Wi-Fi or a mesh radio).

ArduPilot drops message IDs it does not know, so the full dialect reports reach the
HQ either inside TUNNEL through the autopilot or over this link, which carries them
as they are. A reader thread delivers what the HQ sends us (RESCUE_ACK,
RESCUE_PICTURE_ACK, RESCUE_OPERATOR_ACTION, directly or in TUNNEL) to a callback, and keeps the time it
last heard from the HQ.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

from mavlink_io import tunnel
from mavlink_io.codec import Codec, MavMessage
from mavlink_io.dialect import RESCUE_ACK_ID, RESCUE_OPERATOR_ACTION_ID, RESCUE_PICTURE_ACK_ID
from mavlink_io.errors import LinkError
from mavlink_io.link import Link
from mavlink_io.tlog import TlogWriter

log = logging.getLogger(__name__)

_TICK_S = 0.1
_FOR_US = frozenset({RESCUE_ACK_ID, RESCUE_OPERATOR_ACTION_ID, RESCUE_PICTURE_ACK_ID})


class HqLink:
    """A link to the HQ with its own reader thread. ``close()`` is safe twice."""

    def __init__(
        self,
        link: Link,
        codec: Codec,
        on_dialect: Callable[[MavMessage], None],
        tlog: TlogWriter | None = None,
    ) -> None:
        self.link = link
        self.codec = codec
        self._on_dialect = on_dialect
        self._tlog = tlog
        self._last_heard_s: float | None = None
        self._stop = threading.Event()
        self.messages_in = 0
        self.sends_failed = 0
        self._thread = threading.Thread(target=self._run, name="hq-link", daemon=True)
        self._thread.start()

    def heard_within(self, seconds: float) -> bool:
        last = self._last_heard_s
        return last is not None and time.monotonic() - last <= seconds

    def send(self, msg: MavMessage) -> bool:
        data = self.codec.encode(msg)
        try:
            self.link.write(data)
        except LinkError as exc:
            self.sends_failed += 1
            log.debug("%s: send failed: %s", self.link.name, exc)
            return False
        if self._tlog is not None:
            self._tlog.write(data)
        return True

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                data = self.link.read(_TICK_S)
            except LinkError as exc:
                log.warning("%s: %s", self.link.name, exc)
                self._stop.wait(1.0)
                continue
            for msg in self.codec.feed(data) if data else ():
                self._handle(msg)

    def _handle(self, msg: MavMessage) -> None:
        self.messages_in += 1
        self._last_heard_s = time.monotonic()
        if self._tlog is not None:
            self._tlog.write(bytes(msg.get_msgbuf()))
        if tunnel.is_ours(msg):
            msg = tunnel.unpack_tunnel(msg, self.codec)
            if msg is None:
                return
        if msg.get_msgId() not in _FOR_US:
            return
        if getattr(msg, "target_system", 0) not in (0, self.codec.src_system):
            return
        try:
            self._on_dialect(msg)
        except Exception:  # a bug in the handler must not stop the link
            log.exception("handling %s from the HQ failed", msg.get_type())

    def close(self) -> None:
        self._stop.set()
        if self._thread.is_alive() and threading.current_thread() is not self._thread:
            self._thread.join(timeout=2.0)
        self.link.close()
