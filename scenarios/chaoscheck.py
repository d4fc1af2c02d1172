"""What the chaos mission checks and shows: its result, the two databases read back.

``ChaosResult`` holds what a run of ``scenarios.chaos.run_chaos`` measured and
``figures()`` what BENCHMARKS.md shows; ``check`` fills in its failures from the
companion's state database and rescue-hq's registry, both opened read-only (the
programs may still run while ``companion_reported`` and ``hq_sources`` poll them).
"""

from __future__ import annotations

import json
import math
import sqlite3
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from fusion.types import TrackState
from hq.registry import Registry
from hq.view import hq_victims
from mavlink_io.dialect import RESCUE_VICTIM_REPORT_ID
from scenarios.radio import RadioLog
from scenarios.supervise import Supervised
from scenarios.world import World

CAMERA_GRACE_S = 30.0  # a companion's start (models, links) before frames must flow
MAX_SILENCE_S = 30.0  # the longest a settled companion may go without a frame
GATE_M = 1.0  # a reported victim within this of a true one is that person (bench.accuracy)
ACK_ACCEPTED, ACK_DUPLICATE = 0, 1


@dataclass
class ChaosResult:
    seed: int
    mission_s: float
    started_unix_s: float = 0.0
    total_s: float = 0.0
    drain_s: float | None = None  # None: the drain did not finish in time
    faults_done: dict[str, int] = field(default_factory=dict)
    disk_note: str = ""
    true_victims: int = 0
    true_confirmed: int = 0
    true_at_hq: int = 0
    companion_victims: int = 0
    false_victims: int = 0
    merged_victims: int = 0
    hq_duplicates: int = 0
    companion_duplicates: int = 0
    missing_at_hq: list[int] = field(default_factory=list)
    radio: RadioLog | None = None
    acked_not_stored: list[int] = field(default_factory=list)
    longest_wait_s: float | None = None
    confirmed_at_s: list[float] = field(default_factory=list)  # mission time of each
    longest_report_wait_s: float | None = None
    longest_silence_s: float = 0.0  # no frame for a companion running > CAMERA_GRACE_S
    companion_unplanned: int = 0
    companion_quick: int = 0
    hq_unplanned: int = 0
    hq_quick: int = 0
    tracebacks: int = 0
    failures: list[str] = field(default_factory=list)
    details: list[str] = field(default_factory=list)  # per victim, for the log

    def figures(self) -> dict[str, object]:
        r = self.radio
        reports = r.reports if r is not None else []
        acks = r.acks if r is not None else []
        good_acks = {a.seq for a in acks if a.result in (ACK_ACCEPTED, ACK_DUPLICATE)}
        return {
            "seed": self.seed,
            "mission length, s": round(self.mission_s),
            "run length with drain and stops, s": round(self.total_s),
            "victims: true / confirmed by the companion / at the HQ": (
                f"{self.true_victims} / {self.true_confirmed} / {self.true_at_hq}"
            ),
            "companion victim IDs reported (false / merged into another)": (
                f"{self.companion_victims} ({self.false_victims} / {self.merged_victims})"
            ),
            "duplicate HQ victims / duplicate companion IDs for one person": (
                f"{self.hq_duplicates} / {self.companion_duplicates}"
            ),
            "companion victims missing at the HQ": len(self.missing_at_hq),
            "radio datagrams lost down / up, %": (
                f"{r.to_ground.loss_pct:.1f} / {r.to_rover.loss_pct:.1f}"
                if r is not None
                else "n/a"
            ),
            "reports sent (transmissions) / distinct / resent": (
                f"{len(reports)} / {len({x.report_seq for x in reports})} / "
                f"{len(reports) - len({x.report_seq for x in reports})}"
            ),
            "reports acknowledged by the HQ (distinct) / acks sent / rejected": (
                f"{len(good_acks)} / {len(acks)} / "
                f"{sum(a.result not in (ACK_ACCEPTED, ACK_DUPLICATE) for a in acks)}"
            ),
            "acknowledged reports missing from the registry": len(self.acked_not_stored),
            "operator RESEND/actions sent by the HQ": r.actions if r is not None else 0,
            "companion SIGKILLs": self.faults_done.get("companion-kill", 0),
            "HQ SIGTERM / SIGKILL restarts": (
                f"{self.faults_done.get('hq-term', 0)} / {self.faults_done.get('hq-kill', 0)}"
            ),
            "autopilot reboots": self.faults_done.get("reboot", 0),
            "state disk filled": self.disk_note,
            "unplanned exits companion / HQ (of which quick)": (
                f"{self.companion_unplanned} ({self.companion_quick}) / "
                f"{self.hq_unplanned} ({self.hq_quick})"
            ),
            "longest wait of a confirmed victim for the HQ, s": (
                round(self.longest_wait_s, 1) if self.longest_wait_s is not None else "n/a"
            ),
            "victims confirmed at mission time, s": (
                ", ".join(f"{t:.0f}" for t in self.confirmed_at_s) or "none"
            ),
            "longest wait of any report (news) for the HQ, s": (
                round(self.longest_report_wait_s, 1)
                if self.longest_report_wait_s is not None
                else "n/a"
            ),
            f"longest time without a frame, companion up > {CAMERA_GRACE_S:.0f} s, s": round(
                self.longest_silence_s, 1
            ),
            "drain after the mission, s": round(self.drain_s, 1)
            if self.drain_s is not None
            else "timed out",
            "tracebacks in the logs": self.tracebacks,
            "checks": "all passed" if not self.failures else "FAILED: " + "; ".join(self.failures),
        }


def _read_only(path: Path) -> sqlite3.Connection:
    db = sqlite3.connect(f"file:{path}?mode=ro", uri=True, timeout=5.0)
    db.execute("PRAGMA query_only=1")
    return db


def companion_reported(state_db: Path) -> tuple[dict[int, list[Any]], int]:
    """The companion store's reported victims and the reports still in its outbox."""
    if not state_db.exists():
        return {}, 0
    db = _read_only(state_db)
    try:
        row = db.execute("SELECT value FROM kv WHERE key='reported'").fetchone()
        pending = db.execute(
            "SELECT COUNT(*) FROM outbox WHERE msgid=?", (RESCUE_VICTIM_REPORT_ID,)
        ).fetchone()[0]
    finally:
        db.close()
    reported = {int(k): v for k, v in json.loads(row[0]).items()} if row else {}
    return reported, int(pending)


def hq_sources(hq_db: Path, sysid: int) -> set[int]:
    if not hq_db.exists():
        return set()
    db = _read_only(hq_db)
    try:
        rows = db.execute("SELECT victim_id FROM sources WHERE robot_sysid=?", (sysid,)).fetchall()
    except sqlite3.OperationalError:  # not created yet
        return set()
    finally:
        db.close()
    return {int(r[0]) for r in rows}


def _near(points: list[tuple[float, float]], north_m: float, east_m: float) -> int:
    return sum(math.hypot(n - north_m, e - east_m) <= GATE_M for n, e in points)


def _listing(items: list[tuple[int, tuple[float, float]]], north_m: float, east_m: float) -> str:
    near = [
        f"{i} ({n:.2f}, {e:.2f})"
        for i, (n, e) in items
        if math.hypot(n - north_m, e - east_m) <= 2 * GATE_M
    ]
    return ", ".join(near) or "none"


def longest_silence_s(
    silences: list[tuple[float, float]], runs: list[tuple[float, float | None]]
) -> float:
    """The longest part of a camera silence (start, end) that falls in a run (start,
    end or None: still running) more than CAMERA_GRACE_S after its start."""
    longest = 0.0
    for s0, s1 in silences:
        for r0, r1 in runs:
            lo, hi = max(s0, r0 + CAMERA_GRACE_S), min(s1, math.inf if r1 is None else r1)
            longest = max(longest, hi - lo)
    return longest


def check(
    result: ChaosResult,
    world: World,
    reported: dict[int, list[Any]],
    pending: int,
    hq_db: Path,
    companion: Supervised,
    hq: Supervised,
    out: Path,
    drain_max_s: float,
) -> None:
    """Fill in ``result``'s failures and details (the checks: scenarios.chaos)."""
    fails = result.failures
    live = {
        vid: (float(v[2]), float(v[3]))
        for vid, v in reported.items()
        if v[0] not in (TrackState.MERGED.name, TrackState.FALSE_ALARM.name)
    }
    with Registry(hq_db) as registry:
        victims = [v for v in hq_victims(registry) if v.state is not TrackState.FALSE_ALARM]
        sources = {s.report.victim_id for s in registry.sources() if s.report.robot_sysid == 1}
        first_at_hq = registry.first_received_unix_s()
    stored = _stored_seqs(hq_db)
    hq_points = [(v.north_m, v.east_m) for v in victims]
    companion_points = list(live.values())
    result.true_victims = len(world.victims)
    result.companion_victims = len(reported)
    result.merged_victims = sum(v[0] == TrackState.MERGED.name for v in reported.values())
    result.false_victims = sum(
        not any(math.hypot(t.north_m - n, t.east_m - e) <= GATE_M for t in world.victims)
        for n, e in companion_points
    )
    for t in world.victims:
        by_companion = _near(companion_points, t.north_m, t.east_m)
        at_hq = _near(hq_points, t.north_m, t.east_m)
        result.true_confirmed += by_companion > 0
        result.true_at_hq += at_hq > 0
        result.companion_duplicates += max(0, by_companion - 1)
        result.hq_duplicates += max(0, at_hq - 1)
        result.details.append(
            f"true victim {t.victim_id} at ({t.north_m:.2f}, {t.east_m:.2f}): companion "
            + _listing([(vid, p) for vid, p in live.items()], t.north_m, t.east_m)
            + "; HQ "
            + _listing([(v.hq_id, (v.north_m, v.east_m)) for v in victims], t.north_m, t.east_m)
        )
        if by_companion > 1:
            fails.append(
                f"true victim {t.victim_id}: the companion itself holds {by_companion} victim"
                f" IDs for it (so the HQ has {at_hq} HQ victims; want exactly 1)"
            )
        elif by_companion and at_hq != 1:
            fails.append(f"true victim {t.victim_id}: {at_hq} HQ victims (want exactly 1)")
    result.missing_at_hq = sorted(set(reported) - sources)
    if result.missing_at_hq:
        fails.append(f"companion victims missing at the HQ: {result.missing_at_hq}")
    if pending:
        fails.append(f"{pending} reports still in the companion's outbox")
    if result.drain_s is None:
        fails.append(f"the outbox did not drain within {drain_max_s:.0f} s")
    radio = result.radio
    assert radio is not None
    acked = {a.seq for a in radio.acks if a.result in (ACK_ACCEPTED, ACK_DUPLICATE)}
    result.acked_not_stored = sorted(acked - stored)
    if result.acked_not_stored:
        fails.append(f"acknowledged but not in the registry: seq {result.acked_not_stored[:10]}")
    decided: dict[int, int] = {}  # victim -> earliest report time (its confirmation)
    for r in radio.reports:
        decided[r.victim_id] = min(decided.get(r.victim_id, r.time_usec), r.time_usec)
    waits = [
        first_at_hq[(1, vid)] - decided[vid] / 1e6
        for vid in reported
        if (1, vid) in first_at_hq and vid in decided
    ]
    result.longest_wait_s = max(waits) if waits else None
    report_waits = _stored_waits(hq_db).values()
    result.longest_report_wait_s = max(report_waits) if report_waits else None
    result.confirmed_at_s = sorted(
        decided[vid] / 1e6 - result.started_unix_s for vid in reported if vid in decided
    )
    result.companion_unplanned = len(companion.unplanned_exits())
    result.companion_quick = companion.quick_unplanned_exits()
    result.hq_unplanned = len(hq.unplanned_exits())
    result.hq_quick = hq.quick_unplanned_exits()
    for name, sup in (("companion", companion), ("HQ", hq)):
        exits = [r.returncode for r in sup.unplanned_exits()]
        if exits:
            fails.append(f"{name} exited unasked {len(exits)} times (status {exits})")
    result.tracebacks = sum(
        (out / name).read_text(errors="replace").count("Traceback")
        for name in ("companion.log", "hq.log")
    )
    if result.tracebacks:
        fails.append(f"{result.tracebacks} tracebacks in the logs")
    if result.true_confirmed < result.true_victims:
        # Each person lies in plain view across a third of the patrol: one not
        # confirmed means the companion stopped seeing (a dead camera, a stuck loop).
        fails.append(
            f"the companion confirmed {result.true_confirmed} of the {result.true_victims}"
            " people the rover passed in plain view"
        )
    if result.longest_silence_s > MAX_SILENCE_S:
        fails.append(
            f"a running companion got no camera frame for {result.longest_silence_s:.0f} s"
            f" (at most {MAX_SILENCE_S:.0f} s)"
        )
    if result.disk_note.startswith(("full", "not yet")):
        fails.append(f"state disk: {result.disk_note}")


def _stored_seqs(hq_db: Path) -> set[int]:
    return set(_stored_waits(hq_db))


def _stored_waits(hq_db: Path) -> dict[int, float]:
    """Each report the HQ stored from robot 1: seconds from its making to its receipt."""
    db = _read_only(hq_db)
    try:
        rows = db.execute(
            "SELECT report_seq, received_unix_s - report_time_usec / 1e6 FROM reports"
            " WHERE robot_sysid=1"
        ).fetchall()
    finally:
        db.close()
    return {int(seq): float(wait) for seq, wait in rows}
