"""rescue-hq's commands on a registry file, without a running HQ (``mark``, ``look``,
``looks``, ``export``, ``list``), and ``assets`` (the console's map library, fetched at
set-up)."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from hq import coverage, export, table
from hq.cli_args import (
    DEFAULT_DB,
    EXIT_OK,
    EXIT_RUNTIME,
    EXIT_USAGE,
    UsageError,
    open_registry,
    parse_origin,
    parse_sysid,
)
from hq.merge import Origins
from hq.records import OperatorAction
from hq.registry import Registry
from hq.view import build, hq_victims


def _victim_arguments(p: argparse.ArgumentParser) -> None:
    """The registry and the victim an action is about: one robot's, or an HQ victim's
    (every robot's source of it)."""
    p.add_argument("--db", type=Path, default=Path(DEFAULT_DB))
    p.add_argument("--robot", type=parse_sysid, help="robot system ID (with --victim)")
    p.add_argument("--victim", type=int, help="the robot's victim ID (with --robot)")
    p.add_argument("--id", type=int, dest="hq_id", help="HQ victim ID (every robot's source)")


def mark_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="rescue-hq mark",
        description="Record an operator decision; the running HQ sends it to the robot "
        "and resends until the robot acknowledges.",
    )
    _victim_arguments(p)
    what = p.add_mutually_exclusive_group(required=True)
    what.add_argument("--rescued", action="store_true")
    what.add_argument("--false-alarm", action="store_true")
    what.add_argument("--confirmed", action="store_true", help="a real person (reopens)")
    return p


def look_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="rescue-hq look",
        description="Ask a robot to look closer at a victim next (docs/LOOKS.md); the running "
        "HQ sends it until the robot acknowledges. The robot does it only with closer looks "
        "on, armed and in AUTO; with looks off it says so and answers REJECTED.",
    )
    _victim_arguments(p)
    return p


def looks_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="rescue-hq looks",
        description="Switch a robot's closer looks off (a look under way is aborted and the "
        "mission resumed) or on again: what its parameter RC_LOOK_ON does. The running HQ "
        "sends it until the robot acknowledges.",
    )
    p.add_argument("--db", type=Path, default=Path(DEFAULT_DB))
    p.add_argument("--robot", type=parse_sysid, required=True, help="robot system ID")
    p.add_argument("switch", choices=("off", "on"))
    return p


def export_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="rescue-hq export", description="Write the export files.")
    p.add_argument("--db", type=Path, default=Path(DEFAULT_DB))
    p.add_argument("--out", type=Path, required=True, help="output directory")
    p.add_argument("--origin", type=parse_origin, help="EKF origin LAT,LON,ALT (default: stored)")
    return p


def list_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="rescue-hq list", description="Print the table once.")
    p.add_argument("--db", type=Path, default=Path(DEFAULT_DB))
    return p


def assets_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="rescue-hq assets",
        description="The console's map library (Leaflet) from the npm registry, checked by "
        "sha512/sha256 (make runs `fetch` on set-up; nothing is fetched at run time).",
    )
    p.add_argument("action", choices=("fetch", "verify"))
    p.add_argument("--dir", type=Path, help="asset folder (default: in the installation)")
    return p


def mark_command(args: argparse.Namespace) -> int:
    action = (
        OperatorAction.RESCUED
        if args.rescued
        else OperatorAction.CONFIRMED
        if args.confirmed
        else OperatorAction.FALSE_ALARM
    )
    return _record_on_victim("mark", args, action)


def look_command(args: argparse.Namespace) -> int:
    return _record_on_victim("look", args, OperatorAction.LOOK_CLOSER)


def _record_on_victim(command: str, args: argparse.Namespace, action: OperatorAction) -> int:
    """Record ``action`` for one robot's victim, or for every source of an HQ victim."""
    by_source = args.robot is not None or args.victim is not None
    if by_source == (args.hq_id is not None) or (by_source and None in (args.robot, args.victim)):
        raise UsageError(f"{command}: give either --robot N --victim ID, or --id HQ_ID")
    with open_registry(args.db, must_exist=True) as registry:
        if by_source:
            targets = [(args.robot, args.victim)]
        else:
            found = [v for v in hq_victims(registry) if v.hq_id == args.hq_id]
            if not found:
                raise UsageError(f"{command}: no HQ victim {args.hq_id} in {args.db}")
            targets = list(found[0].sources)
        for robot, victim in targets:
            _record(command, args.db, registry, robot, victim, action)
    return EXIT_OK


def looks_command(args: argparse.Namespace) -> int:
    action = OperatorAction.LOOKS_ON if args.switch == "on" else OperatorAction.LOOKS_OFF
    with open_registry(args.db, must_exist=True) as registry:
        _record("looks", args.db, registry, args.robot, 0, action)
    return EXIT_OK


def _record(
    command: str, db: Path, registry: Registry, robot: int, victim: int, action: OperatorAction
) -> None:
    try:
        seq = registry.add_action(robot, victim, action)
    except KeyError as exc:
        raise UsageError(f"{command}: {exc.args[0]} (in {db})") from None
    about = "" if action.whole_robot else f" victim {victim}"
    print(
        f"action {seq}: {action.name} robot {robot}{about} recorded; "
        "the running rescue-hq sends it until the robot acknowledges"
    )


def export_command(args: argparse.Namespace) -> int:
    with open_registry(args.db, must_exist=True) as registry:
        origins = registry.origins()
        if args.origin is not None:  # place NED-only victims of robots without an origin
            origins = Origins(origins.per_robot, args.origin)
        victims = build(registry.sources(), registry.actions(), origins)
        grid = coverage.merged_map(registry.coverage(), origins)
    try:
        result = export.export_all(victims, args.out, grid)
    except OSError as exc:
        print(f"rescue-hq: cannot write exports to {args.out}: {exc}", file=sys.stderr)
        return EXIT_RUNTIME
    for path in result.written:
        print(path)
    if result.local_only:
        print(f"{result.local_only} victim(s) without lat/lon left out: give --origin LAT,LON,ALT")
    return EXIT_OK


def list_command(args: argparse.Namespace) -> int:
    with open_registry(args.db, must_exist=True) as registry:
        header = table.Header(None, [str(args.db)], registry.report_count(), False)
        text = table.render(
            header,
            hq_victims(registry),
            registry.robots(),
            time.time(),
            colour=sys.stdout.isatty(),
        )
    sys.stdout.write(text)
    return EXIT_OK


def assets_command(args: argparse.Namespace) -> int:
    from hq.web import assets

    if args.action == "verify":
        problems = assets.verify(args.dir)
        for line in problems:
            print(line, file=sys.stderr)
        return EXIT_USAGE if problems else EXIT_OK
    try:
        written = assets.fetch(args.dir)
    except assets.FetchError as exc:
        print(f"rescue-hq: {exc}", file=sys.stderr)
        return EXIT_RUNTIME
    folder = args.dir or assets.default_asset_dir()
    print(f"console assets ok in {folder} ({len(written)} written, checked by sha256)")
    return EXIT_OK
