"""The companion's settings through the MAVLink parameter protocol, as QGC's
parameter editor uses it: a real pymavlink client on the simulated rover's ground
port (the rover routes like ArduPilot) lists, reads and sets the parameters of
component 191; values are validated like the config, persist across a restart,
and an edited config file wins over an old override."""

from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from pymavlink import mavutil

from companion.config import Config, DetectorConfig, ReportingConfig
from companion.service.params import Settings
from scenarios.live import LiveSim
from scenarios.world import preset

COMPANION = 191
REAL32 = 9


# -- the table, in process ----------------------------------------------------------------


def _settings(config: Config, saved: Any = None) -> tuple[Settings, list[Any], list[Config]]:
    stored: list[Any] = []
    applied: list[Config] = []
    return Settings(config, saved, applied.append, stored.append), stored, applied


def test_settings_validate_like_the_config_apply_and_save() -> None:
    settings, stored, applied = _settings(Config())
    assert settings.names() == [
        "RC_DET_MIN_SCORE",
        "RC_UPD_MIN_S",
        "RC_ANN_SEV",
        "RC_VID_ON",
        "RC_VID_KBPS",
        "RC_LOOK_ON",
    ]
    assert settings.get("RC_DET_MIN_SCORE") == 0.5
    assert settings.set("RC_DET_MIN_SCORE", 0.7) is None
    assert applied[-1].detector.min_score == 0.7
    assert stored[-1] == {"RC_DET_MIN_SCORE": [0.7, 0.5]}  # the value and the file's then
    for name, bad, why in [
        ("RC_DET_MIN_SCORE", 1.5, "must be in [0, 1]"),
        ("RC_ANN_SEV", 2.5, "not a whole number"),
        ("RC_ANN_SEV", 9.0, "must be a MAV_SEVERITY 0..7"),
        ("RC_UPD_MIN_S", -1.0, "must be >= 0"),
        ("RC_UPD_MIN_S", math.nan, "not a finite number"),
        ("RC_VID_ON", 0.5, "not 0 (off) or 1 (on)"),
        ("RC_VID_KBPS", 10.0, "must be 50..20000"),
    ]:
        reason = settings.set(name, bad)
        assert reason is not None and name in reason and why in reason, reason
    assert len(applied) == 1 and settings.get("RC_DET_MIN_SCORE") == 0.7
    assert settings.set("RC_ANN_SEV", 6.0) is None
    assert applied[-1].reporting.announce_severity == 6  # an int, as in the config
    assert settings.set("RC_VID_ON", 0.0) is None
    assert applied[-1].video.enabled is False  # a bool, as in the config
    assert settings.get("RC_VID_ON") == 0.0


def test_saved_values_hold_until_the_config_file_changes() -> None:
    saved = {"RC_DET_MIN_SCORE": [0.7, 0.5], "RC_UPD_MIN_S": [2.0, 5.0]}
    settings, _, _ = _settings(Config(), saved)
    assert settings.get("RC_DET_MIN_SCORE") == 0.7 and settings.get("RC_UPD_MIN_S") == 2.0
    edited = Config(detector=DetectorConfig(min_score=0.6))  # the operator edited the file
    settings, _, _ = _settings(edited, saved)
    assert settings.get("RC_DET_MIN_SCORE") == 0.6  # the file wins
    assert settings.get("RC_UPD_MIN_S") == 2.0  # untouched in the file: still overridden
    assert settings.snapshot() == {"RC_UPD_MIN_S": [2.0, 5.0]}


@pytest.mark.parametrize(
    "saved",
    [[1, 2], {"RC_DET_MIN_SCORE": "high"}, {"RC_DET_MIN_SCORE": [7.0, 0.5]}, {"NOPE": [1, 1]}],
)
def test_bad_saved_parameters_are_dropped_not_fatal(saved: Any) -> None:
    settings, _, _ = _settings(Config(reporting=ReportingConfig()), saved)
    assert settings.get("RC_DET_MIN_SCORE") == 0.5 and settings.snapshot() == {}


# -- the protocol, end to end ---------------------------------------------------------------


class Gcs:
    """pymavlink as QGC: system 255, component 190, heartbeats so the rover routes to it."""

    def __init__(self, url: str) -> None:
        self.conn = mavutil.mavlink_connection(url, source_system=255, source_component=190)
        self._next_heartbeat = 0.0

    def close(self) -> None:
        self.conn.close()

    def recv(self, want: str, timeout_s: float, **fields: Any) -> Any:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if time.monotonic() >= self._next_heartbeat:
                self.conn.mav.heartbeat_send(6, 8, 0, 0, 4)  # MAV_TYPE_GCS, AUTOPILOT_INVALID
                self._next_heartbeat = time.monotonic() + 0.5
            msg = self.conn.recv_match(type=want, blocking=True, timeout=0.2)
            if msg is None or msg.get_srcComponent() != COMPANION:
                continue
            if all(getattr(msg, k) == v for k, v in fields.items()):
                return msg
        raise TimeoutError(f"no {want} {fields} from component {COMPANION} in {timeout_s} s")

    def statustext(self, timeout_s: float) -> str:
        """The next text from the companion, its MAVLink 2 chunks joined (as QGC does)."""
        parts = [self.recv("STATUSTEXT", timeout_s)]
        while parts[-1].id != 0 and len(parts[-1].text) == 50:
            parts.append(self.recv("STATUSTEXT", timeout_s, id=parts[0].id))
        return " ".join("".join(p.text for p in parts).split())

    def ask(self, send: Callable[[], None], want: str, **fields: Any) -> Any:
        """Send until answered, as QGC does: a companion that has not yet heard its
        autopilot (so does not know its system ID) cannot tell the request is for it."""
        for _ in range(10):
            send()
            try:
                return self.recv(want, 2.0, **fields)
            except TimeoutError:
                continue
        raise TimeoutError(f"no {want} {fields} after 10 requests")

    def param_list(self) -> dict[str, float]:
        first = self.ask(lambda: self.conn.mav.param_request_list_send(1, 0), "PARAM_VALUE")
        values = {first.param_id: first.param_value}
        while len(values) < first.param_count:  # sent in one burst: no resend needed
            msg = self.recv("PARAM_VALUE", 10.0)
            assert msg.param_type == REAL32 and msg.param_count == first.param_count
            values[msg.param_id] = msg.param_value
        return values

    def param_set(self, name: str, value: float) -> float:
        send = lambda: self.conn.mav.param_set_send(1, COMPANION, name.encode(), value, REAL32)  # noqa: E731
        return float(self.ask(send, "PARAM_VALUE", param_id=name).param_value)

    def param_read(self, name: str) -> float:
        send = lambda: self.conn.mav.param_request_read_send(1, COMPANION, name.encode(), -1)  # noqa: E731
        return float(self.ask(send, "PARAM_VALUE", param_id=name).param_value)


def _config(path: Path, sim: LiveSim, state: Path, min_score: float) -> Path:
    path.write_text(
        f'[vehicle]\nurl = "{sim.vehicle_url}"\n[hq]\nurl = ""\n'
        f'[camera]\nsource = "{sim.camera_source}"\n[paths]\nstate_dir = "{state}"\n'
        + f"[detector]\nmin_score = {min_score}\n"
    )
    return path


def _run(cfg: Path, log_path: Path) -> subprocess.Popen[bytes]:
    env = {k: v for k, v in os.environ.items() if k not in ("NOTIFY_SOCKET", "WATCHDOG_USEC")}
    with log_path.open("ab") as log:
        return subprocess.Popen(
            [sys.executable, "-m", "companion.commands.cli", "run", "--config", str(cfg)],
            stdout=log,
            stderr=subprocess.STDOUT,
            env=env,
        )


def _stop(proc: subprocess.Popen[bytes]) -> int:
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
    return proc.wait(timeout=15)


@pytest.fixture
def sim() -> Iterator[LiveSim]:
    with LiveSim(preset("light")) as live:
        yield live


@pytest.mark.slow
def test_parameters_round_trip_with_a_pymavlink_ground_station(
    tmp_path: Path, sim: LiveSim
) -> None:
    state, log_path = tmp_path / "state", tmp_path / "companion.log"
    cfg = _config(tmp_path / "companion.toml", sim, state, 0.5)
    gcs = Gcs(sim.ground_url)
    proc = _run(cfg, log_path)
    try:
        gcs.recv("HEARTBEAT", 30.0)  # the companion is up, and the rover knows both routes
        listed = gcs.param_list()
        assert listed == pytest.approx(
            {
                "RC_DET_MIN_SCORE": 0.5,
                "RC_UPD_MIN_S": 5.0,
                "RC_ANN_SEV": 5,
                "RC_VID_ON": 1,
                "RC_VID_KBPS": 1000.0,
                "RC_LOOK_ON": 0,
            }
        )
        assert gcs.param_set("RC_DET_MIN_SCORE", 0.7) == pytest.approx(0.7)
        assert gcs.param_set("RC_UPD_MIN_S", 2.5) == pytest.approx(2.5)
        # Refused like a bad config value: the answer carries the value in force,
        # and people are told why.
        assert gcs.param_set("RC_DET_MIN_SCORE", 1.5) == pytest.approx(0.7)
        why = gcs.statustext(10.0)
        assert why.startswith("R1 RC_DET_MIN_SCORE = 1.5 refused") and "[0, 1]" in why, why
        assert gcs.param_read("RC_DET_MIN_SCORE") == pytest.approx(0.7)
        assert _stop(proc) == 0
        proc = _run(cfg, log_path)  # a restart keeps what the ground set
        gcs.recv("HEARTBEAT", 30.0)
        assert gcs.param_read("RC_DET_MIN_SCORE") == pytest.approx(0.7)
        assert gcs.param_read("RC_UPD_MIN_S") == pytest.approx(2.5)
        assert _stop(proc) == 0
        _config(cfg, sim, state, 0.6)  # the operator edits the config file: it wins
        proc = _run(cfg, log_path)
        gcs.recv("HEARTBEAT", 30.0)
        assert gcs.param_read("RC_DET_MIN_SCORE") == pytest.approx(0.6)
        assert gcs.param_read("RC_UPD_MIN_S") == pytest.approx(2.5)
    finally:
        assert _stop(proc) == 0, log_path.read_text()[-3000:]
        gcs.close()
    assert "Traceback" not in log_path.read_text()
