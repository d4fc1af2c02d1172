"""Clock offset estimation with injected serial jitter, and reboot detection."""

from __future__ import annotations

import numpy as np
import pytest

from mavlink_io.clock import BootClock, Sample
from mavlink_io.errors import ClockNotSynced

TRUE_OFFSET_S = 1234.5678  # companion monotonic minus autopilot boot time
WIRE_S = 0.0004  # a 40-byte frame at 921600 baud: the smallest possible latency


def stream(
    rng: np.random.Generator, duration_s: float, rate_hz: float, jitter_mean_s: float
) -> list[tuple[float, float]]:
    """(t_boot_s as the autopilot sends it, t_mono_s when we receive it)."""
    out = []
    for k in range(int(duration_s * rate_hz)):
        t_boot_true = 100.0 + k / rate_hz
        latency = WIRE_S + rng.exponential(jitter_mean_s)
        if rng.random() < 0.05:  # bursts: a queue of messages behind a big one
            latency += rng.uniform(0.02, 0.1)
        t_boot_ms = np.floor(t_boot_true * 1000.0) / 1000.0  # time_boot_ms truncates
        out.append((float(t_boot_ms), t_boot_true + TRUE_OFFSET_S + latency))
    return out


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_offset_within_1ms_of_the_wire_floor_despite_jitter(seed: int) -> None:
    rng = np.random.default_rng(seed)
    clock = BootClock(window_s=10.0)
    samples = stream(rng, duration_s=4.0, rate_hz=50.0, jitter_mean_s=0.005)
    naive = []
    for t_boot, t_mono in samples:
        clock.observe(t_boot, t_mono)
        naive.append(t_mono - t_boot)
    error = clock.offset_s - TRUE_OFFSET_S
    # Floor: the wire time is a latency we cannot see; ms truncation adds at most 1 ms.
    assert WIRE_S - 1e-9 <= error <= WIRE_S + 0.001 + 1e-9, error
    # For contrast: the mean of the raw samples is biased by the jitter (>= 5 ms here).
    assert np.mean(naive) - TRUE_OFFSET_S > 0.005
    # Mapping a boot time: within the same bound.
    assert abs(clock.to_mono(150.0) - (150.0 + TRUE_OFFSET_S)) <= WIRE_S + 0.001


def test_converges_fast_and_tracks_drift() -> None:
    rng = np.random.default_rng(7)
    clock = BootClock(window_s=5.0)
    drift = 50e-6  # 50 ppm between the crystals: 0.5 ms per 10 s
    errors = []
    for k in range(60 * 20):  # 60 s at 20 Hz
        t_boot_true = k / 20.0
        offset_now = TRUE_OFFSET_S + drift * t_boot_true
        latency = WIRE_S + rng.exponential(0.004)
        t_boot_ms = np.floor(t_boot_true * 1000.0) / 1000.0
        clock.observe(float(t_boot_ms), t_boot_true + offset_now + latency)
        if k > 40:  # after 2 s
            errors.append(clock.offset_s - offset_now)
    # Within 1.5 ms throughout: wire floor + truncation + at most a window of drift (0.25 ms).
    assert max(abs(e) for e in errors) < 0.0015


def test_reboot_resets_the_estimate() -> None:
    clock = BootClock(reboot_tolerance_s=1.0)
    assert not clock.synced
    with pytest.raises(ClockNotSynced):
        _ = clock.offset_s
    assert clock.observe(300.0, 1000.0) is Sample.OK
    assert clock.offset_s == pytest.approx(700.0)
    assert clock.observe(299.5, 1000.1) is Sample.OK  # small reordering: not a reboot
    # Boot time jumped back: a new boot once three samples agree, not on the first.
    assert clock.observe(2.0, 1010.0) is Sample.REJECTED
    assert clock.observe(2.1, 1010.1) is Sample.REJECTED
    assert clock.offset_s == pytest.approx(700.0)
    assert clock.observe(2.2, 1010.2) is Sample.NEW_BOOT
    assert clock.reboots == 1
    assert clock.offset_s == pytest.approx(1008.0)  # the old, smaller offset is gone
    assert clock.last_boot_s == pytest.approx(2.2)


def test_lone_absurd_samples_are_rejected_and_change_nothing() -> None:
    clock = BootClock(reboot_tolerance_s=1.0)
    for i in range(10):
        assert clock.observe(300.0 + i * 0.1, 1000.0 + i * 0.1) is Sample.OK
    # One far ahead of our clock (latency cannot explain it), one back at zero, then
    # two that disagree with each other: none is confirmed.
    for boot_s, mono_s in ((4e6, 1001.0), (0.0, 1001.05), (50.0, 1001.1), (10.0, 1001.15)):
        assert clock.observe(boot_s, mono_s) is Sample.REJECTED
    assert clock.observe(301.2, 1001.2) is Sample.OK
    assert (clock.reboots, clock.rejected) == (0, 4)
    assert clock.offset_s == pytest.approx(700.0)
    assert clock.last_boot_s == pytest.approx(301.2)
