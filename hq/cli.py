"""`rescue-hq`: the ground side that receives, acknowledges, merges and exports victims.

    rescue-hq [run] [--listen URL ...] [--db PATH] [--sysid N] [--export-dir DIR]
                    [--signing-key FILE] [--origin LAT,LON,ALT] [--no-table]
                    [--sbs HOST:PORT|off] [--duration-s T] [--web HOST:PORT | --no-web]
                    [--web-token-file FILE] [--link-timeout-s T] [-v]
    rescue-hq mark   --db PATH (--robot N --victim ID | --id HQ_ID)
                     (--rescued | --false-alarm | --confirmed)
    rescue-hq export --db PATH --out DIR [--origin LAT,LON,ALT]
    rescue-hq list   --db PATH
    rescue-hq assets fetch|verify

Exit status: 0 ok; 1 runtime failure (a link cannot be opened, an export cannot
be written); 2 bad usage, configuration or database (a clear one-line message
naming the file).
"""

from __future__ import annotations

import argparse
import logging
import signal
import sys
import threading
import time
from pathlib import Path
from types import FrameType
from typing import TYPE_CHECKING

from fusion.types import GlobalOrigin
from hq import coverage, epoch, export, table
from hq.app import HqApp, HqOptions
from hq.errors import HqError
from hq.merge import Origins
from hq.output import TerminalWriter, WriterLogHandler
from hq.records import OperatorAction
from hq.registry import Registry
from hq.registry_file import RegistryCorrupt, RegistryError
from hq.sbs import DEFAULT_ADDRESS, SbsServer
from hq.view import build, hq_victims
from hq.web.state import LiveRobots
from mavlink_io.errors import LinkError, LinkSpecError, SigningError
from mavlink_io.hub import SingleLink, UdpHubLink, open_endpoint
from mavlink_io.linkspec import LinkSpec, parse_link
from mavlink_io.signing import load_signing

if TYPE_CHECKING:
    from hq.web.server import Console

log = logging.getLogger("hq")

EXIT_OK = 0
EXIT_RUNTIME = 1
EXIT_USAGE = 2
DEFAULT_LISTEN = "udpin:0.0.0.0:14600"
DEFAULT_DB = "rescue-hq.sqlite"
SBS_OFF = "off"
DEFAULT_WEB = "127.0.0.1:8080"
_SUBCOMMANDS = ("run", "mark", "export", "list", "assets")


class UsageError(HqError):
    """Bad usage or configuration: exit 2."""


def _origin(text: str) -> GlobalOrigin:
    parts = text.split(",")
    try:
        if len(parts) != 3:
            raise ValueError("expected LAT,LON,ALT")
        return GlobalOrigin(float(parts[0]), float(parts[1]), float(parts[2]))
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"origin {text!r}: {exc}") from None


def _sysid(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not 1 <= value <= 255:
        raise argparse.ArgumentTypeError(f"system ID {value} is outside 1..255")
    return value


def _sbs(text: str) -> tuple[str, int] | str:
    if text == SBS_OFF:
        return SBS_OFF
    host, sep, port_text = text.rpartition(":")
    try:
        port = int(port_text)
    except ValueError:
        port = -1
    if not sep or not host or not 0 <= port <= 65535:
        raise argparse.ArgumentTypeError(f"{text!r}: expected HOST:PORT (port 0..65535) or off")
    return (host, port)


def _duration(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not value > 0:
        raise argparse.ArgumentTypeError("duration must be positive")
    return value


def _web_address(text: str) -> tuple[str, int]:
    host, sep, port_text = text.rpartition(":")
    host = host.strip("[]")
    try:
        port = int(port_text)
    except ValueError:
        port = -1
    if not sep or not host or not 0 <= port <= 65535:
        raise argparse.ArgumentTypeError(f"{text!r}: expected HOST:PORT, e.g. {DEFAULT_WEB}")
    return host, port


def _run_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="rescue-hq",
        description="Receive, acknowledge, merge and export victim reports from rescue robots. "
        "Other commands: mark, export, list, assets (rescue-hq COMMAND --help). "
        "The operator's browser console is on by default (docs/HQ.md).",
    )
    p.add_argument(
        "--listen",
        action="append",
        metavar="URL",
        help=f"link to listen on, repeatable (default {DEFAULT_LISTEN}); "
        "udpin:H:P, udpout:H:P, tcp:H:P, tcpin:H:P, serial:/dev/X:BAUD",
    )
    p.add_argument("--db", type=Path, default=Path(DEFAULT_DB), help="SQLite registry file")
    p.add_argument("--sysid", type=_sysid, default=245, help="the HQ's MAVLink system ID")
    p.add_argument(
        "--export-dir",
        type=Path,
        help="write victims.geojson/.kml/.csv and coverage.geojson (the searched-area map) here",
    )
    p.add_argument("--signing-key", type=Path, help="MAVLink 2 signing key file (mode 0600)")
    p.add_argument(
        "--origin",
        type=_origin,
        help="EKF origin LAT,LON,ALT of robots that report only local NED positions",
    )
    p.add_argument("--no-table", action="store_true", help="plain log lines, no live table")
    p.add_argument(
        "--sbs",
        type=_sbs,
        metavar="HOST:PORT|off",
        help="serve the victims to QGroundControl's ADS-B layer as an SBS-1 feed "
        f"(default {DEFAULT_ADDRESS[0]}:{DEFAULT_ADDRESS[1]}; skipped with a warning "
        "when that port is taken; off: no feed)",
    )
    p.add_argument("--duration-s", type=_duration, help="run this long, then exit cleanly")
    web = p.add_mutually_exclusive_group()
    web.add_argument(
        "--web",
        type=_web_address,
        metavar="HOST:PORT",
        help=f"the browser console's address (default {DEFAULT_WEB}; port 0 picks one); "
        "an address other than loopback needs --web-token-file. When the default port "
        "is taken, rescue-hq runs on without the console and says so",
    )
    web.add_argument("--no-web", action="store_true", help="no browser console")
    p.add_argument(
        "--web-token-file",
        type=Path,
        help="file holding the console's token (one line, 12+ characters); "
        "every page and request must then give it",
    )
    p.add_argument(
        "--link-timeout-s",
        type=_duration,
        default=5.0,
        help="the console shows a robot's link as lost after this long unheard (default 5)",
    )
    p.add_argument("-v", "--verbose", action="store_true", help="log at INFO level")
    return p


def _assets_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="rescue-hq assets",
        description="The console's map library (Leaflet) from the npm registry, checked by "
        "sha512/sha256 (make runs `fetch` on set-up; nothing is fetched at run time).",
    )
    p.add_argument("action", choices=("fetch", "verify"))
    p.add_argument("--dir", type=Path, help="asset folder (default: in the installation)")
    return p


def _mark_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="rescue-hq mark",
        description="Record an operator decision; the running HQ sends it to the robot "
        "and resends until the robot acknowledges.",
    )
    p.add_argument("--db", type=Path, default=Path(DEFAULT_DB))
    p.add_argument("--robot", type=_sysid, help="robot system ID (with --victim)")
    p.add_argument("--victim", type=int, help="the robot's victim ID (with --robot)")
    p.add_argument("--id", type=int, dest="hq_id", help="HQ victim ID (every robot's source)")
    what = p.add_mutually_exclusive_group(required=True)
    what.add_argument("--rescued", action="store_true")
    what.add_argument("--false-alarm", action="store_true")
    what.add_argument("--confirmed", action="store_true", help="a real person (reopens)")
    return p


def _export_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="rescue-hq export", description="Write the export files.")
    p.add_argument("--db", type=Path, default=Path(DEFAULT_DB))
    p.add_argument("--out", type=Path, required=True, help="output directory")
    p.add_argument("--origin", type=_origin, help="EKF origin LAT,LON,ALT (default: stored)")
    return p


def _list_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="rescue-hq list", description="Print the table once.")
    p.add_argument("--db", type=Path, default=Path(DEFAULT_DB))
    return p


def _open_registry(path: Path, *, must_exist: bool, recover: bool = False) -> Registry:
    """The registry; with ``recover`` (run), a damaged file is moved aside, said once."""
    if must_exist and not path.exists():
        raise UsageError(f"database {path}: no such file")
    if path.is_dir():
        raise UsageError(f"database {path}: is a directory")
    try:
        return Registry(path)
    except RegistryCorrupt as exc:
        if not recover:
            raise UsageError(str(exc)) from None
        damage = exc
    except RegistryError as exc:
        raise UsageError(str(exc)) from None
    try:
        aside = epoch.move_aside(path)
        registry = Registry(path)
    except (OSError, RegistryError) as exc:
        raise UsageError(f"{damage}; and it cannot be replaced: {exc}") from None
    log.error(
        "%s; moved it to %s and started a new registry in new ID epoch %d: "
        "HQ victim IDs go on from %d, none of the old file's is reused",
        damage,
        aside.name,
        registry.epoch,
        epoch.first_id(registry.epoch),
    )
    return registry


def _read_token(path: Path) -> str:
    try:
        token = path.read_text(encoding="utf-8").strip()
    except (OSError, UnicodeDecodeError) as exc:
        raise UsageError(f"console token file {path}: cannot read: {exc}") from None
    if not token or "\n" in token:
        raise UsageError(f"console token file {path}: expected one line with the token")
    return token


def _console(args: argparse.Namespace, live: LiveRobots) -> Console | None:
    if args.no_web:
        return None
    # Imported here: the web stack loads only when the console is on.
    from hq.web.access import AccessConfigError
    from hq.web.server import Console, ConsoleOptions

    host, port = args.web or _web_address(DEFAULT_WEB)
    token = _read_token(args.web_token_file) if args.web_token_file else None
    options = ConsoleOptions(host, port, token, args.link_timeout_s)
    try:
        return Console(args.db, options, live)
    except AccessConfigError as exc:
        raise UsageError(str(exc)) from None


def _cmd_run(args: argparse.Namespace) -> int:
    try:
        specs = [parse_link(url) for url in (args.listen or [DEFAULT_LISTEN])]
        signing = load_signing(args.signing_key) if args.signing_key else None
    except (LinkSpecError, SigningError) as exc:
        raise UsageError(str(exc)) from None
    live = LiveRobots()
    stop = threading.Event()
    _install_signal_handlers(stop)  # before anything is printed: a stop then is clean too
    console = _console(args, live)  # a bad console setting: exit 2 before any file is made
    registry = _open_registry(args.db, must_exist=False, recover=True)
    try:
        if args.origin is not None:
            try:
                registry.set_default_origin(args.origin)
            except RegistryError as exc:  # a full disk: the origin still serves this run
                log.error("--origin not stored for export/list (used for this run): %s", exc)
        endpoints = _open_endpoints(specs)
        sbs: SbsServer | None = None
        try:
            sbs = _open_sbs(args.sbs)
            if console is not None and not _start_console(console, required=args.web is not None):
                console = None
            options = HqOptions(
                sysid=args.sysid,
                export_dir=args.export_dir,
                signing=signing,
                live_table=not args.no_table and sys.stdout.isatty(),
                duration_s=args.duration_s,
                live=live,
            )
            app = HqApp(registry, endpoints, options, sys.stdout, sbs)
            app.run(stop)
            c = app.counters
            log.info(
                "stopped: %d reports, %d duplicates, %d rejected, %d acks, %d actions acked, "
                "%d refused (bad values), %d refused (signature); %d pictures stored, "
                "%d picture chunks refused, %d pictures rejected",
                c.reports,
                c.duplicates,
                c.rejected,
                c.acks_sent,
                c.actions_acked,
                c.refused,
                c.signature_refused,
                app.pictures.counters.stored,
                app.pictures.counters.chunks_refused,
                app.pictures.counters.rejected,
            )
        finally:
            if sbs is not None:
                sbs.close()
            if console is not None:
                console.stop()
            for ep in endpoints:
                ep.close()
    finally:
        registry.close()
    return EXIT_OK


def _start_console(console: Console, *, required: bool) -> bool:
    """Start the console; False when the default address is taken (the HQ runs on)."""
    from hq.web.server import ConsoleError

    try:
        url = console.start()
    except ConsoleError as exc:
        if required:
            raise LinkError(str(exc)) from None
        print(
            f"rescue-hq: {exc}; running without the console (give --web HOST:PORT)",
            file=sys.stderr,
            flush=True,
        )
        return False
    note = " (token required)" if console.options.token else ""
    print(f"rescue-hq: console on {url}{note}", flush=True)
    for problem in console.asset_problems:
        print(f"rescue-hq: console has no map: {problem}", flush=True)
    return True


def _open_endpoints(specs: list[LinkSpec]) -> list[UdpHubLink | SingleLink]:
    opened: list[UdpHubLink | SingleLink] = []
    try:
        for spec in specs:
            ep = open_endpoint(spec)
            opened.append(ep)
            where = (
                f"udpin:{ep.local_address[0]}:{ep.local_address[1]}"
                if isinstance(ep, UdpHubLink)
                else ep.name
            )
            print(f"rescue-hq: listening on {where}", flush=True)
    except LinkError:
        for ep in opened:
            ep.close()
        raise
    return opened


def _open_sbs(choice: tuple[str, int] | str | None) -> SbsServer | None:
    """The SBS-1 feed for QGC (``choice``: --sbs, None when not given). The default
    address is best effort (another rescue-hq or a dump1090 may hold it: a warning,
    no feed); an address given is required."""
    if choice == SBS_OFF:
        return None
    explicit = isinstance(choice, tuple)
    host, port = choice if isinstance(choice, tuple) else DEFAULT_ADDRESS
    try:
        sbs = SbsServer(host, port)
    except OSError as exc:
        if explicit:
            raise LinkError(f"SBS-1 feed on {host}:{port}: {exc.strerror or exc}") from None
        print(
            f"rescue-hq: warning: no SBS-1 feed for QGC: {host}:{port}: {exc.strerror or exc} "
            "(give --sbs HOST:PORT, or --sbs off)",
            file=sys.stderr,
            flush=True,
        )
        return None
    where = sbs.address
    print(
        f"rescue-hq: SBS-1 feed for QGC's ADSB server setting on {where[0]}:{where[1]}", flush=True
    )
    return sbs


def _install_signal_handlers(stop: threading.Event) -> None:
    def handler(_signum: int, _frame: FrameType | None) -> None:
        stop.set()

    signal.signal(signal.SIGTERM, handler)
    signal.signal(signal.SIGINT, handler)


def _cmd_mark(args: argparse.Namespace) -> int:
    by_source = args.robot is not None or args.victim is not None
    if by_source == (args.hq_id is not None) or (by_source and None in (args.robot, args.victim)):
        raise UsageError("mark: give either --robot N --victim ID, or --id HQ_ID")
    action = (
        OperatorAction.RESCUED
        if args.rescued
        else OperatorAction.CONFIRMED
        if args.confirmed
        else OperatorAction.FALSE_ALARM
    )
    with _open_registry(args.db, must_exist=True) as registry:
        if by_source:
            targets = [(args.robot, args.victim)]
        else:
            found = [v for v in hq_victims(registry) if v.hq_id == args.hq_id]
            if not found:
                raise UsageError(f"mark: no HQ victim {args.hq_id} in {args.db}")
            targets = list(found[0].sources)
        for robot, victim in targets:
            try:
                seq = registry.add_action(robot, victim, action)
            except KeyError as exc:
                raise UsageError(f"mark: {exc.args[0]} (in {args.db})") from None
            print(
                f"action {seq}: {action.name} robot {robot} victim {victim} recorded; "
                "the running rescue-hq sends it until the robot acknowledges"
            )
    return EXIT_OK


def _cmd_export(args: argparse.Namespace) -> int:
    with _open_registry(args.db, must_exist=True) as registry:
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


def _cmd_list(args: argparse.Namespace) -> int:
    with _open_registry(args.db, must_exist=True) as registry:
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


def _cmd_assets(args: argparse.Namespace) -> int:
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


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    command = argv[0] if argv and argv[0] in _SUBCOMMANDS else "run"
    if argv and argv[0] in _SUBCOMMANDS:
        argv = argv[1:]
    parsers = {
        "run": (_run_parser, _cmd_run),
        "mark": (_mark_parser, _cmd_mark),
        "export": (_export_parser, _cmd_export),
        "list": (_list_parser, _cmd_list),
        "assets": (_assets_parser, _cmd_assets),
    }
    make_parser, run = parsers[command]
    args = make_parser().parse_args(argv)  # exits 2 on bad usage
    # `run`'s log goes through its own writer thread: a paused terminal must not stall
    # the main thread that acknowledges reports (hq/output.py).
    handler = (
        WriterLogHandler(TerminalWriter(sys.stderr, "hq-log"))
        if command == "run"
        else logging.StreamHandler(sys.stderr)
    )
    handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s"))
    logging.basicConfig(
        level=logging.INFO if getattr(args, "verbose", False) else logging.WARNING,
        handlers=[handler],
    )
    try:
        return run(args)
    except UsageError as exc:
        print(f"rescue-hq: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except LinkError as exc:
        print(f"rescue-hq: {exc}", file=sys.stderr)
        return EXIT_RUNTIME
    finally:
        handler.close()  # the last lines written (or, on a terminal that does not read, not)


if __name__ == "__main__":
    sys.exit(main())
