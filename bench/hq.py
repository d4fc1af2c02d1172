"""rescue-hq: report-to-acknowledgement latency and sustained ingest rate

An in-process HqApp (real UDP on 127.0.0.1, a real SQLite registry in WAL mode
with synchronous=FULL, so every acknowledgement waits for an fsync) receives
victim reports from hq.simrobot robots. Latency: one report at a time, send to
RESCUE_ACK received, 200 reports from one robot. Ingest: three robots send 300
reports each as fast as acknowledgements allow (a window of 8 outstanding per
robot), so reports are batched into shared transactions. Target: a confirmed
victim shows at the HQ within 1 s (issue 9); the ack latency bounds that.
"""

from __future__ import annotations

import statistics
import tempfile
import threading
import time
from pathlib import Path

from hq.app import HqApp, HqOptions
from hq.registry import Registry
from hq.simrobot import SimRobot
from mavlink_io.hub import UdpHubLink

_LATENCY_REPORTS = 200
_INGEST_ROBOTS = 3
_INGEST_REPORTS = 300
_WINDOW = 8


class _Null:
    def write(self, _text: str) -> int:
        return 0

    def flush(self) -> None:
        pass


def _latency(robot: SimRobot) -> list[float]:
    out = []
    for i in range(_LATENCY_REPORTS):
        msg = robot.report_msg(robot.victim(1 + i % 50, float(i % 50), 0.0))
        t0 = time.perf_counter()
        robot.send(msg)
        robot.wait_for("RESCUE_ACK", 5.0, seq=msg.report_seq)
        out.append(time.perf_counter() - t0)
    return out


def _ingest(robot: SimRobot, victim_base: int) -> None:
    outstanding: set[int] = set()
    sent = 0
    while sent < _INGEST_REPORTS or outstanding:
        while sent < _INGEST_REPORTS and len(outstanding) < _WINDOW:
            msg = robot.report_msg(robot.victim(victim_base + sent % 40, 100.0 + sent % 40, 0.0))
            robot.send(msg)
            outstanding.add(msg.report_seq)
            sent += 1
        for rx in robot.receive(5.0):
            if rx.msg.get_type() == "RESCUE_ACK":
                outstanding.discard(rx.msg.seq)


def run() -> dict[str, object]:
    with tempfile.TemporaryDirectory(prefix="bench-hq-") as tmp:
        hub = UdpHubLink("127.0.0.1", 0)
        stop = threading.Event()

        def serve() -> None:  # the registry lives in the thread that uses it (sqlite3 rule)
            with Registry(Path(tmp) / "hq.sqlite") as registry:
                HqApp(registry, [hub], HqOptions(), _Null()).run(stop)  # type: ignore[arg-type]

        thread = threading.Thread(target=serve, daemon=True)
        thread.start()
        try:
            with SimRobot(1, hub.local_address) as robot:
                lat = _latency(robot)
            robots = [SimRobot(10 + i, hub.local_address) for i in range(_INGEST_ROBOTS)]
            t0 = time.perf_counter()
            workers = [
                threading.Thread(target=_ingest, args=(r, 1000 * (i + 1)))
                for i, r in enumerate(robots)
            ]
            for w in workers:
                w.start()
            for w in workers:
                w.join()
            elapsed = time.perf_counter() - t0
            for r in robots:
                r.close()
        finally:
            stop.set()
            thread.join(timeout=5)
            hub.close()
    lat_ms = sorted(v * 1e3 for v in lat)
    return {
        "ack latency median (ms)": round(statistics.median(lat_ms), 2),
        "ack latency p95 (ms)": round(lat_ms[int(0.95 * len(lat_ms)) - 1], 2),
        "ack latency max (ms)": round(lat_ms[-1], 2),
        "ingest, 3 robots (reports/s)": round(_INGEST_ROBOTS * _INGEST_REPORTS / elapsed, 1),
    }


if __name__ == "__main__":
    print(run())
