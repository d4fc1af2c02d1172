"""MAVProxy, a real ground station, shows our STATUSTEXT (including chunked text)."""

from __future__ import annotations

import queue
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from mavlink_io import statustext
from mavlink_io.netlinks import UdpOutLink
from mavlink_io.vehicle import VehicleLink, VehicleSettings

MAVPROXY = Path(sys.executable).with_name("mavproxy.py")


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def wait_line(lines: queue.Queue[str], needle: str, timeout_s: float) -> str:
    end = time.monotonic() + timeout_s
    seen = []
    while (remaining := end - time.monotonic()) > 0:
        try:
            line = lines.get(timeout=remaining)
        except queue.Empty:
            break
        seen.append(line)
        if needle in line:
            return line
    raise AssertionError(f"MAVProxy never printed {needle!r}; it printed: {seen[-20:]}")


@pytest.mark.skipif(not MAVPROXY.exists(), reason=f"MAVProxy not installed at {MAVPROXY}")
def test_mavproxy_shows_victim_statustext(tmp_path: Path) -> None:
    port = free_udp_port()
    proc = subprocess.Popen(
        [
            sys.executable,
            str(MAVPROXY),
            f"--master=udpin:127.0.0.1:{port}",
            "--daemon",
            "--non-interactive",
            "--nowait",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        cwd=tmp_path,  # MAVProxy writes its own mav.tlog here
    )
    lines: queue.Queue[str] = queue.Queue()

    def pump() -> None:
        assert proc.stdout is not None
        for line in proc.stdout:
            lines.put(line.rstrip())

    threading.Thread(target=pump, daemon=True).start()
    vehicle = VehicleLink(UdpOutLink("127.0.0.1", port), VehicleSettings(system_id=7))
    try:
        # MAVProxy sees our 1 Hz heartbeat as component 191 of vehicle 7.
        wait_line(lines, "Detected vehicle 7:191", timeout_s=20.0)
        for msg in statustext.statustext_msgs("CRITICAL victim #3 at N12.3 E4.5 (8%)", 2):
            assert vehicle.send(msg)
        long_text = "MEDIUM victim #4 partly buried under a collapsed shelf, north aisle"
        chunks = statustext.statustext_msgs(long_text, 4)
        assert len(chunks) == 2
        for msg in chunks:
            assert vehicle.send(msg)
        assert "CRITICAL victim #3 at N12.3 E4.5 (8%)" in wait_line(lines, "CRITICAL", 10.0)
        # Reassembled; split between words, the first chunk padded with spaces to 50
        # bytes (QGC's HTML message list shows a run of spaces as one).
        shown = wait_line(lines, "MEDIUM victim #4", 10.0)
        assert long_text in " ".join(shown.split())
    finally:
        vehicle.close()
        proc.terminate()
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        if proc.stdout is not None:
            proc.stdout.close()
