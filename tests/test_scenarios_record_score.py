"""Recording (tlog + frames on one clock, camera config, ground truth), scoring, the
camera server's wire format, and the CLI."""

from __future__ import annotations

import json
import math
import signal
import socket
import struct
import subprocess
import sys
import threading
import time
import tomllib
from pathlib import Path

import cv2
import numpy as np
import pytest
from pymavlink import mavutil

from companion.calibration import camera_model
from companion.config_load import config_from_dict
from fusion.types import Urgency
from scenarios.camera import default_camera
from scenarios.camserver import HEADER, CameraServer
from scenarios.cli import main
from scenarios.motion import Trajectory, TruePose, route_of
from scenarios.record import record
from scenarios.render import Renderer
from scenarios.score import (
    GroundTruth,
    ReportedVictim,
    ScoreInputError,
    TrueVictim,
    format_score,
    load_report,
    score,
    truth_from_dict,
)
from scenarios.world import preset

START = 1_700_000_000.0


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("rec")
    record(preset("mixed"), out, duration_s=3.0, start_unix_s=START)
    return out


def _tlog(path: Path) -> list:
    conn = mavutil.mavlink_connection(str(path), dialect="common")
    msgs = []
    while (m := conn.recv_match()) is not None:
        msgs.append(m)
    conn.close()
    return msgs


def test_tlog_is_readable_and_on_the_frames_clock(recording: Path) -> None:
    msgs = _tlog(recording / "mission.tlog")
    kinds = {m.get_type() for m in msgs}
    assert {
        "HEARTBEAT",
        "ATTITUDE",
        "LOCAL_POSITION_NED",
        "GLOBAL_POSITION_INT",
        "SYSTEM_TIME",
    } <= kinds
    assert {"GPS_GLOBAL_ORIGIN", "HOME_POSITION", "SIM_STATE"} <= kinds
    stamps = [m._timestamp for m in msgs]
    assert stamps == sorted(stamps) and stamps[0] >= START and stamps[-1] <= START + 3.0
    # SYSTEM_TIME carries the rover's wall clock: it equals the tlog's own stamp.
    for m in msgs:
        if m.get_type() == "SYSTEM_TIME":
            assert m.time_unix_usec / 1e6 == pytest.approx(m._timestamp, abs=1e-6)
    frames = sorted(int(p.stem) for p in (recording / "frames").glob("*.jpg"))
    assert len(frames) == 30  # 3 s at 10 fps
    assert np.allclose(np.diff(frames), 100_000)
    assert frames[0] >= START * 1e6 and frames[-1] <= (START + 3.0) * 1e6
    image = cv2.imread(str(recording / "frames" / f"{frames[0]}.jpg"))
    assert image.shape == (480, 640, 3)


def test_tlog_pose_is_the_true_pose_plus_small_error(recording: Path) -> None:
    traj = Trajectory.for_world(preset("mixed"))
    for m in _tlog(recording / "mission.tlog"):
        if m.get_type() == "LOCAL_POSITION_NED":
            true = traj.pose_at(m._timestamp - START)
            # Drift (<= 8 cm) plus noise (1 cm, so 5 sigma) bounds the estimate's error.
            assert math.hypot(m.x - true.north_m, m.y - true.east_m) < 0.14


def test_camera_toml_loads_as_the_rendered_camera(recording: Path) -> None:
    data = tomllib.loads((recording / "camera.toml").read_text())
    config = config_from_dict(data)
    assert camera_model(config.camera) == default_camera()
    assert config.camera.source.startswith("frames:")


def test_ground_truth_lists_victims_and_first_sight(recording: Path) -> None:
    truth = json.loads((recording / "ground_truth.json").read_text())
    world = preset("mixed")
    assert [v["victim_id"] for v in truth["victims"]] == [v.victim_id for v in world.victims]
    for got, v in zip(truth["victims"], world.victims, strict=True):
        assert got["urgency"] == v.urgency.name
        assert got["visibility_pct"] == pytest.approx(v.visibility_pct, abs=1e-3)
    seen = [v for v in truth["victims"] if v["first_in_view_unix_s"] is not None]
    assert seen and all(START <= v["first_in_view_unix_s"] <= START + 3.0 for v in seen)
    assert truth["route_ne_m"] == [list(p) for p in route_of(world)]


def test_recording_is_deterministic(tmp_path: Path, recording: Path) -> None:
    record(preset("mixed"), tmp_path, duration_s=3.0, start_unix_s=START)
    assert (tmp_path / "mission.tlog").read_bytes() == (recording / "mission.tlog").read_bytes()
    names = sorted(p.name for p in (tmp_path / "frames").iterdir())
    assert names == sorted(p.name for p in (recording / "frames").iterdir())
    for name in names[::7]:
        assert (tmp_path / "frames" / name).read_bytes() == (
            recording / "frames" / name
        ).read_bytes()


# -- scoring ------------------------------------------------------------------------


def _truth() -> GroundTruth:
    return GroundTruth(
        (
            TrueVictim(1, 2.0, 2.0, Urgency.LIGHT, first_in_view_unix_s=100.0),
            TrueVictim(2, 6.0, 5.0, Urgency.MEDIUM, first_in_view_unix_s=110.0),
            # Buried: only a hand at (9.8, 3.6) shows, 0.9 m from the body centre.
            TrueVictim(3, 9.0, 3.2, Urgency.CRITICAL, 9.8, 3.6, first_in_view_unix_s=120.0),
            TrueVictim(4, 10.5, 7.0, Urgency.LIGHT, first_in_view_unix_s=None),
        ),
        view_known=True,
    )


def test_score_on_a_hand_made_case() -> None:
    reports = [
        ReportedVictim(11, Urgency.LIGHT, 2.1, 2.0, 101.0, 103.0),  # 0.1 m, right class
        ReportedVictim(12, Urgency.LIGHT, 6.0, 5.4, 112.0),  # 0.4 m, wrong class
        ReportedVictim(13, Urgency.LIGHT, 2.5, 2.3, 105.0),  # a duplicate of victim 1
        ReportedVictim(14, Urgency.CRITICAL, 9.85, 3.65, 125.0),  # at the hand: 0.07 m
        ReportedVictim(15, Urgency.MEDIUM, 4.0, 7.5, 130.0),  # nothing there
    ]
    r = score(_truth(), reports)
    assert r.recall == pytest.approx(3 / 4)
    assert r.missed_ids == (4,)
    assert r.false_victims == 1
    assert r.duplicates == {1: 1}
    assert {(m.true_id, m.reported_id) for m in r.matches} == {(1, 11), (2, 12), (3, 14)}
    assert r.error_median_m == pytest.approx(0.1)
    assert r.error_max_m == pytest.approx(0.4)
    assert r.error_p95_m == pytest.approx(0.1 + 0.9 * 0.3)  # numpy's linear percentile
    assert r.urgency_accuracy == pytest.approx(2 / 3)
    assert sorted(r.time_to_report_s) == pytest.approx([2.0, 3.0, 5.0])  # 103-100, 112-110, 125-120
    # Victim 4 never came into view: recall over the three that did is whole.
    assert r.never_in_view_ids == (4,)
    assert r.recall_in_view == 1.0
    assert "never in view: ids [4]" in format_score(r)


def test_recall_in_view_only_where_the_truth_records_the_views() -> None:
    victims = [
        {"victim_id": 1, "north_m": 1.0, "east_m": 1.0, "urgency": "LIGHT"},
        {"victim_id": 2, "north_m": 5.0, "east_m": 5.0, "urgency": "MEDIUM"},
    ]
    found = [ReportedVictim(9, Urgency.MEDIUM, 5.1, 5.0, 0.0)]
    # A truth without first_in_view_unix_s says nothing of what was seen.
    unknown = score(truth_from_dict({"victims": victims}), found)
    assert unknown.never_in_view_ids == () and unknown.recall_in_view is None
    # Recorded: victim 1 was seen and missed, victim 2 never seen yet found (a report
    # near a hidden body is a match, but not one of the victims in view).
    seen = [
        {**victims[0], "first_in_view_unix_s": 10.0},
        {**victims[1], "first_in_view_unix_s": None},
    ]
    known = score(truth_from_dict({"victims": seen}), found)
    assert known.recall == 0.5
    assert known.never_in_view_ids == (2,)
    assert known.recall_in_view == 0.0


def test_hungarian_prefers_the_globally_best_assignment() -> None:
    truth = GroundTruth(
        (TrueVictim(1, 0.0, 0.0, Urgency.LIGHT), TrueVictim(2, 1.2, 0.0, Urgency.LIGHT))
    )
    # Greedy would give report A (0.55 m from 1, 0.65 m from 2) to victim 1 and leave B,
    # 0.95 m from 1 and 2.15 m from 2, out; the optimum pairs A-2 and B-1.
    reports = [
        ReportedVictim(1, Urgency.LIGHT, 0.55, 0.0, 0.0),
        ReportedVictim(2, Urgency.LIGHT, -0.95, 0.0, 0.0),
    ]
    r = score(truth, reports)
    assert r.recall == 1.0 and r.false_victims == 0
    assert {(m.true_id, m.reported_id) for m in r.matches} == {(1, 2), (2, 1)}


def test_inside_95_ellipse_uses_the_reported_covariance() -> None:
    truth = GroundTruth(
        (TrueVictim(1, 0.0, 0.0, Urgency.LIGHT), TrueVictim(2, 5.0, 0.0, Urgency.LIGHT))
    )
    round_01 = ((0.01, 0.0), (0.0, 0.01))  # sigma 0.1 m
    long_north = ((0.09, 0.0), (0.0, 0.0025))  # sigma 0.3 m north, 0.05 m east
    reports = [
        # 0.2 m north: 4 sigma^2 inside a 0.1 m circle (5.99 is the 95 % bound)...
        ReportedVictim(1, Urgency.LIGHT, 0.2, 0.0, 0.0, cov_ne_m2=round_01),
        # ...but 0.2 m east of victim 2 is 16 sigma^2 in an ellipse long to the north.
        ReportedVictim(2, Urgency.LIGHT, 5.0, 0.2, 0.0, cov_ne_m2=long_north),
    ]
    r = score(truth, reports)
    d2 = {m.true_id: m.mahalanobis2 for m in r.matches}
    assert d2 == {1: pytest.approx(4.0), 2: pytest.approx(16.0)}
    assert r.inside_95_ellipse == 0.5
    # Reports without a covariance give no figure rather than a made-up one.
    bare = [ReportedVictim(1, Urgency.LIGHT, 0.2, 0.0, 0.0)]
    assert score(truth, bare).inside_95_ellipse is None


def test_empty_world_scores_false_victims_only() -> None:
    r = score(GroundTruth(()), [ReportedVictim(1, Urgency.LIGHT, 1.0, 1.0, 0.0)])
    assert r.recall is None and r.false_victims == 1 and r.urgency_accuracy is None


def test_bad_report_file_names_the_key(tmp_path: Path) -> None:
    path = tmp_path / "r.json"
    path.write_text(
        json.dumps(
            {
                "victims": [
                    {
                        "victim_id": 1,
                        "urgency": "SEVERE",
                        "north_m": 1,
                        "east_m": 2,
                        "first_seen_unix_s": 0,
                    }
                ]
            }
        )
    )
    with pytest.raises(ScoreInputError, match=r"victims\[0\]\.urgency = 'SEVERE'"):
        load_report(path)
    good = {"victim_id": 1, "urgency": "LIGHT", "north_m": 1, "east_m": 2}
    path.write_text(
        json.dumps({"victims": [{**good, "first_seen_unix_s": 0, "cov_ne_m2": [[1, 0], [0]]}]})
    )
    with pytest.raises(ScoreInputError, match=r"victims\[0\]\.cov_ne_m2 = .*2x2"):
        load_report(path)
    path.write_text("{not json")
    with pytest.raises(ScoreInputError, match="not valid JSON"):
        load_report(path)


def test_cli_record_then_score(tmp_path: Path) -> None:
    out = tmp_path / "m"
    cmd = [sys.executable, "-m", "scenarios.cli"]
    done = subprocess.run(
        [
            *cmd,
            "record",
            "--preset",
            "light",
            "--out",
            str(out),
            "--duration-s",
            "1",
            "--start-unix-s",
            str(START),
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr
    truth = json.loads((out / "ground_truth.json").read_text())
    v = truth["victims"][0]
    report = tmp_path / "report.json"
    report.write_text(
        json.dumps(
            {
                "victims": [
                    {
                        "victim_id": 7,
                        "urgency": v["urgency"],
                        "north_m": v["north_m"] + 0.3,
                        "east_m": v["east_m"],
                        "first_seen_unix_s": START + 0.5,
                        "extra": 1,
                    }
                ]
            }
        )
    )
    done = subprocess.run(
        [
            *cmd,
            "score",
            "--truth",
            str(out / "ground_truth.json"),
            "--victims",
            str(report),
            "--json",
        ],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 0, done.stderr
    figures = json.loads(done.stdout)
    assert figures["recall"] == 1.0 and figures["urgency_accuracy"] == 1.0
    # The distance is to the nearer of the body centre and the uncovered part's centroid.
    to_visible = math.hypot(
        v["north_m"] + 0.3 - v["visible_north_m"], v["east_m"] - v["visible_east_m"]
    )
    assert figures["error_median_m"] == pytest.approx(min(0.3, to_visible), abs=1e-6)
    bad = subprocess.run(
        [*cmd, "record", "--world", str(tmp_path / "none.toml"), "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert (
        bad.returncode == 2
        and "cannot read world file" in bad.stderr
        and "Traceback" not in bad.stderr
    )


# -- camera server ------------------------------------------------------------------


def _read_exact(sock: socket.socket, n: int) -> bytes:
    buf = b""
    while len(buf) < n:
        chunk = sock.recv(n - len(buf))
        if not chunk:
            raise AssertionError("camera server closed the connection")
        buf += chunk
    return buf


def test_camera_server_sends_length_time_jpeg_frames() -> None:
    world = preset("light")
    pose = TruePose(0.0, 4.3, 3.2, -0.1, 0.0, 0.0, 0.0)
    clock = iter(START + 0.1 * k for k in range(10_000))
    server = CameraServer(Renderer(world), lambda: (pose, next(clock)), fps=20.0).start()
    try:
        with socket.create_connection(server.address, timeout=10.0) as sock:
            stamps = []
            for _ in range(3):
                length, t_us = HEADER.unpack(_read_exact(sock, HEADER.size))
                jpeg = _read_exact(sock, length - 8)
                image = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR)
                assert image is not None and image.shape == (480, 640, 3)
                stamps.append(t_us)
            assert stamps == sorted(stamps) and len(set(stamps)) == 3
            assert all(t >= START * 1e6 for t in stamps)
    finally:
        server.close()
    assert struct.calcsize(">IQ") == HEADER.size == 12


def test_camera_server_keeps_accepting_after_a_failed_accept() -> None:
    """A client that vanishes while it connects makes accept() fail once (here the
    listener is made to fail, as a client reset before accept does): the next client
    still gets frames."""
    world = preset("light")
    pose = TruePose(0.0, 4.3, 3.2, -0.1, 0.0, 0.0, 0.0)
    clock = iter(START + 0.1 * k for k in range(10_000))
    server = CameraServer(Renderer(world), lambda: (pose, next(clock)), fps=20.0)
    real, failed = server._listener, threading.Event()

    class FailingOnce:
        def accept(self) -> tuple[socket.socket, object]:
            if not failed.is_set():
                failed.set()
                raise ConnectionAbortedError(103, "Software caused connection abort")
            return real.accept()

        def __getattr__(self, name: str) -> object:
            return getattr(real, name)

    server._listener = FailingOnce()  # type: ignore[assignment]
    server.start()
    try:
        assert failed.wait(5.0)
        with socket.create_connection(real.getsockname(), timeout=10.0) as sock:
            length, _t_us = HEADER.unpack(_read_exact(sock, HEADER.size))
            assert len(_read_exact(sock, length - 8)) == length - 8
    finally:
        server.close()


def test_camera_server_records_a_stretch_without_frames_sent() -> None:
    """The chaos mission's check that a running companion always gets frames reads
    these: no client for 2.5 s after the start is one silence, ended by the first
    frame sent; a client taking frames makes none; close() ends a pending one."""
    world = preset("light")
    pose = TruePose(0.0, 4.3, 3.2, -0.1, 0.0, 0.0, 0.0)
    clock = iter(START + 0.1 * k for k in range(10_000))
    server = CameraServer(Renderer(world), lambda: (pose, next(clock)), fps=20.0).start()
    started = time.monotonic()
    try:
        time.sleep(2.5)
        assert server.silences == []  # still open: ended by the next frame sent
        with socket.create_connection(server.address, timeout=10.0) as sock:
            for _ in range(5):
                length, _t_us = HEADER.unpack(_read_exact(sock, HEADER.size))
                _read_exact(sock, length - 8)
        assert len(server.silences) == 1
        s0, s1 = server.silences[0]
        assert abs(s0 - started) < 0.5 and 2.4 < s1 - s0 < 5.0
        time.sleep(2.5)  # the client is gone: a second silence, ended by close()
    finally:
        server.close()
    assert len(server.silences) == 2 and server.silences[1][1] - server.silences[1][0] > 2.0


def test_rover_stops_cleanly_on_sigterm_right_after_start() -> None:
    """A harness may stop the simulated rover the moment it is up: exit 0, promptly.
    (The handler race behind a hang is pinned deterministically in
    tests/test_companion_stopsignals.py; this run rarely hits its window.)"""
    with subprocess.Popen(
        [
            *(sys.executable, "-m", "scenarios.cli", "rover", "--preset", "empty"),
            *("--link", "udpin:127.0.0.1:0", "--camera-port", "0"),
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    ) as proc:
        try:
            assert proc.stdout is not None and proc.stderr is not None
            first = proc.stdout.readline()
            assert first.startswith("rover link 0: udpin:127.0.0.1:"), first
            proc.send_signal(signal.SIGTERM)
            code = proc.wait(timeout=10)
            assert code == 0, proc.stderr.read()
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()


def test_rover_serves_both_cameras_live() -> None:
    """``rescue-sim rover --camera-port 0 --thermal-port 0``: the colour camera's JPEGs
    and the thermal camera's 16-bit centi-kelvin PNGs, each on its own port with the
    same framing, stamped with the wall clock of the rover's true pose."""
    with subprocess.Popen(
        [
            *(sys.executable, "-m", "scenarios.cli", "rover", "--preset", "thermal_covered"),
            *("--link", "udpin:127.0.0.1:0", "--camera-port", "0", "--thermal-port", "0"),
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    ) as proc:
        try:
            assert proc.stdout is not None and proc.stderr is not None
            lines = [proc.stdout.readline() for _ in range(3)]
            assert lines[0].startswith("rover link 0: udpin:127.0.0.1:"), lines
            assert lines[1].startswith("camera: tcp 127.0.0.1:"), lines
            assert lines[2].startswith("thermal camera: tcp 127.0.0.1:"), lines
            colour_port, thermal_port = (int(line.rsplit(":", 1)[1]) for line in lines[1:])
            with socket.create_connection(("127.0.0.1", thermal_port), timeout=10.0) as sock:
                stamps = []
                for _ in range(3):
                    length, t_us = HEADER.unpack(_read_exact(sock, HEADER.size))
                    png = np.frombuffer(_read_exact(sock, length - 8), np.uint8)
                    words = cv2.imdecode(png, cv2.IMREAD_UNCHANGED)
                    assert words.dtype == np.uint16 and words.shape == (120, 160)
                    temps_c = words / 100.0 - 273.15
                    assert 10.0 < float(np.median(temps_c)) < 25.0  # the world's 18 °C room
                    stamps.append(t_us / 1e6)
                assert stamps == sorted(stamps) and len(set(stamps)) == 3
                assert abs(stamps[-1] - time.time()) < 5.0
            with socket.create_connection(("127.0.0.1", colour_port), timeout=10.0) as sock:
                length, _t_us = HEADER.unpack(_read_exact(sock, HEADER.size))
                jpeg = np.frombuffer(_read_exact(sock, length - 8), np.uint8)
                image = cv2.imdecode(jpeg, cv2.IMREAD_COLOR)
                assert image is not None and image.shape == (480, 640, 3)
            proc.send_signal(signal.SIGTERM)
            code = proc.wait(timeout=10)
            assert code == 0, proc.stderr.read()
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["world", "--seed", "-3"], "--seed: expected a whole number >= 0, got '-3'"),
        (["world", "--seed", "x"], "--seed"),
        (["record", "--preset", "light", "--out", "o", "--fps", "0"], "--fps: '0' is outside"),
        (["record", "--preset", "light", "--out", "o", "--fps", "nan"], "--fps: 'nan'"),
        (["record", "--preset", "light", "--out", "o", "--duration-s", "-5"], "--duration-s"),
        (["record", "--preset", "light", "--out", "o", "--start-unix-s", "-1"], "--start-unix"),
        (["score", "--truth", "t", "--victims", "v", "--gate-m", "0"], "--gate-m: '0'"),
        (["rover", "--preset", "light", "--link", "pty", "--time-scale", "inf"], "--time-scale"),
        (
            ["rover", "--preset", "light", "--link", "pty", "--camera-port", "70000"],
            "--camera-port",
        ),
        (
            ["rover", "--preset", "light", "--link", "pty", "--thermal-port", "-1"],
            "--thermal-port",
        ),
        (["demo", "--speed-m-s", "0"], "--speed-m-s: '0' is outside (0, 5]"),
        (["demo", "--duration-s", "inf"], "--duration-s: 'inf'"),
    ],
)
def test_cli_refuses_numbers_no_mission_can_use(
    args: list[str], needle: str, capsys: pytest.CaptureFixture[str]
) -> None:
    """A zero frame rate, a negative seed or duration, a NaN ended in a traceback (a
    division by zero, numpy's seed check, an empty tlog); argparse now names them."""
    with pytest.raises(SystemExit) as done:
        main(args)
    err = capsys.readouterr().err
    assert done.value.code == 2 and needle in err and "Traceback" not in err, err
