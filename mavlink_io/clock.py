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

One absurd ``time_boot_ms`` (a corrupt or forged message) must not do that. A sample
that does not fit the current timeline (boot time backwards by more than the
tolerance, or ahead of the companion's clock by more than it, which latency can
never explain) is only a candidate: the timeline changes when ``confirm_samples``
consecutive candidates agree with each other (same offset within the tolerance,
boot time not going backwards). Until then each is refused (``observe`` returns
``REJECTED``, ``rejected`` counts it) and changes nothing. At 20 Hz telemetry the
confirmation costs 0.1 s after a real reboot.
"""

from __future__ import annotations

import enum
import threading
from collections import deque

from mavlink_io.errors import ClockNotSynced


class Sample(enum.Enum):
    """What ``BootClock.observe`` made of a sample."""

    OK = "ok"  # on the current timeline
    NEW_BOOT = "new boot"  # a confirmed new timeline: the autopilot rebooted
    REJECTED = "rejected"  # off the timeline and not (yet) confirmed: ignore the message


class BootClock:
    """Minimum-latency estimate of ``t_mono - t_boot``. Thread-safe."""

    def __init__(
        self, window_s: float = 10.0, reboot_tolerance_s: float = 1.0, confirm_samples: int = 3
    ) -> None:
        if window_s <= 0 or reboot_tolerance_s <= 0 or confirm_samples < 1:
            raise ValueError("window_s and reboot_tolerance_s must be > 0, confirm_samples >= 1")
        self._window_s = window_s
        self._reboot_tolerance_s = reboot_tolerance_s
        self._confirm_samples = confirm_samples
        self._lock = threading.Lock()
        # (t_mono_s, offset_s) with increasing offsets: the front is the window minimum.
        self._envelope: deque[tuple[float, float]] = deque()
        self._last_boot_s: float | None = None
        self._candidates: list[tuple[float, float]] = []  # (t_boot_s, t_mono_s) off-timeline
        self.reboots = 0
        self.samples = 0
        self.rejected = 0

    def observe(self, t_boot_s: float, t_mono_s: float) -> Sample:
        """Add a sample (a message's boot time and when we received it); see Sample."""
        with self._lock:
            self.samples += 1
            tol = self._reboot_tolerance_s
            offset = t_mono_s - t_boot_s
            last = self._last_boot_s
            env = self._envelope
            off_timeline = last is not None and (
                t_boot_s < last - tol or (bool(env) and offset < env[0][1] - tol)
            )
            if not off_timeline:
                self._candidates.clear()
                self._add(t_boot_s, t_mono_s, offset)
                return Sample.OK
            if not self._continues_candidates(t_boot_s, offset):
                self._candidates.clear()
            self._candidates.append((t_boot_s, t_mono_s))
            if len(self._candidates) < self._confirm_samples:
                self.rejected += 1
                return Sample.REJECTED
            env.clear()
            self._last_boot_s = None
            for boot_s, mono_s in self._candidates:
                self._add(boot_s, mono_s, mono_s - boot_s)
            self._candidates.clear()
            self.reboots += 1
            return Sample.NEW_BOOT

    def _continues_candidates(self, t_boot_s: float, offset: float) -> bool:
        if not self._candidates:
            return True
        boot_s, mono_s = self._candidates[-1]
        return t_boot_s >= boot_s and abs(offset - (mono_s - boot_s)) <= self._reboot_tolerance_s

    def _add(self, t_boot_s: float, t_mono_s: float, offset: float) -> None:
        if self._last_boot_s is None or t_boot_s > self._last_boot_s:
            self._last_boot_s = t_boot_s
        env = self._envelope
        while env and env[-1][1] >= offset:
            env.pop()
        env.append((t_mono_s, offset))
        while env[0][0] < t_mono_s - self._window_s:
            env.popleft()

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
            self._candidates.clear()
