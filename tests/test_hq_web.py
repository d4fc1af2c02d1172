"""rescue-hq console without a browser: its state, its access rules, its HTTP API.

The pure parts (ellipse, list order, path memory) are checked on values; the rest
against a real `rescue-hq` process (UDP and HTTP on 127.0.0.1, SQLite registry)
fed by hq.simrobot robots, over plain HTTP (urllib). The page itself is driven in
Chromium in test_hq_web_browser.py.
"""

from __future__ import annotations

import csv
import io
import json
import math
import socket
import sqlite3
import subprocess
import sys
import time
import urllib.error
import urllib.request
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

import npmfetch
from bench.hq_console import HqConsoleProcess, Mission
from fusion.types import TrackState, Urgency, VictimReport
from hq.records import (
    ACK_RESULT_REJECTED,
    Action,
    IncomingReport,
    OperatorAction,
    Robot,
    RobotStatus,
)
from hq.registry import Registry
from hq.view import HqVictim, hq_victims
from hq.web import assets
from hq.web.feed import Changes, picture_versions
from hq.web.notes import Notes
from hq.web.state import LiveRobots, Page, ellipse_95, robots_lost, snapshot

REPO = Path(__file__).resolve().parents[1]
TOKEN = "correct-horse-battery"


# -- pure parts -------------------------------------------------------------------------


def test_ellipse_axes_and_bearing() -> None:
    k = math.sqrt(5.991)
    e = ellipse_95(((4.0, 0.0), (0.0, 1.0)))  # σ 2 m north, 1 m east
    assert e["major_m"] == pytest.approx(2 * k, abs=1e-3)
    assert e["minor_m"] == pytest.approx(k, abs=1e-3)
    assert e["bearing_deg"] == pytest.approx(0.0)
    # the same ellipse turned 45° toward east: major axis along north-east
    c, s = math.cos(math.pi / 4), math.sin(math.pi / 4)
    nn, ne, ee = 4 * c * c + s * s, (4 - 1) * c * s, 4 * s * s + c * c
    e = ellipse_95(((nn, ne), (ne, ee)))
    assert e["bearing_deg"] == pytest.approx(45.0, abs=1e-6)
    assert e["major_m"] == pytest.approx(2 * k, abs=1e-3)


def _victim(hq_id: int, urgency: Urgency, first: float, state: TrackState) -> HqVictim:
    cov = ((1.0, 0.0), (0.0, 1.0))
    return HqVictim(
        hq_id, ((1, hq_id),), urgency, 50.0, state, 1.0, 2.0, 0.0, cov, 1.0,
        None, None, None, first, first + 5, 3, 0,
    )  # fmt: skip


def test_list_order_open_first_then_urgency_then_waiting_longest() -> None:
    victims = [
        _victim(1, Urgency.LIGHT, 100.0, TrackState.CONFIRMED),
        _victim(2, Urgency.CRITICAL, 300.0, TrackState.CONFIRMED),
        _victim(3, Urgency.CRITICAL, 200.0, TrackState.CONFIRMED),
        _victim(4, Urgency.CRITICAL, 50.0, TrackState.RESCUED),
        _victim(5, Urgency.MEDIUM, 400.0, TrackState.TENTATIVE),
    ]
    actions = [Action(7, 1, 4, OperatorAction.RESCUED, 60.0, 2, 61.0)]
    state = snapshot(victims, [], actions, [], {}, {}, 500.0, 5.0)
    assert [v["id"] for v in state["victims"]] == [3, 2, 5, 1, 4]
    rescued = state["victims"][-1]
    assert rescued["resolved"] is True
    assert rescued["actions"] == [
        {
            "seq": 7, "action": "rescued", "robot": 1, "created_unix_s": 60.0,
            "acked": True, "rejected": False, "why": None,
        }
    ]  # fmt: skip
    assert rescued["picture"] is None  # no picture: the page shows its placeholder


T_UNIX_S = 1_700_000_000.0


def _report(
    robot: int, victim: int, north_m: float, urgency: Urgency = Urgency.MEDIUM, **kw: Any
) -> VictimReport:
    fields: dict[str, Any] = {
        "victim_id": victim, "robot_sysid": robot, "state": TrackState.CONFIRMED,
        "urgency": urgency, "visibility_pct": 30.0, "north_m": north_m, "east_m": 10.0 * robot,
        "down_m": 0.0, "cov_ne_m2": ((0.25, 0.0), (0.0, 0.25)), "observations": 3,
        "first_seen_unix_s": T_UNIX_S - 10.0, "last_seen_unix_s": T_UNIX_S,
    }  # fmt: skip
    return VictimReport(**{**fields, **kw})


def test_the_page_state_is_updated_from_what_changed_and_equals_a_full_build(
    tmp_path: Path,
) -> None:
    path = tmp_path / "hq.sqlite"
    registry, notes = Registry(path), Notes(path)
    read = sqlite3.connect(f"file:{path}?mode=ro", uri=True, isolation_level=None)
    changes, page = Changes(read), Page()
    seq = iter(range(1, 10_000))

    def store(report: VictimReport, merged_into: int = 0) -> None:
        n = next(seq)
        registry.store_reports([IncomingReport(report, n, n, merged_into, 191, T_UNIX_S)])

    def updated() -> dict[str, Any]:
        """The page brought up to date from the changes, as the console does."""
        robots = registry.robots()
        changes.update(registry, notes, page, robots)
        page.set_robots(robots, {}, T_UNIX_S, 5.0)
        return dict(json.loads(page.json(T_UNIX_S, 5.0)))

    def full() -> dict[str, Any]:
        victims = hq_victims(registry)
        pictures = picture_versions(registry, victims)
        return snapshot(
            victims, registry.robots(), registry.actions(), notes.all(), {}, pictures,
            T_UNIX_S, 5.0,
        )  # fmt: skip

    def rebuilt_by(step: Any) -> int:
        """How many victims the update after ``step`` rebuilt; the page equals a full build."""
        before = changes.victims_built
        step()
        assert updated() == full()
        return changes.victims_built - before

    try:
        for robot in (1, 2, 3):
            for victim in range(1, 11):
                store(_report(robot, victim, 10.0 * victim))
        assert rebuilt_by(lambda: None) == 30
        assert rebuilt_by(lambda: None) == 0  # nothing changed: nothing rebuilt
        assert rebuilt_by(lambda: store(_report(2, 5, 50.5, Urgency.CRITICAL))) == 1
        hq_id = next(
            v["id"] for v in full()["victims"] if v["sources"] == [{"robot": 2, "victim_id": 5}]
        )
        assert rebuilt_by(lambda: notes.add(hq_id, "voices heard")) == 1
        seq_rescued = registry.add_action(2, 5, OperatorAction.RESCUED)
        assert rebuilt_by(lambda: None) == 1  # the action being sent
        assert rebuilt_by(lambda: registry.ack_action(seq_rescued, T_UNIX_S, 2)) == 1
        assert page_victim(updated(), hq_id)["actions"][0]["rejected"] is True
        assert rebuilt_by(lambda: registry.store_picture(2, 5, 9, b"\xff\xd8jpeg", T_UNIX_S)) == 1
        # robot 3 finds its victim 6 is its victim 7: the two HQ victims become one
        merged = _report(3, 6, 70.0, state=TrackState.MERGED)
        assert rebuilt_by(lambda: store(merged, merged_into=7)) == 1
        assert len(updated()["victims"]) == 29
    finally:
        read.close()
        notes.close()
        registry.close()


def page_victim(state: dict[str, Any], hq_id: int) -> dict[str, Any]:
    return dict(next(v for v in state["victims"] if v["id"] == hq_id))


def test_path_keeps_its_shape_in_bounded_memory() -> None:
    live = LiveRobots(path_step_m=0.5, max_path_points=100)
    for i in range(1000):
        live.position(2, 0.1 * i, 0.0, 1000.0 + i)  # 0.1 m steps: one point per 0.5 m
    live.position(2, float("nan"), 0.0, 3000.0)  # ignored
    track = live.tracks()[2]
    assert len(track.path) <= 100
    assert track.path[0] == (0.0, 0.0)
    assert track.north_m == pytest.approx(99.9)
    assert track.path[-1][0] > 99.0  # the newest part is kept at full detail


def test_link_lost_after_the_timeout() -> None:
    live = LiveRobots()
    robots = [
        Robot(1, 191, 0.0, 100.0, None, None, None),
        Robot(2, 191, 0.0, 100.0, None, None, None),
    ]
    live.heard(1, 108.0)  # a heartbeat of robot 1's, not stored in the registry
    live.heard(255, 90.0)  # a ground station, not a robot: never "lost"
    assert robots_lost(robots, live, 110.0, 5.0) == frozenset({2})


def test_a_robots_status_reaches_the_page_as_json() -> None:
    status = RobotStatus(30.0, 9.5, 1.0, 80.0, 0, 2, 1, 3)
    robots = [Robot(1, 191, 0.0, 100.0, status, 100.0, None)]
    state = json.loads(json.dumps(snapshot([], robots, [], [], {}, {}, 101.0, 5.0)))
    assert state["robots"][0]["status"]["fps"] == 9.5
    assert state["robots"][0]["status"]["outbox_pending"] == 3


def test_npm_tarball_integrity_is_checked() -> None:
    with pytest.raises(npmfetch.FetchError, match="integrity"):
        npmfetch.check_integrity(assets.LEAFLET, b"not the leaflet tarball")


def test_altered_asset_is_named(tmp_path: Path) -> None:
    (tmp_path / "leaflet.js").write_text("alert('not leaflet')")
    problems = assets.verify(tmp_path)
    assert len(problems) == len(assets.ASSETS)
    assert any("leaflet.js is missing or altered" in p for p in problems)


def test_assets_verify_names_what_is_missing(tmp_path: Path) -> None:
    cmd = [sys.executable, "-m", "hq.cli", "assets", "verify", "--dir", str(tmp_path)]
    done = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=30)
    assert done.returncode == 2
    assert "leaflet.js is missing or altered: run `rescue-hq assets fetch`" in done.stderr


# -- configuration ----------------------------------------------------------------------


def _run_hq(*args: str) -> subprocess.CompletedProcess[str]:
    cmd = [sys.executable, "-m", "hq.cli", "--listen", "udpin:127.0.0.1:0", *args]
    return subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=30)


def test_network_address_without_token_refuses_to_start(tmp_path: Path) -> None:
    done = _run_hq("--db", str(tmp_path / "a.sqlite"), "--web", "0.0.0.0:0", "--duration-s", "5")
    assert done.returncode == 2
    assert "reachable from the network" in done.stderr
    assert "--web-token-file" in done.stderr
    assert "Traceback" not in done.stderr
    assert not (tmp_path / "a.sqlite").exists()  # refused before anything was made


def test_short_token_refuses_to_start(tmp_path: Path) -> None:
    token = tmp_path / "token"
    token.write_text("short\n")
    done = _run_hq(
        "--db", str(tmp_path / "a.sqlite"), "--web", "0.0.0.0:0", "--web-token-file", str(token),
        "--duration-s", "5",
    )  # fmt: skip
    assert done.returncode == 2
    assert "at least 12" in done.stderr


def test_console_address_in_use_exits_1(tmp_path: Path) -> None:
    with socket.create_server(("127.0.0.1", 0)) as taken:
        port = taken.getsockname()[1]
        done = _run_hq(
            "--db", str(tmp_path / "a.sqlite"), "--web", f"127.0.0.1:{port}", "--duration-s", "5"
        )  # fmt: skip
    assert done.returncode == 1
    assert f"cannot listen on 127.0.0.1:{port}" in done.stderr
    assert "Traceback" not in done.stderr


# -- HTTP against a running HQ ----------------------------------------------------------


def _request(
    url: str, *, data: Any = None, headers: dict[str, str] | None = None, method: str | None = None
) -> tuple[int, bytes, Any]:
    body = (
        None if data is None else (data if isinstance(data, bytes) else json.dumps(data).encode())
    )
    req = urllib.request.Request(url, data=body, headers=headers or {}, method=method)
    opener = urllib.request.build_opener(_NoRedirect)
    try:
        with opener.open(req, timeout=10) as resp:
            return resp.status, resp.read(), resp.headers
    except urllib.error.HTTPError as exc:
        return exc.code, exc.read(), exc.headers


class _NoRedirect(urllib.request.HTTPRedirectHandler):
    def redirect_request(self, *_args: Any, **_kw: Any) -> None:
        return None


@pytest.fixture
def hq_token(tmp_path: Path) -> Iterator[tuple[HqConsoleProcess, Mission]]:
    token_file = tmp_path / "token"
    token_file.write_text(TOKEN + "\n")
    hq = HqConsoleProcess(tmp_path, "--web-token-file", str(token_file))
    mission = Mission(hq.address, (1,))
    try:
        yield hq, mission
    finally:
        mission.close()
        assert hq.stop() == 0, hq.stderr  # SIGTERM with pages open: a clean exit


def test_requests_without_the_token_are_refused(hq_token: tuple[HqConsoleProcess, Mission]) -> None:
    hq, mission = hq_token
    mission.report(1, 5, 3.0, 4.0, Urgency.CRITICAL)
    url = hq.url
    for path in ("api/state", "api/events", "export/victims.csv", "vendor/leaflet.js"):
        status, _, headers = _request(url + path)
        assert status == 401, path
    status, _, _ = _request(url + "api/victims/1/action", data={"action": "rescued"})
    assert status == 401
    status, _, _ = _request(
        url + "api/state", headers={"Authorization": "Bearer wrong-token-wrong"}
    )
    assert status == 401
    status, page, _ = _request(url)
    assert status == 401 and b'name="token"' in page  # the sign-in form
    status, page, _ = _request(url + "login", data=b"token=nope")
    assert status == 401 and b"wrong token" in page
    # the right token: by header, and by the sign-in form's cookie
    status, body, _ = _request(url + "api/state", headers={"Authorization": f"Bearer {TOKEN}"})
    assert status == 200 and json.loads(body)["victims"][0]["sources"][0]["victim_id"] == 5
    status, _, headers = _request(url + "login", data=f"token={TOKEN}".encode())
    assert status == 303
    cookie = headers["Set-Cookie"]
    assert "HttpOnly" in cookie and "SameSite=strict" in cookie
    status, page, _ = _request(url, headers={"Cookie": cookie.split(";")[0]})
    assert status == 200 and b"/static/console.js" in page
    with pytest.raises(TimeoutError):  # the refused action was not recorded, not sent
        mission.robots[1].wait_for("RESCUE_OPERATOR_ACTION", 1.0)


@pytest.fixture
def hq_open(tmp_path: Path) -> Iterator[tuple[HqConsoleProcess, Mission]]:
    hq = HqConsoleProcess(tmp_path, "--origin", "47.397742,8.545594,488", "--link-timeout-s", "1.0")
    mission = Mission(hq.address, (1, 2))
    try:
        yield hq, mission
    finally:
        mission.close()
        assert hq.stop() == 0, hq.stderr  # SIGTERM with pages open: a clean exit


def _state(hq: HqConsoleProcess) -> dict[str, Any]:
    status, body, _ = _request(hq.url + "api/state")
    assert status == 200
    return dict(json.loads(body))


def _wait_state(hq: HqConsoleProcess, test: Any, what: str, timeout_s: float = 5.0) -> Any:
    deadline = time.monotonic() + timeout_s
    while True:
        state = _state(hq)
        if test(state):
            return state
        if time.monotonic() > deadline:
            raise AssertionError(f"no {what} within {timeout_s} s: {state}")
        time.sleep(0.05)


def test_action_from_the_console_reaches_the_robot_and_its_ack_shows(
    hq_open: tuple[HqConsoleProcess, Mission],
) -> None:
    hq, mission = hq_open
    mission.report(2, 17, 6.0, -3.0, Urgency.MEDIUM)
    hq_id = _wait_state(hq, lambda s: s["victims"], "victim")["victims"][0]["id"]
    status, body, _ = _request(
        hq.url + f"api/victims/{hq_id}/action",
        data={"action": "false_alarm"},
        headers={"Origin": hq.url.rstrip("/")},
    )
    assert status == 200
    seq = json.loads(body)["action_seqs"][0]
    action = mission.robots[2].wait_for("RESCUE_OPERATOR_ACTION", 5.0, victim_id=17).msg
    assert action.action == 2 and action.action_seq == seq  # FALSE_ALARM, as recorded
    mission.ack(2, action)
    state = _wait_state(
        hq, lambda s: s["victims"][0]["actions"] and s["victims"][0]["actions"][0]["acked"], "ack"
    )
    assert state["victims"][0]["state"] == "FALSE_ALARM"


def test_an_action_the_robot_rejects_shows_as_rejected_with_the_reason(
    hq_open: tuple[HqConsoleProcess, Mission],
) -> None:
    hq, mission = hq_open
    mission.report(1, 8, 4.0, 2.0, Urgency.CRITICAL)
    hq_id = _wait_state(hq, lambda s: s["victims"], "victim")["victims"][0]["id"]
    status, _, _ = _request(hq.url + f"api/victims/{hq_id}/action", data={"action": "rescued"})
    assert status == 200
    action = mission.robots[1].wait_for("RESCUE_OPERATOR_ACTION", 5.0, victim_id=8).msg
    # the robot no longer knows that victim (its state was reset): REJECTED
    mission.ack(1, action, result=ACK_RESULT_REJECTED)
    state = _wait_state(hq, lambda s: s["victims"][0]["actions"][0]["rejected"], "the rejection")
    victim = state["victims"][0]
    assert victim["state"] == "CONFIRMED" and not victim["resolved"]  # still to be rescued
    answer = victim["actions"][0]
    assert answer["acked"] is False  # never "acknowledged ✓"
    assert "REJECTED" in answer["why"] and "not applied" in answer["why"]


def test_bad_actions_and_notes_get_clear_answers(hq_open: tuple[HqConsoleProcess, Mission]) -> None:
    hq, mission = hq_open
    mission.report(1, 3, 1.0, 1.0)
    hq_id = _wait_state(hq, lambda s: s["victims"], "victim")["victims"][0]["id"]
    cases = [
        (f"api/victims/{hq_id}/action", {"action": "delete"}, 400, "action must be one of"),
        (f"api/victims/{hq_id}/action", b"{not json", 400, "not JSON"),
        ("api/victims/999/action", {"action": "rescued"}, 404, "no HQ victim 999"),
        (f"api/victims/{hq_id}/note", {"text": "   "}, 400, "needs some text"),
        (f"api/victims/{hq_id}/note", {"text": "x" * 501}, 400, "at most 500"),
    ]
    for path, data, code, text in cases:
        status, body, _ = _request(hq.url + path, data=data)
        assert status == code, path
        assert text in json.loads(body)["error"]
    status, _, _ = _request(
        hq.url + f"api/victims/{hq_id}/action",
        data={"action": "rescued"},
        headers={"Origin": "http://evil.example"},
    )
    assert status == 403  # another site's page cannot press the buttons
    status, body, _ = _request(hq.url + f"victims/{hq_id}/picture")
    assert status == 404 and "no robot has sent one" in json.loads(body)["error"]
    status, _, _ = _request(hq.url + f"api/victims/{hq_id}/note", data={"text": "voices heard"})
    assert status == 200
    state = _wait_state(hq, lambda s: s["victims"][0]["notes"], "note")
    assert state["victims"][0]["notes"][0]["text"] == "voices heard"


def test_exports_download(hq_open: tuple[HqConsoleProcess, Mission]) -> None:
    hq, mission = hq_open
    mission.report(1, 1, 10.0, 0.0, Urgency.CRITICAL)
    mission.report(2, 1, -5.0, 20.0, Urgency.LIGHT)
    _wait_state(hq, lambda s: len(s["victims"]) == 2, "two victims")
    status, body, headers = _request(hq.url + "export/victims.csv")
    assert status == 200 and "attachment" in headers["Content-Disposition"]
    rows = list(csv.DictReader(io.StringIO(body.decode())))
    assert sorted(r["urgency"] for r in rows) == ["CRITICAL", "LIGHT"]
    assert all(r["lat_deg"].startswith("47.39") for r in rows)  # placed by --origin
    status, body, _ = _request(hq.url + "export/victims.geojson")
    assert status == 200 and len(json.loads(body)["features"]) == 2
    status, body, _ = _request(hq.url + "export/victims.kml")
    assert status == 200 and body.count(b"<Placemark") == 2
    status, _, _ = _request(hq.url + "export/passwords.txt")
    assert status == 404


def test_live_events_carry_news_and_lost_links(hq_open: tuple[HqConsoleProcess, Mission]) -> None:
    hq, mission = hq_open
    mission.drive(5.0)
    with urllib.request.urlopen(hq.url + "api/events", timeout=10) as stream:

        def next_state(test: Any, what: str) -> dict[str, Any]:
            deadline = time.monotonic() + 5.0
            while time.monotonic() < deadline:
                line = stream.readline().decode()
                if line.startswith("data: "):
                    state = dict(json.loads(line[6:]))
                    if test(state):
                        return state
            raise AssertionError(f"no event with {what}")

        first = next_state(lambda s: s["robots"], "robots")
        robot1 = next(r for r in first["robots"] if r["sysid"] == 1)
        assert robot1["position"] == {"north_m": 5.0, "east_m": -30.0}
        assert len(robot1["path"]) >= 2
        mission.report(1, 42, 2.0, 2.0, Urgency.CRITICAL)
        state = next_state(lambda s: s["victims"], "the new victim")
        assert state["victims"][0]["sources"] == [{"robot": 1, "victim_id": 42}]
        assert state["victims"][0]["lat_deg"] == pytest.approx(47.39776, abs=1e-4)
        # robots stop talking: their links show as lost, then back when heard again
        state = next_state(lambda s: all(r["link_lost"] for r in s["robots"]), "lost links")
        mission.status([2])
        state = next_state(
            lambda s: [r["sysid"] for r in s["robots"] if not r["link_lost"]] == [2],
            "robot 2 back",
        )
