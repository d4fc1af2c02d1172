"""``rescue-companion``: the program on the Pi.

Exit status: 0 success (or stopped by SIGTERM/SIGINT), 1 runtime failure, 2 bad
configuration or usage (systemd does not restart it: RestartPreventExitStatus=2),
3 the state directory cannot be created or written (a corrupt state file is moved
aside and the service starts afresh in a new ID epoch: companion/storage/recovery.py).
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
from collections.abc import Sequence
from pathlib import Path

from companion.config import Config
from companion.config_load import ConfigError, load_config

EXIT_OK = 0
EXIT_FAILURE = 1
EXIT_CONFIG = 2
EXIT_STATE = 3

log = logging.getLogger(__name__)


_CONFIG_HELP = "the TOML config file (docs/CONFIG.md; on the Pi /etc/rescue-companion/config.toml)"


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="rescue-companion",
        description="The victim-finding program on the rover's companion computer.",
        epilog="Exit status: 0 ok, 1 runtime failure, 2 bad configuration or input, "
        "3 the state directory cannot be written.",
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="log at DEBUG level")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    check = sub.add_parser(
        "check-config",
        help="validate a config file and print the result",
        description="Validate a config file, its camera calibration and the devices it "
        "names (camera, video file or frames folder, serial ports); exit 2 naming the "
        "first problem.",
    )
    check.add_argument("--config", type=Path, required=True, help=_CONFIG_HELP)
    check.add_argument(
        "--no-devices",
        action="store_true",
        help="check the file only, not that its camera and serial ports exist here "
        "(for a config meant for another machine)",
    )
    run = sub.add_parser(
        "run",
        help="run the companion service (systemd Type=notify)",
        description="Run the service: vehicle link, camera, detection, tracking, "
        "reports to the HQ. Stops on SIGTERM or SIGINT.",
    )
    run.add_argument("--config", type=Path, required=True, help=_CONFIG_HELP)
    run.add_argument(
        "--debug-processing-delay-s",
        type=float,
        default=0.0,
        metavar="SECONDS",
        help="fault injection for tests: extra processing time per frame",
    )
    run.add_argument(
        "--debug-stall-after-s",
        type=float,
        default=None,
        metavar="SECONDS",
        help="fault injection for tests: the processing loop hangs after this long",
    )
    rep = sub.add_parser(
        "replay",
        help="run the pipeline offline on a recorded mission",
        description="Run the live pipeline offline on a recorded mission "
        "(docs/REPLAY.md); exit 2 for unusable inputs, 1 if the output cannot be written.",
    )
    rep.add_argument(
        "--config", type=Path, required=True, help="the companion's config (camera, detector, ...)"
    )
    rep.add_argument(
        "--tlog", type=Path, required=True, help="the autopilot's telemetry log (.tlog)"
    )
    rep.add_argument(
        "--frames",
        type=Path,
        required=True,
        metavar="DIR",
        help="folder of frames named <unix_time_us>.jpg or .png",
    )
    rep.add_argument(
        "--thermal-frames",
        type=Path,
        default=None,
        metavar="DIR",
        help="folder of thermal frames named <unix_time_us>.png (16-bit, centi-kelvin) on "
        "the tlog's clock; needs the config's [thermal] section",
    )
    rep.add_argument(
        "--out",
        type=_replay_out,
        required=True,
        help="the victims JSON file to write (a map PNG goes beside it), or a folder "
        "(one that exists, or a name ending in /) for victims.json and victims.png",
    )
    det = sub.add_parser(
        "detect",
        help="run the perception step on image and video files",
        description="Run the person detection on image and video files and print what it finds.",
    )
    det.add_argument(
        "--config", type=Path, default=None, help="camera and detector settings (default: built-in)"
    )
    det.add_argument(
        "--json", action="store_true", help="print one JSON object per image or video frame"
    )
    det.add_argument(
        "--annotate",
        type=Path,
        default=None,
        metavar="DIR",
        help="write a copy of each image (a PNG) or video (an MP4) with its detections "
        "drawn into DIR",
    )
    det.add_argument(
        "--every",
        type=_positive_int,
        default=1,
        metavar="N",
        help="in a video, detect on every N-th frame (default 1: all)",
    )
    det.add_argument(
        "images",
        type=Path,
        nargs="+",
        metavar="IMAGE_OR_DIR",
        help="image or video files, or folders of them",
    )
    models = sub.add_parser(
        "models",
        help="fetch or check the person model files",
        description="Fetch the person model files (checked by sha256) or check those there.",
    )
    models.add_argument(
        "action",
        choices=["fetch", "check"],
        help="fetch: download what is missing or wrong; check: verify the files",
    )
    models.add_argument(
        "--dir", type=Path, default=None, help="model folder (default: the one in the venv)"
    )
    return parser


def _replay_out(text: str) -> Path:
    """argparse type: ``--out``; a name ending in / is a folder even before it exists
    (Path drops the slash: "out/" wrote a file named out)."""
    return Path(text) / "victims.json" if text.endswith(("/", os.sep)) else Path(text)


def _positive_int(text: str) -> int:
    """argparse type: a whole number >= 1."""
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a whole number >= 1, got {text!r}")
    return value


def _models(action: str, folder: Path | None) -> int:
    from companion.vision import models

    where = folder or models.default_model_dir()
    if action == "fetch":
        try:
            written = models.fetch(folder)
        except models.ModelMissing as exc:
            print(f"rescue-companion: models: {exc}", file=sys.stderr)
            return EXIT_FAILURE
        print(f"models ok in {where} ({len(written)} downloaded, checked by sha256)")
        return EXIT_OK
    problems = models.verify(folder)
    for line in problems:
        print(f"rescue-companion: models: {line}", file=sys.stderr)
    if not problems:
        print(f"models ok in {where}")
    return EXIT_CONFIG if problems else EXIT_OK


def _detect(args: argparse.Namespace) -> int:
    from companion.commands.detect import run_detect
    from companion.vision.base import VisionError

    config = None
    if args.config is not None:
        try:
            config = load_config(args.config)
        except ConfigError as exc:
            print(f"rescue-companion: config error: {exc}", file=sys.stderr)
            return EXIT_CONFIG
    try:
        return run_detect(config, args.images, args.json, args.annotate, args.every)
    except VisionError as exc:
        print(f"rescue-companion: detect: {exc}", file=sys.stderr)
        return EXIT_CONFIG


def _missing_devices(config: Config) -> list[str]:
    """What the config names on this machine that is not there: a camera device,
    video file or frames folder, a serial port. ``run`` waits for a serial port or a
    camera that may appear later; ``check-config`` is the pre-flight check and fails."""
    from companion.sources.base import CameraError
    from companion.sources.colour_open import parse_source
    from mavlink_io.linkspec import parse_link

    problems: list[str] = []
    try:
        spec = parse_source(config.camera.source)
    except CameraError as exc:
        return [f"camera.{exc}"]
    paths = {
        "device": Path(f"/dev/video{spec.target}"),
        "file": Path(spec.target),
        "frames": Path(spec.target),
    }
    path = paths.get(spec.kind)
    if path is not None and not path.exists():
        what = {"device": "no such camera device", "file": "no such video file"}
        problems.append(
            f"camera.source = {config.camera.source!r}: "
            f"{what.get(spec.kind, 'no such frames folder')} {path}"
        )
    problems += _missing_thermal(config)
    for key, url in (("vehicle.url", config.vehicle.url), ("hq.url", config.hq.url)):
        link = parse_link(url) if url else None
        if link is not None and link.kind == "serial" and not Path(link.device).exists():
            problems.append(f"{key} = {url!r}: no such serial port {link.device}")
    return problems


def _missing_thermal(config: Config) -> list[str]:
    """The thermal camera device or frames folder the config names, when it is not
    here (``lepton`` alone: no PureThermal board found by its V4L2 name)."""
    from companion.sources.base import CameraError
    from companion.sources.thermal import parse_thermal_source
    from companion.sources.thermal_live import find_purethermal

    if config.thermal is None:
        return []
    source = config.thermal.source
    spec = parse_thermal_source(source)  # checked when the config was loaded
    if spec.kind == "sim":
        return []  # a network camera: the service waits for it and says so
    if spec.kind == "frames":
        if not Path(spec.target).is_dir():
            return [f"thermal.source = {source!r}: no such thermal frames folder {spec.target}"]
    elif not spec.target:
        try:
            find_purethermal()
        except CameraError as exc:
            return [f"thermal.source = {source!r}: {exc}"]
    elif not Path(spec.target).exists():
        return [f"thermal.source = {source!r}: no such thermal camera device {spec.target}"]
    return []


def _check_config(config: Config, devices: bool = True) -> int:
    from companion.calibration import camera_model

    problems = _missing_devices(config) if devices else []
    for line in problems:
        print(f"rescue-companion: config error: {line}", file=sys.stderr)
    if problems:
        return EXIT_CONFIG
    cam = camera_model(config.camera)
    k = cam.intrinsics
    if config.thermal is None:
        thermal = "colour camera only"
    else:
        t = camera_model(config.thermal).intrinsics
        thermal = (
            f"thermal {config.thermal.source} {t.width_px}x{t.height_px} fx={t.fx_px:.1f}px "
            f"emissivity {config.thermal.emissivity:g}"
        )
    print(
        f"config ok: vehicle {config.vehicle.url}, camera {config.camera.source} "
        f"{k.width_px}x{k.height_px} fx={k.fx_px:.1f}px, {thermal}, detector "
        f"{config.detector.backend}, state in {config.paths.state_dir}"
    )
    return EXIT_OK


def _run(config: Config, delay_s: float, stall_after_s: float | None) -> int:
    from companion.service.processing import FaultInjection
    from companion.service.run import Service
    from companion.service.sdnotify import Notifier
    from companion.service.stopsignals import StopSignals
    from companion.storage.store import StoreError
    from companion.vision.base import VisionError
    from mavlink_io.errors import LinkError, SigningError, TlogError

    notifier = Notifier()
    try:
        service = Service(config, notifier, FaultInjection(delay_s, stall_after_s))
    except (SigningError, VisionError, TlogError) as exc:
        print(f"rescue-companion: {exc}", file=sys.stderr)
        return EXIT_CONFIG
    except StoreError as exc:
        print(f"rescue-companion: {exc}", file=sys.stderr)
        return EXIT_STATE
    except LinkError as exc:
        print(f"rescue-companion: {exc}", file=sys.stderr)
        return EXIT_FAILURE

    signals = StopSignals()
    signals.install()
    try:
        return service.run(signals.reason)
    finally:
        notifier.close()


def _replay(
    config: Config, tlog: Path, frames: Path, out: Path, thermal_frames: Path | None
) -> int:
    from companion.commands.replay import prepare_output, replay, write_outputs
    from companion.sources.base import CameraError
    from companion.vision.base import VisionError
    from mavlink_io.errors import TlogError

    try:
        out = prepare_output(out)  # before the mission is processed, not after
    except OSError as exc:
        print(f"rescue-companion: replay: cannot write {out}: {exc}", file=sys.stderr)
        return EXIT_FAILURE
    try:
        result = replay(config, tlog, frames, thermal_frames)
    except (CameraError, TlogError, VisionError) as exc:
        print(f"rescue-companion: replay: {exc}", file=sys.stderr)
        return EXIT_CONFIG
    try:
        png = write_outputs(result, out)
    except OSError as exc:
        print(f"rescue-companion: replay: cannot write {out}: {exc}", file=sys.stderr)
        return EXIT_FAILURE
    skipped = f", {result.frames_skipped} unreadable skipped" if result.frames_skipped else ""
    thermal = ""
    if thermal_frames is not None:
        thermal = f" and {result.thermal_frames} thermal frames"
        if result.thermal_frames_skipped:
            thermal += f" ({result.thermal_frames_skipped} skipped)"
    print(
        f"replayed {result.frames} frames{thermal} ({result.frames_without_pose} without a pose"
        f"{skipped}), {len(result.victims)} victims -> {out}, map {png}"
    )
    for v in sorted(result.victims, key=lambda v: v.victim_id):
        print(
            f"  #{v.victim_id:<3d} {v.urgency.name:<8s} {v.visibility_pct:5.1f}% "
            f"N{v.north_m:7.2f} E{v.east_m:7.2f} +-{v.sigma_m:.2f} m  {v.state.name.lower()} "
            f"({v.observations} obs; {', '.join(v.cues.names()) or 'no cue'})"
        )
    return EXIT_OK


def main(argv: Sequence[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO,
        format="%(levelname)s %(name)s: %(message)s",
        stream=sys.stderr,
    )
    if args.command == "models":
        return _models(args.action, args.dir)
    if args.command == "detect":
        return _detect(args)
    try:
        config = load_config(args.config)
    except ConfigError as exc:
        print(f"rescue-companion: config error: {exc}", file=sys.stderr)
        return EXIT_CONFIG
    if args.command == "check-config":
        return _check_config(config, devices=not args.no_devices)
    if args.command == "run":
        return _run(config, args.debug_processing_delay_s, args.debug_stall_after_s)
    if args.command == "replay":
        return _replay(config, args.tlog, args.frames, args.out, args.thermal_frames)
    raise AssertionError(f"unhandled command {args.command}")  # argparse guarantees the set


if __name__ == "__main__":
    sys.exit(main())
