"""``rescue-companion``: the program on the Pi.

Exit status: 0 success, 1 runtime failure, 2 bad configuration or usage.
"""

from __future__ import annotations

import argparse
import logging
import sys
from collections.abc import Sequence
from pathlib import Path

from companion.config import Config, ConfigError, load_config

EXIT_OK = 0
EXIT_FAILURE = 1
EXIT_CONFIG = 2

log = logging.getLogger(__name__)


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="rescue-companion", description=__doc__.splitlines()[0])
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    sub = parser.add_subparsers(dest="command", required=True)
    check = sub.add_parser("check-config", help="validate a config file and print the result")
    check.add_argument("--config", type=Path, required=True)
    return parser


def _check_config(config: Config) -> int:
    from companion.calibration import camera_model

    cam = camera_model(config.camera)
    k = cam.intrinsics
    print(
        f"config ok: vehicle {config.vehicle.url}, camera {config.camera.source} "
        f"{k.width_px}x{k.height_px} fx={k.fx_px:.1f}px, detector {config.detector.backend}, "
        f"state in {config.paths.state_dir}"
    )
    return EXIT_OK


def main(argv: Sequence[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO,
        format="%(levelname)s %(name)s: %(message)s",
        stream=sys.stderr,
    )
    try:
        config = load_config(args.config)
    except ConfigError as exc:
        print(f"rescue-companion: config error: {exc}", file=sys.stderr)
        return EXIT_CONFIG
    if args.command == "check-config":
        return _check_config(config)
    raise AssertionError(f"unhandled command {args.command}")  # argparse guarantees the set


if __name__ == "__main__":
    sys.exit(main())
