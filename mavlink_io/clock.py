"""Map the autopilot's boot time onto the companion's monotonic clock.

Every timestamped message (ATTITUDE, LOCAL_POSITION_NED, ...) gives one sample

    offset_i = t_mono_received_i - t_boot_i = offset + latency_i,   latency_i >= 0

where latency is the time from the autopilot stamping the sample to our reader
seeing it: queueing in the autopilot, the frame's time on the wire, the OS and our
reader thread. Latency jitters by milliseconds on a serial link (and by tens of
milliseconds when a burst of messages queues up), but it is never negative, so the
*minimum* of the samples over a sliding window (the minimum-latency envelope) is the
best estimate of ``offset``: late samples are simply outvoted.

Achievable accuracy (measured in tests/test_mavlink_clock.py with injected jitter):
the estimate equals the true offset plus the *smallest* latency seen in the window,
which is at least one frame's transmission time (about 0.4 ms for a 40-byte frame
at 921600 baud, 3.5 ms at 115200) plus up to 1 ms of ``time_boot_ms`` truncation on
the sample that happens to be fastest. With 50 messages per second and exponential
jitter of 5 ms mean, the error stays within 1 ms of that floor after 2 s. A bias of
a few milliseconds is negligible for geolocation: a rover at 1 m/s moves 1 mm/ms.

The window (default 10 s) follows the slow drift of the two crystals (tens of ppm,
i.e. well under 1 ms per 10 s). An autopilot reboot shows as its boot time jumping
backwards by more than ``reboot_tolerance_s``: the estimate is reset and
``reboots`` counts it; the caller clears anything stamped with the old boot.
"""

from __future__ import annotations

import threading
from collections import deque

from mavlink_io.errors import ClockNotSynced


class BootClock:
    """Minimum-latency estimate of ``t_mono - t_boot``. Thread-safe."""

    def __init__(self, window_s: float = 10.0, reboot_tolerance_s: float = 1.0) -> None:
        if window_s <= 0 or reboot_tolerance_s <= 0:
            raise ValueError("window_s and reboot_tolerance_s must be > 0")
        self._window_s = window_s
        self._reboot_tolerance_s = reboot_tolerance_s
        self._lock = threading.Lock()
        # (t_mono_s, offset_s) with increasing offsets: the front is the window minimum.
        self._envelope: deque[tuple[float, float]] = deque()
        self._last_boot_s: float | None = None
        self.reboots = 0
        self.samples = 0

    def observe(self, t_boot_s: float, t_mono_s: float) -> bool:
        """Add a sample (a message's boot time and when we received it).

        Returns True when the boot time jumped backwards: the autopilot rebooted and
        the estimate restarted from this sample.
        """
        with self._lock:
            rebooted = (
                self._last_boot_s is not None
                and t_boot_s < self._last_boot_s - self._reboot_tolerance_s
            )
            if rebooted:
                self._envelope.clear()
                self.reboots += 1
            if self._last_boot_s is None or rebooted or t_boot_s > self._last_boot_s:
                self._last_boot_s = t_boot_s
            offset = t_mono_s - t_boot_s
            env = self._envelope
            while env and env[-1][1] >= offset:
                env.pop()
            env.append((t_mono_s, offset))
            while env[0][0] < t_mono_s - self._window_s:
                env.popleft()
            self.samples += 1
            return rebooted

    @property
    def synced(self) -> bool:
        with self._lock:
            return bool(self._envelope)

    @property
    def offset_s(self) -> float:
        """Current estimate of t_mono - t_boot; ClockNotSynced before the first sample."""
        with self._lock:
            if not self._envelope:
                raise ClockNotSynced("no timestamped message from the autopilot yet")
            return self._envelope[0][1]

    @property
    def last_boot_s(self) -> float | None:
        """The newest boot time seen (the autopilot's uptime), or None."""
        with self._lock:
            return self._last_boot_s

    def to_mono(self, t_boot_s: float) -> float:
        """The companion monotonic time of an autopilot boot time."""
        return t_boot_s + self.offset_s

    def to_boot(self, t_mono_s: float) -> float:
        """The autopilot boot time of a companion monotonic time."""
        return t_mono_s - self.offset_s

    def reset(self) -> None:
        """Forget everything (e.g. after a link loss, a different autopilot may answer)."""
        with self._lock:
            self._envelope.clear()
            self._last_boot_s = None
