"""What ``rescue-sim demo`` shows a person at the end (scenarios/demo.py runs it):
the HQ's victims scored against the world's truth, one line per true victim, the
totals, the share of the floor searched and the mission map with the looks."""

from __future__ import annotations

import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

from companion.commands.missionmap import MapLook, MapTruth, MapVictim, draw_mission_map
from fusion.coverage import CoverageGrid
from fusion.types import TrackState
from hq import coverage as hq_coverage
from hq.registry import Registry
from hq.view import hq_victims
from scenarios.score import (
    ReportedVictim,
    ScoreResult,
    format_score,
    score,
    truth_of_world,
)
from scenarios.world import World


@dataclass(frozen=True)
class DemoResult:
    out_dir: Path
    confirmed: int
    map_png: Path
    score_text: str
    companion_exit: int
    hq_exit: int
    searched_text: str = ""  # the share of the floor searched (the coverage map, issue 43)


def summarise(
    world: World,
    out_dir: Path,
    route: list[tuple[float, float]],
    first_in_view: dict[int, float],
    companion_exit: int,
    hq_exit: int,
    reported_at: dict[tuple[int, int], float] | None = None,
    coverage: CoverageGrid | None = None,
    looks: list[MapLook] | None = None,
) -> DemoResult:
    """Score and map what the HQ holds (the victims ``rescue-hq list`` shows).
    ``reported_at``: when each (robot, victim) was first reported, on the mission's
    clock; default: when the HQ first received it. ``coverage``: where the robot
    looked; default: the HQ's merged map."""
    registry = Registry(out_dir / "hq.sqlite")
    try:
        victims = [v for v in hq_victims(registry) if v.state is not TrackState.FALSE_ALARM]
        received = registry.first_received_unix_s() if reported_at is None else reported_at
        if coverage is None:
            merged = hq_coverage.load(registry)
            coverage = CoverageGrid()
            coverage.add_look(merged.cells, merged.p)
    finally:
        registry.close()
    floor = (0.0, world.size_m[0], 0.0, world.size_m[1])
    searched = coverage.summary(floor)
    searched_text = (
        f"floor searched well: {100 * searched.searched_well_share:.0f} % "
        f"(glanced at or better: {100 * searched.glanced_at_share:.0f} %) "
        f"of the {world.size_m[0]:g} x {world.size_m[1]:g} m floor, as the cameras claim it "
        "(no depth: floor behind tall debris counts as seen)"
    )
    reported = [
        ReportedVictim(
            v.hq_id,
            v.urgency,
            v.north_m,
            v.east_m,
            v.first_seen_unix_s,
            min((received[s] for s in v.sources if s in received), default=None),
            ((v.sigma_m**2, 0.0), (0.0, v.sigma_m**2)),
        )
        for v in victims
    ]
    result = score(truth_of_world(world, first_in_view), reported)
    map_png = out_dir / "mission_map.png"
    draw_mission_map(
        map_png,
        route,
        [
            MapVictim(
                f"V{v.hq_id} {v.cues.cameras}".rstrip(),
                v.urgency,
                v.north_m,
                v.east_m,
                ((v.sigma_m**2, 0.0), (0.0, v.sigma_m**2)),
                v.visibility_pct,
            )
            for v in victims
        ],
        [
            MapTruth(
                f"T{v.victim_id}",
                v.urgency,
                v.north_m,
                v.east_m,
                (v.visible_north_m, v.visible_east_m),
            )
            for v in world.victims
        ],
        [d.polygon for d in world.debris],
        floor,
        coverage,
        looks or (),
    )
    cameras = {v.hq_id: v.cues.cameras or "?" for v in victims}
    table = _victim_table(world, result, reported, first_in_view, cameras)
    return DemoResult(
        out_dir,
        len(victims),
        map_png,
        table + "\n\n" + format_score(result),
        companion_exit,
        hq_exit,
        searched_text,
    )


def _victim_table(
    world: World,
    result: ScoreResult,
    reported: list[ReportedVictim],
    first_in_view: dict[int, float],
    cameras: dict[int, str],
) -> str:
    """One line per true victim: what the HQ got for it, and which camera found it
    (colour, thermal or both; "?" from a robot that does not say)."""
    by_true = {m.true_id: m for m in result.matches}
    by_id = {r.victim_id: r for r in reported}
    lines = ["true victim   urgency    reported as          camera   error   first report"]
    for v in world.victims:
        m = by_true.get(v.victim_id)
        if m is None:
            unseen = " (never in view)" if v.victim_id in result.never_in_view_ids else ""
            lines.append(f"T{v.victim_id:<11d} {v.urgency.name:<10s} not reported{unseen}")
            continue
        r = by_id[m.reported_id]
        seen = first_in_view.get(v.victim_id)
        delay = (
            f"{r.first_reported_unix_s - seen:5.1f} s after first in view"
            if seen is not None and r.first_reported_unix_s is not None
            else "n/a"
        )
        lines.append(
            f"T{v.victim_id:<11d} {v.urgency.name:<10s} V{r.victim_id:<3d} "
            f"{r.urgency.name:<16s} {cameras.get(r.victim_id, '?'):<8s} {m.error_m:4.2f} m  {delay}"
        )
    false = [r for r in reported if r.victim_id not in {m.reported_id for m in result.matches}]
    for r in false:
        lines.append(
            f"{'(none)':<12s} {'':<10s} V{r.victim_id:<3d} {r.urgency.name:<16s} "
            f"{cameras.get(r.victim_id, '?'):<8s} false victim"
        )
    return "\n".join(lines)


def print_summary(result: DemoResult) -> None:
    listing = subprocess.run(
        [sys.executable, "-m", "hq.cli", "list", "--db", str(result.out_dir / "hq.sqlite")],
        capture_output=True,
        text=True,
        timeout=60,
    )
    print("\nvictims at the HQ:")
    print(listing.stdout.rstrip() or listing.stderr.rstrip())
    print("\nagainst the world's ground truth:")
    print(result.score_text)
    if result.searched_text:
        print(f"\n{result.searched_text}")
    print(f"\nmission map: {result.map_png}")
    print(f"HQ exports: {result.out_dir / 'exports'} (GeoJSON, KML, CSV)")
    logs = [result.out_dir / n for n in ("companion.log", "hq.log")]
    print("logs: " + ", ".join(str(p) for p in logs if p.exists()))
    if (result.out_dir / "mission").is_dir():
        print(f"recorded mission: {result.out_dir / 'mission'} (rescue-companion replay)")
