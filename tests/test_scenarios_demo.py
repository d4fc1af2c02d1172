"""`rescue-sim demo` as `make demo` runs it: a recorded mission through the companion's
pipeline to a real rescue-hq, with the table, the map and the exports a newcomer
reads. A real subprocess; the mission is cut short to keep the test run short."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from hq.registry import Registry
from hq.view import hq_victims

REPO = Path(__file__).resolve().parents[1]
# At the demo's 0.4 m/s the mixed preset's whole-body victim (T1) is reported at
# 49.5 s, on the rover's second lane (its route goes around debris and people).
MISSION_S = 60.0


def _demo(out: Path, *extra: str) -> subprocess.CompletedProcess[str]:
    cmd = [sys.executable, "-m", "scenarios.cli", "demo", "--out", str(out), *extra]
    return subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=280)


def _table(stdout: str) -> list[str]:
    """The per-victim lines of the ground-truth table."""
    return [line for line in stdout.splitlines() if line.startswith("T")]


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_demo_reports_to_the_hq_maps_and_starts_fresh_unless_resumed(tmp_path: Path) -> None:
    out = tmp_path / "demo"
    first = _demo(out, "--duration-s", str(MISSION_S))
    assert first.returncode == 0, first.stderr[-2000:]
    assert "Traceback" not in first.stderr
    lines = _table(first.stdout)
    t1 = lines[0].split()
    assert t1[:2] == ["T1", "LIGHT"] and t1[2][:1] == "V" and t1[3] == "LIGHT"
    assert "after first in view" in lines[0]
    assert "false victims 0" in first.stdout
    # The companion is in the loop with its closer looks on: the rover left its route
    # to look again, and the demo says what each look settled.
    assert "demo: closer look 1 at " in first.stdout
    # What the table says was reported is what the HQ holds and exports.
    reported = sorted(int(w[1:]) for line in lines for w in line.split() if w[:1] == "V")
    assert reported[0] == 1
    assert (out / "mission_map.png").stat().st_size > 10_000
    csv_lines = (out / "exports" / "victims.csv").read_text().count("\n")
    assert csv_lines == 1 + len(reported)  # a header, then one row per victim
    with Registry(out / "hq.sqlite") as reg:
        assert sorted(v.hq_id for v in hq_victims(reg)) == reported
    # The HQ's robot table shows the replayed companion's status at the mission's end:
    # every frame of the 5 frames/s camera processed, its confirmed victims.
    out_lines = first.stdout.splitlines()
    head = next(i for i, line in enumerate(out_lines) if line.split()[:2] == ["ROBOT", "HEARD"])
    robot = out_lines[head + 1].split()
    assert robot[2:4] == ["5.0", str(len(reported))] and "VEH" in robot and "CAM" in robot
    # --resume keeps what the HQ holds (a 2 s mission finds nobody new) ...
    resumed = _demo(out, "--duration-s", "2", "--resume")
    assert resumed.returncode == 0, resumed.stderr[-2000:]
    with Registry(out / "hq.sqlite") as reg:
        assert sorted(v.hq_id for v in hq_victims(reg)) == reported
    # ... and without it every run starts afresh: the same 2 s mission holds only what
    # it reported itself (the thermal camera may confirm T1 within it), numbered anew.
    fresh = _demo(out, "--duration-s", "2")
    assert fresh.returncode == 0, fresh.stderr[-2000:]
    again = sorted(
        int(w[1:]) for line in _table(fresh.stdout) for w in line.split() if w[:1] == "V"
    )
    assert len(again) < len(reported) and again == list(range(1, len(again) + 1))
    with Registry(out / "hq.sqlite") as reg:
        assert sorted(v.hq_id for v in hq_victims(reg)) == again
