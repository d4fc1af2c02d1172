"""``rescue-hq run``: the HQ's links, the app's loop, the SBS-1 feed for QGC and the
browser console, until SIGTERM, SIGINT or ``--duration-s``."""

from __future__ import annotations

import argparse
import logging
import signal
import sys
import threading
from pathlib import Path
from types import FrameType
from typing import TYPE_CHECKING

from hq.app import HqApp, HqOptions
from hq.cli_args import (
    DEFAULT_DB,
    DEFAULT_LISTEN,
    DEFAULT_WEB,
    EXIT_OK,
    SBS_OFF,
    UsageError,
    open_registry,
    parse_duration,
    parse_origin,
    parse_sbs,
    parse_sysid,
    parse_web_address,
)
from hq.registry_file import RegistryError
from hq.sbs import DEFAULT_ADDRESS, SbsServer
from hq.web.state import LiveRobots
from mavlink_io.errors import LinkError, LinkSpecError, SigningError
from mavlink_io.hub import SingleLink, UdpHubLink, open_endpoint
from mavlink_io.linkspec import LinkSpec, parse_link
from mavlink_io.signing import load_signing

if TYPE_CHECKING:
    from hq.web.server import Console

log = logging.getLogger("hq")


def run_parser() -> argparse.ArgumentParser:
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
    p.add_argument("--sysid", type=parse_sysid, default=245, help="the HQ's MAVLink system ID")
    p.add_argument(
        "--export-dir",
        type=Path,
        help="write victims.geojson/.kml/.csv and coverage.geojson (the searched-area map) here",
    )
    p.add_argument("--signing-key", type=Path, help="MAVLink 2 signing key file (mode 0600)")
    p.add_argument(
        "--origin",
        type=parse_origin,
        help="EKF origin LAT,LON,ALT of robots that report only local NED positions",
    )
    p.add_argument("--no-table", action="store_true", help="plain log lines, no live table")
    p.add_argument(
        "--sbs",
        type=parse_sbs,
        metavar="HOST:PORT|off",
        help="serve the victims to QGroundControl's ADS-B layer as an SBS-1 feed "
        f"(default {DEFAULT_ADDRESS[0]}:{DEFAULT_ADDRESS[1]}; skipped with a warning "
        "when that port is taken; off: no feed)",
    )
    p.add_argument("--duration-s", type=parse_duration, help="run this long, then exit cleanly")
    web = p.add_mutually_exclusive_group()
    web.add_argument(
        "--web",
        type=parse_web_address,
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
        type=parse_duration,
        default=5.0,
        help="the console shows a robot's link as lost after this long unheard (default 5)",
    )
    p.add_argument("-v", "--verbose", action="store_true", help="log at INFO level")
    return p


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

    host, port = args.web or parse_web_address(DEFAULT_WEB)
    token = _read_token(args.web_token_file) if args.web_token_file else None
    options = ConsoleOptions(host, port, token, args.link_timeout_s)
    try:
        return Console(args.db, options, live)
    except AccessConfigError as exc:
        raise UsageError(str(exc)) from None


def run_command(args: argparse.Namespace) -> int:
    try:
        specs = [parse_link(url) for url in (args.listen or [DEFAULT_LISTEN])]
        signing = load_signing(args.signing_key) if args.signing_key else None
    except (LinkSpecError, SigningError) as exc:
        raise UsageError(str(exc)) from None
    live = LiveRobots()
    stop = threading.Event()
    _install_signal_handlers(stop)  # before anything is printed: a stop then is clean too
    console = _console(args, live)  # a bad console setting: exit 2 before any file is made
    registry = open_registry(args.db, must_exist=False, recover=True)
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
