"""``rescue-sim``: the simulated warehouse, rover and camera.

    rescue-sim world  (--preset P | --seed S | --world W) [--out W.toml]
    rescue-sim record (--preset P | --seed S | --world W) --out DIR [--duration-s T]
                      [--no-thermal]
    rescue-sim score  --truth DIR/ground_truth.json --victims REPORT.json [--json]
    rescue-sim sheet  (--preset P | --seed S | --world W) --out sheet.png
    rescue-sim rover  (--preset P | --seed S | --world W) --link URL [--link URL ...]
                      [--camera-port PORT] [--thermal-port PORT] [--time-scale X]
    rescue-sim demo   [--preset P | --seed S | --world W] [--out DIR] [--duration-s T]
                      [--resume] [--live] [--no-looks]

Exit status: 0 success, 1 runtime failure, 2 bad input or usage.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path

from mavlink_io.errors import LinkError
from scenarios.world import PRESETS, World, WorldError

EXIT_OK = 0
EXIT_FAILURE = 1
EXIT_USAGE = 2

log = logging.getLogger(__name__)


def _number(low: float, high: float, low_open: bool = True) -> Callable[[str], float]:
    """argparse type: a number in (low, high] (or [low, high] with ``low_open`` False)."""
    bounds = f"{'(' if low_open else '['}{low:g}, {high:g}]"

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
        if not ((low < value if low_open else low <= value) and value <= high):
            raise argparse.ArgumentTypeError(f"{text!r} is outside {bounds}")
        return value

    return parse


def _whole(low: int, high: int, what: str) -> Callable[[str], int]:
    """argparse type: a whole number in [low, high]."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            value = low - 1
        if not low <= value <= high:
            raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}")
        return value

    return parse


_SEED = _whole(0, 2**63 - 1, "a whole number >= 0")
_PORT = _whole(0, 65535, "a TCP port 0..65535 (0: any free one)")
_DURATION_S = _number(0.0, 1e6)
_SPEED_M_S = _number(0.0, 5.0)


def _world_args(p: argparse.ArgumentParser, required: bool = True) -> None:
    g = p.add_mutually_exclusive_group(required=required)
    g.add_argument("--preset", choices=PRESETS, help="one of the seven scenarios")
    g.add_argument("--seed", type=_SEED, help="a generated mixed world")
    g.add_argument("--world", type=Path, help="a world TOML file")


def _world(args: argparse.Namespace) -> World:
    from scenarios.world import generate_world, load_world, preset

    if args.preset:
        return preset(args.preset)
    if args.seed is None and args.world is None:  # demo's default: the mixed scenario
        return preset("mixed")
    if args.seed is not None:
        return generate_world(args.seed)
    return load_world(args.world)


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="rescue-sim", description=__doc__.splitlines()[0])
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    sub = parser.add_subparsers(dest="command", required=True)

    w = sub.add_parser("world", help="print or save a world and its victims' ground truth")
    _world_args(w)
    w.add_argument("--out", type=Path, help="write the world TOML here")

    r = sub.add_parser(
        "record", help="record a mission (tlog, colour and thermal frames, camera, truth)"
    )
    _world_args(r)
    r.add_argument("--out", type=Path, required=True, help="output directory")
    r.add_argument("--duration-s", type=_DURATION_S, help="default: the whole route")
    r.add_argument("--fps", type=_number(0.0, 60.0), default=10.0)
    r.add_argument(
        "--start-unix-s",
        type=_number(0.0, 4e9, low_open=False),
        help="wall time of simulation start (default: now)",
    )
    r.add_argument(
        "--no-thermal",
        action="store_true",
        help="no thermal camera: no thermal/ folder and no [thermal] section",
    )

    s = sub.add_parser("score", help="score a victim report against the ground truth")
    s.add_argument("--truth", type=Path, required=True, help="ground_truth.json")
    s.add_argument("--victims", type=Path, required=True, help="REPORT.json")
    s.add_argument("--gate-m", type=_number(0.0, 100.0), default=1.0)
    s.add_argument("--json", action="store_true", help="print the figures as JSON")

    c = sub.add_parser("sheet", help="a PNG contact sheet: map, route, victims, frames")
    _world_args(c)
    c.add_argument("--out", type=Path, required=True)

    v = sub.add_parser("rover", help="run the simulated rover (and its cameras) live")
    _world_args(v)
    v.add_argument("--link", action="append", required=True, help="udpin:H:P, tcpin:H:P, ..., pty")
    v.add_argument(
        "--camera-port", type=_PORT, help="serve camera frames on this TCP port (0: any free one)"
    )
    v.add_argument(
        "--thermal-port",
        type=_PORT,
        help="serve the thermal camera's frames (centi-kelvin PNG, 8.7/s) on this TCP port "
        "(0: any free one)",
    )
    v.add_argument("--camera-host", default="127.0.0.1", help="where both cameras listen")
    v.add_argument("--time-scale", type=_number(0.0, 100.0), default=1.0)
    v.add_argument("--speed-m-s", type=_SPEED_M_S, default=0.4)
    d = sub.add_parser(
        "demo",
        help="a simulated mission through the companion's pipeline to a real rescue-hq, "
        "deterministic (--live: the whole product in real time on loopback)",
    )
    _world_args(d, required=False)
    d.add_argument("--out", type=Path, default=Path("demo-out"), help="logs, map, exports")
    d.add_argument("--duration-s", type=_DURATION_S, help="default: the whole route")
    # As the scenario suite's missions drive (scenarios.record): at 0.6 m/s and 5
    # frames/s the arm out of the rubble was in view on too few frames to confirm.
    d.add_argument("--speed-m-s", type=_SPEED_M_S, default=0.4)
    d.add_argument(
        "--resume",
        action="store_true",
        help="keep the previous run's state in --out (default: start fresh)",
    )
    d.add_argument(
        "--live",
        action="store_true",
        help="rover, camera, rescue-companion run and rescue-hq live in real time "
        "(results then depend on how many frames this machine processes)",
    )
    d.add_argument(
        "--no-looks",
        action="store_true",
        help="the rover drives its route only (default: the companion takes it on closer "
        "looks at what it is unsure of; not with --live)",
    )
    return parser


def _cmd_world(args: argparse.Namespace, world: World) -> int:
    from scenarios.world import save_world

    if args.out:
        save_world(world, args.out)
        print(f"wrote {args.out}")
    print(
        f"world '{world.name}' seed {world.seed}, {len(world.victims)} victims, {len(world.debris)} debris"
    )
    for vic in world.victims:
        print(
            f"  victim {vic.victim_id}: north {vic.north_m:.2f} m east {vic.east_m:.2f} m, "
            f"visibility {vic.visibility_pct:.1f} % -> {vic.urgency.name}"
        )
    return EXIT_OK


def _cmd_record(args: argparse.Namespace, world: World) -> int:
    from scenarios.record import record

    res = record(
        world,
        args.out,
        duration_s=args.duration_s,
        fps=args.fps,
        start_unix_s=args.start_unix_s,
        thermal=not args.no_thermal,
    )
    thermal = f", {res.thermal_frames} thermal frames" if not args.no_thermal else ""
    print(
        f"recorded {res.duration_s:.1f} s: {res.frames} frames{thermal}, {res.packets} packets "
        f"-> {res.out_dir}"
    )
    return EXIT_OK


def _cmd_score(args: argparse.Namespace) -> int:
    from scenarios.score import format_score, load_report, load_truth, score

    result = score(load_truth(args.truth), load_report(args.victims), args.gate_m)
    print(json.dumps(result.as_dict(), indent=1) if args.json else format_score(result))
    return EXIT_OK


def _cmd_sheet(args: argparse.Namespace, world: World) -> int:
    from scenarios.sheet import write_sheet

    print(f"wrote {write_sheet(world, args.out)}")
    return EXIT_OK


def _cmd_rover(args: argparse.Namespace, world: World) -> int:
    from companion.service.stopsignals import StopSignals
    from scenarios.camserver import CameraServer, FrameServer, ThermalCameraServer
    from scenarios.render import Renderer
    from scenarios.rover import SimRover
    from scenarios.thermal import ThermalRenderer

    signals = StopSignals()  # not Event.set in a handler: see companion/service/stopsignals.py
    signals.install()
    rover = SimRover(world, args.link, time_scale=args.time_scale, speed_m_s=args.speed_m_s)
    servers: list[FrameServer] = []
    try:
        rover.start()
        for i, spec in enumerate(args.link):
            where = rover.pty_path(i) if spec == "pty" else spec
            print(f"rover link {i}: {where}", flush=True)
        if args.camera_port is not None:
            cam = CameraServer(
                Renderer(world),
                rover.camera_pose,
                host=args.camera_host,
                port=args.camera_port,
                time_scale=args.time_scale,
            )
            servers.append(cam.start())
            print(f"camera: tcp {cam.address[0]}:{cam.address[1]}", flush=True)
        if args.thermal_port is not None:
            warm = ThermalCameraServer(
                ThermalRenderer(world),
                rover.camera_pose,
                host=args.camera_host,
                port=args.thermal_port,
                time_scale=args.time_scale,
            )
            servers.append(warm.start())
            print(f"thermal camera: tcp {warm.address[0]}:{warm.address[1]}", flush=True)
        while signals.reason() is None:
            time.sleep(0.1)
    finally:
        for server in servers:
            server.close()
        rover.close()
    return EXIT_OK


def _cmd_demo(args: argparse.Namespace, world: World) -> int:
    from scenarios.demo import DemoError, run_demo
    from scenarios.demo_summary import print_summary

    try:
        result = run_demo(
            world,
            args.out,
            args.duration_s,
            args.speed_m_s,
            args.resume,
            live=args.live,
            looks=not args.no_looks,
        )
    except DemoError as exc:
        print(f"rescue-sim: demo: {exc}", file=sys.stderr)
        return EXIT_FAILURE
    print_summary(result)
    if result.companion_exit != 0 or result.hq_exit != 0:
        print(
            f"rescue-sim: demo: rescue-companion exited {result.companion_exit}, "
            f"rescue-hq {result.hq_exit} (see the logs)",
            file=sys.stderr,
        )
        return EXIT_FAILURE
    return EXIT_OK


def main(argv: Sequence[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO,
        format="%(levelname)s %(name)s: %(message)s",
        stream=sys.stderr,
    )
    from scenarios.score import ScoreInputError

    try:
        if args.command == "score":
            return _cmd_score(args)
        world = _world(args)
        handler = {
            "world": _cmd_world,
            "record": _cmd_record,
            "sheet": _cmd_sheet,
            "rover": _cmd_rover,
            "demo": _cmd_demo,
        }[args.command]
        return handler(args, world)
    except (WorldError, ScoreInputError) as exc:
        print(f"rescue-sim: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except (LinkError, OSError) as exc:
        print(f"rescue-sim: {exc}", file=sys.stderr)
        return EXIT_FAILURE


if __name__ == "__main__":
    sys.exit(main())
