"""The systemd unit verifies and is hardened (exposure <= 2.5)."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
UNIT = ROOT / "systemd" / "rescue-companion.service"
INSTALLED_EXEC = "/opt/rescue-companion/venv/bin/rescue-companion"


@pytest.fixture
def analyze() -> str:
    path = shutil.which("systemd-analyze")
    assert path, "systemd-analyze is missing: `make` installs Debian's systemd package"
    return path


@pytest.fixture
def local_unit(tmp_path: Path) -> Path:
    """The unit with ExecStart pointing at this checkout's console script.

    verify checks that the executable exists; on the Pi it lives under /opt.
    """
    script = Path(sys.executable).parent / "rescue-companion"
    assert script.exists(), f"{script} missing: the package is not installed in this venv"
    unit = tmp_path / UNIT.name
    unit.write_text(UNIT.read_text().replace(INSTALLED_EXEC, str(script)))
    return unit


def test_unit_verifies(analyze: str, local_unit: Path) -> None:
    result = subprocess.run(
        [analyze, "verify", str(local_unit)], capture_output=True, text=True, timeout=60
    )
    own = [ln for ln in result.stderr.splitlines() if local_unit.name in ln]
    assert result.returncode == 0 and not own, result.stderr


def test_unit_exposure_is_at_most_2_5(analyze: str, local_unit: Path) -> None:
    result = subprocess.run(
        [analyze, "security", "--offline=yes", str(local_unit)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    match = re.search(r"Overall exposure level for \S+: (\d+\.\d+)", result.stdout)
    assert match, result.stdout[-2000:] + result.stderr
    assert float(match.group(1)) <= 2.5


def test_unit_is_notify_with_watchdog_and_no_restart_on_bad_config() -> None:
    text = UNIT.read_text()
    for line in (
        "Type=notify",
        "WatchdogSec=",
        "Restart=on-failure",
        "RestartPreventExitStatus=2",
        "StateDirectory=rescue-companion",
        "ConfigurationDirectory=rescue-companion",
        "ProtectSystem=strict",
        "NoNewPrivileges=yes",
        "DevicePolicy=closed",
        "SupplementaryGroups=dialout video",
    ):
        assert line in text, line
    assert INSTALLED_EXEC + " run --config /etc/rescue-companion/config.toml" in text
