"""The companion and the real rescue-hq on a direct link (UDP over Wi-Fi/mesh):
reports arrive and are acknowledged; an operator's decision reaches the robot."""

from __future__ import annotations

import re
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest
from hqproc import mark, start_companion
from test_hq_e2e import HqProcess, start_hq  # noqa: F401  (the fixture)

from scenarios.live import LiveSim
from scenarios.world import preset

pytestmark = pytest.mark.slow


def test_direct_link_report_ack_and_operator_mark(
    tmp_path: Path,
    start_hq: Callable[..., HqProcess],  # noqa: F811  (pytest fixture)
) -> None:
    hq = start_hq()
    with LiveSim(preset("light"), patrol_first_victim=True, speed_m_s=0.25) as sim:
        proc, log = start_companion(tmp_path, sim.vehicle_url, sim.camera_source, hq.port)
        try:
            line = hq.wait_line("report robot 1 victim", 60.0)
            victim_id = int(re.search(r"victim (\d+)", line).group(1))  # type: ignore[union-attr]
            mark(hq.db, 1, victim_id, "rescued")
            # The running HQ sends the action; the robot applies it and reports the
            # victim RESCUED, which the HQ receives and acknowledges.
            deadline = time.monotonic() + 30.0
            while True:  # report lines of this victim until one says RESCUED
                line = hq.wait_line(
                    f"report robot 1 victim {victim_id} seq", deadline - time.monotonic()
                )
                if "RESCUED" in line:
                    break
            # The operator changes their mind (the console's Confirm): the robot reopens it.
            mark(hq.db, 1, victim_id, "confirmed")
            while True:
                line = hq.wait_line(
                    f"report robot 1 victim {victim_id} seq", deadline - time.monotonic()
                )
                if "CONFIRMED" in line:
                    break
        finally:
            proc.send_signal(signal.SIGTERM)
            assert proc.wait(timeout=15) == 0, log.read_text()[-3000:]
    text = log.read_text()
    assert f"operator marked victim {victim_id} RESCUED" in text
    assert f"operator marked victim {victim_id} CONFIRMED" in text
    # Every report was acknowledged over the direct link: nothing left to resend.
    listing = subprocess.run(
        [sys.executable, "-m", "hq.cli", "list", "--db", str(hq.db)],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert "CONFIRMED" in listing.stdout
