"""`rescue-hq`: the ground side that receives, acknowledges, merges and exports victims.

    rescue-hq [run] [--listen URL ...] [--db PATH] [--sysid N] [--export-dir DIR]
                    [--signing-key FILE] [--origin LAT,LON,ALT] [--no-table]
                    [--sbs HOST:PORT|off] [--duration-s T] [--web HOST:PORT | --no-web]
                    [--web-token-file FILE] [--link-timeout-s T] [-v]
    rescue-hq mark   --db PATH (--robot N --victim ID | --id HQ_ID)
                     (--rescued | --false-alarm | --confirmed)
    rescue-hq look   --db PATH (--robot N --victim ID | --id HQ_ID)
    rescue-hq looks  --db PATH --robot N off|on
    rescue-hq export --db PATH --out DIR [--origin LAT,LON,ALT]
    rescue-hq list   --db PATH
    rescue-hq assets fetch|verify

Exit status: 0 ok; 1 runtime failure (a link cannot be opened, an export cannot
be written); 2 bad usage, configuration or database (a clear one-line message
naming the file).
"""

from __future__ import annotations

import logging
import sys

from hq.cli_args import EXIT_RUNTIME, EXIT_USAGE, UsageError
from hq.cli_registry import (
    assets_command,
    assets_parser,
    export_command,
    export_parser,
    list_command,
    list_parser,
    look_command,
    look_parser,
    looks_command,
    looks_parser,
    mark_command,
    mark_parser,
)
from hq.cli_run import run_command, run_parser
from hq.output import TerminalWriter, WriterLogHandler
from mavlink_io.errors import LinkError

_SUBCOMMANDS = ("run", "mark", "look", "looks", "export", "list", "assets")


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    command = argv[0] if argv and argv[0] in _SUBCOMMANDS else "run"
    if argv and argv[0] in _SUBCOMMANDS:
        argv = argv[1:]
    parsers = {
        "run": (run_parser, run_command),
        "mark": (mark_parser, mark_command),
        "look": (look_parser, look_command),
        "looks": (looks_parser, looks_command),
        "export": (export_parser, export_command),
        "list": (list_parser, list_command),
        "assets": (assets_parser, assets_command),
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
