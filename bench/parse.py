"""MAVLink parse throughput and vehicle-link reader CPU share

Throughput: ``Codec.feed`` on a real ArduSub telemetry stream (the packets of
../shared/data/tlogs/ardusub_real_2023-05-04_small.tlog, 46 message types, without
the tlog timestamps; a synthetic rover mix when the data is absent), fed in 4096-
and 256-byte reads, on one core. Target: at least 10x the line rate of a 921600-baud
serial port (92,160 B/s). Also the real corrupt log (baddata) as raw bytes.
Reader CPU: a VehicleLink on UDP loopback receiving a realistic telemetry load
(heartbeat 1 Hz, ATTITUDE and LOCAL_POSITION_NED 20 Hz, GLOBAL_POSITION_INT 5 Hz
plus VFR_HUD, RC/servo/IMU at 20 Hz and SYS_STATUS: about 131 msg/s) and then the full 921600
line rate; CPU time of its reader thread over wall time. Target: under 10% of a core
at the realistic load.
"""

from __future__ import annotations

import time
from pathlib import Path

from mavlink_io.codec import Codec
from mavlink_io.netlinks import UdpInLink, UdpOutLink
from mavlink_io.vehicle import VehicleLink, VehicleSettings

LINE_RATE_B_S = 92_160  # 921600 baud, 8N1
DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "tlogs"


def _real_stream() -> tuple[bytes, str]:
    path = DATA / "ardusub_real_2023-05-04_small.tlog"
    if not path.exists():
        return _synthetic_stream(2000), "synthetic rover mix"
    codec = Codec(255, 190)
    packets = [bytes(m.get_msgbuf()) for m in codec.feed(path.read_bytes())]
    return b"".join(packets), path.name


def _synthetic_stream(seconds: int) -> bytes:
    tx = Codec(7, 1)
    m = tx.module
    out = bytearray()
    for k in range(seconds * 20):
        t_ms = k * 50
        out += tx.encode(m.MAVLink_attitude_message(t_ms, 0.01, 0.02, 1.0, 0, 0, 0))
        out += tx.encode(m.MAVLink_local_position_ned_message(t_ms, 1, 2, 0, 0.5, 0, 0))
        out += tx.encode(m.MAVLink_vfr_hud_message(0.5, 0.5, 90, 20, 0, 0))
        out += tx.encode(m.MAVLink_rc_channels_raw_message(t_ms, 0, *[1500] * 8, 255))
        out += tx.encode(m.MAVLink_servo_output_raw_message(t_ms * 1000, 0, *[1500] * 8))
        out += tx.encode(m.MAVLink_raw_imu_message(t_ms * 1000, 1, 2, 3, 4, 5, 6, 7, 8, 9))
        if k % 4 == 0:
            out += tx.encode(m.MAVLink_global_position_int_message(t_ms, 1, 1, 0, 0, 0, 0, 0, 0))
            out += tx.encode(
                m.MAVLink_sys_status_message(0, 0, 0, 500, 12000, -1, 80, 0, 0, 0, 0, 0, 0)
            )
        if k % 20 == 0:
            out += tx.encode(m.MAVLink_heartbeat_message(10, 3, 0, 0, 4, 3))
    return bytes(out)


def _throughput(stream: bytes, chunk: int) -> tuple[float, float]:
    best = float("inf")
    messages = 0
    for _ in range(3):
        codec = Codec(255, 190)
        start = time.perf_counter()
        for i in range(0, len(stream), chunk):
            codec.feed(stream[i : i + chunk])
        best = min(best, time.perf_counter() - start)
        messages = codec.counters.messages
    return messages / best, len(stream) / best


def _reader_cpu_share(stream: bytes, bytes_per_s: float, seconds: float) -> float:
    """Feed ``stream`` (looping) to a VehicleLink at ``bytes_per_s``; its reader's CPU share."""
    server = UdpInLink("127.0.0.1", 0)
    vehicle = VehicleLink(server, VehicleSettings())
    sender = UdpOutLink("127.0.0.1", server.local_address[1])
    ident = vehicle._thread.ident
    if ident is None:  # pragma: no cover - the thread starts in the constructor
        raise RuntimeError("reader thread did not start")
    clock_id = time.pthread_getcpuclockid(ident)
    period_s = 0.01
    per_tick = max(1, int(bytes_per_s * period_s))
    try:
        cpu0, wall0 = time.clock_gettime(clock_id), time.monotonic()
        pos = 0
        next_tick = wall0
        while time.monotonic() - wall0 < seconds:
            end = pos + per_tick
            chunk = (
                stream[pos:end]
                if end <= len(stream)
                else stream[pos:] + stream[: end - len(stream)]
            )
            pos = end % len(stream)
            for i in range(0, len(chunk), 1400):  # datagrams below the MTU
                sender.write(chunk[i : i + 1400])
            next_tick += period_s
            time.sleep(
                max(0.0, next_tick - time.monotonic())
            )  # pacing the load, not a readiness check
        cpu1, wall1 = time.clock_gettime(clock_id), time.monotonic()
    finally:
        sender.close()
        vehicle.close()
    return (cpu1 - cpu0) / (wall1 - wall0)


def run() -> dict[str, object]:
    stream, source = _real_stream()
    msgs_4k, bytes_4k = _throughput(stream, 4096)
    msgs_256, bytes_256 = _throughput(stream, 256)
    figures: dict[str, object] = {
        "stream": f"{source}, {len(stream)} bytes",
        "parse msgs/s (4096-byte reads)": round(msgs_4k),
        "parse bytes/s (4096-byte reads)": round(bytes_4k),
        "x 921600-baud line rate (4096-byte reads)": round(bytes_4k / LINE_RATE_B_S, 1),
        "parse msgs/s (256-byte reads)": round(msgs_256),
        "x 921600-baud line rate (256-byte reads)": round(bytes_256 / LINE_RATE_B_S, 1),
    }
    bad = DATA / "ardusub_real_2023-04-18_baddata.tlog"
    if bad.exists():
        raw = bad.read_bytes()
        _, bad_bytes = _throughput(raw, 4096)
        figures["x line rate, corrupt log raw bytes"] = round(bad_bytes / LINE_RATE_B_S, 1)
    realistic = _synthetic_stream(10)  # 10 s of a rover's telemetry, ~131 msg/s
    load_b_s = len(realistic) / 10.0
    figures["realistic load bytes/s"] = round(load_b_s)
    figures["reader CPU % of a core, realistic load"] = round(
        100 * _reader_cpu_share(realistic, load_b_s, 5.0), 2
    )
    saturating = _synthetic_stream(120)  # > 5 s at line rate: no replayed (rebooting) clock
    figures["reader CPU % of a core, full 921600 line rate"] = round(
        100 * _reader_cpu_share(saturating, LINE_RATE_B_S, 5.0), 1
    )
    return figures


if __name__ == "__main__":
    for key, value in run().items():
        print(f"{key}: {value}")
