"""What a newcomer meets first: help texts, check-config's pre-flight of the
devices a config names, and what ``run`` says while no autopilot answers."""

from __future__ import annotations

import argparse
import os
import pty
import signal
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from companion.commands.cli import _parser

CLI = [sys.executable, "-m", "companion.commands.cli"]


def _subparsers(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    return {}


def test_every_flag_is_explained_and_no_help_shows_raw_markup() -> None:
    parser = _parser()
    parsers = {"": parser, **_subparsers(parser)}
    assert set(parsers) == {"", "check-config", "run", "replay", "detect", "models"}
    for name, p in parsers.items():
        for action in p._actions:
            if isinstance(action, argparse._SubParsersAction | argparse._HelpAction):
                continue
            assert action.help and action.help != argparse.SUPPRESS, (name, action.dest)
        text = subprocess.run(
            [*CLI, *([name] if name else []), "--help"],
            capture_output=True,
            text=True,
            timeout=60,
            check=True,
        ).stdout
        assert "`" not in text, (name, text)


def _config(tmp_path: Path, camera: str, vehicle: str) -> Path:
    cfg = tmp_path / "c.toml"
    cfg.write_text(
        f'[vehicle]\nurl = "{vehicle}"\n[camera]\nsource = "{camera}"\n'
        f'[detector]\nbackend = "classic"\n[paths]\nstate_dir = "{tmp_path / "state"}"\n'
    )
    return cfg


def _check(cfg: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [*CLI, "check-config", "--config", str(cfg)], capture_output=True, text=True, timeout=60
    )


@pytest.mark.parametrize(
    ("camera", "vehicle", "expected"),
    [
        ("device:57", "udpin:127.0.0.1:14550", "no such camera device /dev/video57"),
        ("/dev/video57", "udpin:127.0.0.1:14550", "no such camera device /dev/video57"),
        ("frames:/nonexistent/frames", "udpin:127.0.0.1:14550", "no such frames folder"),
        ("sim", "serial:/dev/ttyNOPE57:921600", "no such serial port /dev/ttyNOPE57"),
    ],
)
def test_check_config_fails_for_a_device_that_is_not_there(
    tmp_path: Path, camera: str, vehicle: str, expected: str
) -> None:
    result = _check(_config(tmp_path, camera, vehicle))
    assert result.returncode == 2, result.stdout
    assert expected in result.stderr and "Traceback" not in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1


def test_check_config_passes_when_the_devices_are_there(tmp_path: Path) -> None:
    frames = tmp_path / "frames"
    frames.mkdir()
    master, slave = pty.openpty()  # a real serial device path
    try:
        result = _check(_config(tmp_path, f"frames:{frames}", f"serial:{os.ttyname(slave)}:57600"))
    finally:
        os.close(master)
        os.close(slave)
    assert result.returncode == 0, result.stderr
    assert "config ok" in result.stdout


def test_run_without_an_autopilot_says_what_it_waits_for_and_where(tmp_path: Path) -> None:
    frames = tmp_path / "frames"
    frames.mkdir()
    cv2.imwrite(str(frames / "1700000000000000.jpg"), np.full((480, 640, 3), 90, np.uint8))
    cfg = _config(tmp_path, f"frames:{frames}", "udpin:127.0.0.1:0")
    log = tmp_path / "log.txt"
    with log.open("wb") as out:
        proc = subprocess.Popen(
            [*CLI, "run", "--config", str(cfg)], stdout=out, stderr=subprocess.STDOUT
        )
    try:
        end = time.monotonic() + 30.0
        while "waiting for the autopilot" not in log.read_text() and time.monotonic() < end:
            assert proc.poll() is None, log.read_text()
            time.sleep(0.2)
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=20)
    line = next(x for x in log.read_text().splitlines() if "waiting for the autopilot" in x)
    assert "HEARTBEAT" in line and "udpin:127.0.0.1:0" in line
    assert "listening on UDP 127.0.0.1:0 (port" in line


def test_the_licence_is_an_spdx_string_that_pip_installs_without_a_warning() -> None:
    # A TOML table (license = { text = "MIT" }) makes setuptools >= 77 warn at every
    # pip install; the SPDX string needs setuptools >= 77 to build.
    import tomllib

    root = Path(__file__).resolve().parents[1]
    meta = tomllib.loads((root / "pyproject.toml").read_text())
    assert meta["project"]["license"] == "MIT"
    assert "setuptools>=77" in meta["build-system"]["requires"]
