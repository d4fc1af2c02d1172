"""``make pi-check``'s comparer: the arm64 root's results against the host's.

``compare HOST_DIR PI_DIR`` reads, from each folder, ``detect.jsonl`` (the JSON lines
of ``rescue-companion detect --json`` on the same pictures) and ``replay/victims.json``
(``rescue-companion replay`` of the same recorded mission), prints every difference
and exits 1 when one is beyond the tolerances: another number of people in a picture,
a box corner more than ``--box-px`` off, another urgency; another number of victims,
another state or urgency, a position more than ``--position-m`` off, other frame or
pose counts. Scores, visibilities and cues are compared and printed, not judged: the
two CPUs' float kernels round differently, and only what a user is told must agree.
It writes the figures to ``PI_DIR/comparison.json``.

``ops OUT.json -- DETECT_ARGS / REPLAY_ARGS`` counts, in this process, how often each
person model runs (the companion's own ``detect`` and ``replay`` commands, LiteRT's
interpreter counted) and how many multiply-accumulates one run of each model is, from
its convolution and fully connected layers' shapes: what a Pi 5 must compute per frame,
whatever this machine's speed.

Run by tools/pi-check.sh; exit 2 names an unreadable input.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import sys
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TextIO, TypeVar

import numpy as np

from fusion.errors import RescueError

T = TypeVar("T")

BOX_PX = 4.0
POSITION_M = 0.05


class PiCheckError(RescueError):
    """An input the comparer cannot read: its one-line message names the file."""


@dataclass(frozen=True)
class Found:
    """One person found in one picture."""

    box: tuple[float, float, float, float]  # x, y, w, h in pixels
    urgency: str
    score: float
    visibility_pct: float
    cues: frozenset[str]

    def corner_px(self, other: Found) -> float:
        """The largest difference of the two boxes' corners, in pixels."""
        x, y, w, h = self.box
        ox, oy, ow, oh = other.box
        return max(abs(x - ox), abs(y - oy), abs(x + w - ox - ow), abs(y + h - oy - oh))


@dataclass(frozen=True)
class Victim:
    victim_id: int
    state: str
    urgency: str
    north_m: float
    east_m: float
    visibility_pct: float

    def distance_m(self, other: Victim) -> float:
        return math.hypot(self.north_m - other.north_m, self.east_m - other.east_m)


@dataclass(frozen=True)
class Replay:
    counts: dict[str, int]  # frames, poses, ...: must be equal
    victims: tuple[Victim, ...]


@dataclass
class Comparison:
    differences: list[str]  # beyond the tolerances: the check fails
    notes: list[str]  # within them, or not judged
    figures: dict[str, object]

    @property
    def ok(self) -> bool:
        return not self.differences


def read_detect(path: Path) -> dict[str, list[Found]]:
    """``detect --json`` lines, keyed by the picture's file name."""
    try:
        lines = path.read_text().splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise PiCheckError(f"{path}: cannot be read: {exc}") from None
    out: dict[str, list[Found]] = {}
    for number, line in enumerate(lines, 1):
        if not line.strip():
            continue
        try:
            row = json.loads(line)
            name = Path(str(row["image"])).name
            out[name] = [
                Found(
                    tuple(float(v) for v in d["box"]),  # type: ignore[arg-type]
                    str(d["urgency"]),
                    float(d["score"]),
                    float(d["visibility_pct"]),
                    frozenset(str(c) for c in d["cues"]),
                )
                for d in row["detections"]
            ]
        except (ValueError, KeyError, TypeError) as exc:
            raise PiCheckError(f"{path}:{number}: not a detect --json line ({exc!r})") from None
        if any(len(f.box) != 4 for f in out[name]):
            raise PiCheckError(f"{path}:{number}: a box is not [x, y, w, h]")
    if not out:
        raise PiCheckError(f"{path}: no picture in it")
    return out


REPLAY_COUNTS = ("frames", "frames_skipped", "frames_without_pose", "thermal_frames", "poses")


def read_replay(path: Path) -> Replay:
    try:
        doc = json.loads(path.read_text())
        counts = {k: int(doc[k]) for k in REPLAY_COUNTS if k in doc}
        victims = tuple(
            Victim(
                int(v["victim_id"]),
                str(v["state"]),
                str(v["urgency"]),
                float(v["north_m"]),
                float(v["east_m"]),
                float(v["visibility_pct"]),
            )
            for v in doc["victims"]
        )
    except OSError as exc:
        raise PiCheckError(f"{path}: cannot be read: {exc}") from None
    except (ValueError, KeyError, TypeError) as exc:
        raise PiCheckError(f"{path}: not a replay victims.json ({exc!r})") from None
    return Replay(counts, victims)


def _pairs(
    host: Sequence[T], pi: Sequence[T], distance: Callable[[T, T], float]
) -> list[tuple[int, int]]:
    """Nearest pairs first, each item used once (greedy; a handful of items)."""
    candidates = sorted(
        (distance(h, p), i, j) for i, h in enumerate(host) for j, p in enumerate(pi)
    )
    used_h: set[int] = set()
    used_p: set[int] = set()
    pairs = []
    for _, i, j in candidates:
        if i not in used_h and j not in used_p:
            used_h.add(i)
            used_p.add(j)
            pairs.append((i, j))
    return pairs


def _box(box: tuple[float, ...]) -> str:
    return "[" + ", ".join(f"{v:g}" for v in box) + "]"


def compare_detect(
    host: dict[str, list[Found]], pi: dict[str, list[Found]], box_px: float = BOX_PX
) -> Comparison:
    diffs: list[str] = []
    notes: list[str] = []
    worst_px = worst_score = worst_vis = 0.0
    for name in sorted(set(host) - set(pi)):
        diffs.append(f"detect {name}: on the host only")
    for name in sorted(set(pi) - set(host)):
        diffs.append(f"detect {name}: on aarch64 only")
    for name in sorted(set(host) & set(pi)):
        h, p = host[name], pi[name]
        if len(h) != len(p):
            diffs.append(f"detect {name}: {len(h)} people on the host, {len(p)} on aarch64")
        for i, j in _pairs(h, p, Found.corner_px):
            a, b = h[i], p[j]
            px = a.corner_px(b)
            worst_px = max(worst_px, px)
            worst_score = max(worst_score, abs(a.score - b.score))
            worst_vis = max(worst_vis, abs(a.visibility_pct - b.visibility_pct))
            if px > box_px:
                diffs.append(
                    f"detect {name}: box {_box(a.box)} on the host, {_box(b.box)} on aarch64"
                )
            if a.urgency != b.urgency:
                diffs.append(f"detect {name}: {a.urgency} on the host, {b.urgency} on aarch64")
            if a.cues != b.cues:
                notes.append(
                    f"detect {name}: cues {sorted(a.cues)} on the host, {sorted(b.cues)} on aarch64"
                )
    figures: dict[str, object] = {
        "pictures": len(set(host) | set(pi)),
        "people found, host / aarch64": f"{sum(map(len, host.values()))} / "
        f"{sum(map(len, pi.values()))}",
        "largest box corner difference, px": round(worst_px, 2),
        "largest score difference": round(worst_score, 4),
        "largest visibility difference, points": round(worst_vis, 2),
    }
    return Comparison(diffs, notes, figures)


def compare_replay(host: Replay, pi: Replay, position_m: float = POSITION_M) -> Comparison:
    diffs: list[str] = []
    notes: list[str] = []
    for key in sorted(set(host.counts) | set(pi.counts)):
        if host.counts.get(key) != pi.counts.get(key):
            diffs.append(
                f"replay {key}: {host.counts.get(key)} on the host, {pi.counts.get(key)} on aarch64"
            )
    if len(host.victims) != len(pi.victims):
        diffs.append(
            f"replay: {len(host.victims)} victims on the host, {len(pi.victims)} on aarch64"
        )
    worst_m = worst_vis = 0.0
    pairs = _pairs(host.victims, pi.victims, Victim.distance_m)
    for i, j in pairs:
        a, b = host.victims[i], pi.victims[j]
        off = a.distance_m(b)
        worst_m = max(worst_m, off)
        worst_vis = max(worst_vis, abs(a.visibility_pct - b.visibility_pct))
        where = f"replay victim #{a.victim_id} (aarch64 #{b.victim_id})"
        if off > position_m:
            diffs.append(
                f"{where}: at N {a.north_m:.3f} E {a.east_m:.3f} m on the host, "
                f"N {b.north_m:.3f} E {b.east_m:.3f} m on aarch64 ({off:.3f} m apart)"
            )
        if (a.state, a.urgency) != (b.state, b.urgency):
            diffs.append(
                f"{where}: {a.state} {a.urgency} on the host, {b.state} {b.urgency} on aarch64"
            )
        if a.victim_id != b.victim_id:
            notes.append(f"{where}: numbered differently")
    figures: dict[str, object] = {
        "replay victims, host / aarch64": f"{len(host.victims)} / {len(pi.victims)}",
        "replay urgencies, host": ", ".join(v.urgency for v in host.victims) or "none",
        "largest victim position difference, m": round(worst_m, 4),
        "largest victim visibility difference, points": round(worst_vis, 2),
    }
    figures.update({f"replay {k}": v for k, v in host.counts.items()})
    return Comparison(diffs, notes, figures)


def compare_dirs(
    host_dir: Path, pi_dir: Path, box_px: float = BOX_PX, position_m: float = POSITION_M
) -> Comparison:
    det = compare_detect(
        read_detect(host_dir / "detect.jsonl"), read_detect(pi_dir / "detect.jsonl"), box_px
    )
    rep = compare_replay(
        read_replay(host_dir / "replay" / "victims.json"),
        read_replay(pi_dir / "replay" / "victims.json"),
        position_m,
    )
    return Comparison(
        det.differences + rep.differences, det.notes + rep.notes, det.figures | rep.figures
    )


# ---- what a Pi 5 must compute: model runs per frame, multiply-accumulates per run ----

_MAC_OPS = {
    "CONV_2D",
    "DEPTHWISE_CONV_2D",
    "FULLY_CONNECTED",
    "TRANSPOSE_CONV",
    "Convolution2DTransposeBias",  # MediaPipe's custom op (the selfie model's last layer)
}


def model_macs(path: Path) -> int:
    """Multiply-accumulates of one run of a .tflite model, from its layers' shapes."""
    from ai_edge_litert.interpreter import Interpreter

    it = Interpreter(model_path=str(path))
    it.allocate_tensors()
    shapes = {t["index"]: tuple(int(s) for s in t["shape"]) for t in it.get_tensor_details()}
    total = 0
    for op in it._get_ops_details():
        name = op["op_name"]
        if name not in _MAC_OPS:
            continue
        ins, outs = list(op["inputs"]), list(op["outputs"])
        out_elems = int(np.prod(shapes[outs[0]]))
        if name == "CONV_2D":  # filter [cout, kh, kw, cin]
            _, kh, kw, cin = shapes[ins[1]]
            total += out_elems * kh * kw * cin
        elif name == "DEPTHWISE_CONV_2D":  # filter [1, kh, kw, cout]
            _, kh, kw, _ = shapes[ins[1]]
            total += out_elems * kh * kw
        elif name == "FULLY_CONNECTED":  # weights [out, in]
            total += out_elems * shapes[ins[1]][1]
        else:  # each input element times a filter [cout, kh, kw, cin]
            cout, kh, kw, _ = shapes[ins[1]]
            # TRANSPOSE_CONV: (output shape, filter, input); the custom op: (input, filter, bias)
            data = ins[2] if name == "TRANSPOSE_CONV" else ins[0]
            total += int(np.prod(shapes[data])) * kh * kw * cout
    return total


def count_model_runs(argv: Sequence[str], stdout: TextIO) -> tuple[Counter[str], int]:
    """Runs ``rescue-companion ARGV`` here (its output to ``stdout``) and counts each
    model's runs, by file name."""
    import ai_edge_litert.interpreter as litert

    from companion.commands.cli import main as companion_main

    runs: Counter[str] = Counter()
    real = litert.Interpreter

    class Counting(real):  # type: ignore[misc, valid-type]
        def __init__(self, *args: object, model_path: str = "", **kwargs: object) -> None:
            super().__init__(*args, model_path=model_path, **kwargs)
            self._name = Path(model_path).name

        def invoke(self) -> None:
            runs[self._name] += 1
            super().invoke()

    litert.Interpreter = Counting
    try:
        with contextlib.redirect_stdout(stdout):
            status = companion_main(list(argv))
    finally:
        litert.Interpreter = real
    return runs, status


def ops_report(
    models_dir: Path, runs: Counter[str], frames: int, macs: Callable[[Path], int] = model_macs
) -> dict[str, object]:
    """Per model: MACs a run, runs a frame; and the total MACs a frame, in millions."""
    per_model = {}
    total = 0.0
    for name in sorted(runs):
        one = macs(models_dir / name)
        per_frame = runs[name] / frames
        total += one * per_frame
        per_model[name] = {
            "mmac_per_run": round(one / 1e6, 1),
            "runs_per_frame": round(per_frame, 3),
        }
    return {"frames": frames, "models": per_model, "mmac_per_frame": round(total / 1e6, 1)}


def _ops(args: argparse.Namespace) -> int:
    from companion.config import DetectorConfig
    from companion.vision.models import default_model_dir

    report: dict[str, object] = {"model_threads (the default)": DetectorConfig().model_threads}
    log = args.out.with_suffix(".stdout")
    with log.open("w") as stdout:
        counted = [
            (label, argv, frames, *count_model_runs(argv, stdout))
            for label, argv, frames in (
                ("detect (each picture alone)", args.detect, args.detect_frames),
                ("replay (a camera stream)", args.replay, args.replay_frames),
            )
        ]
    for label, argv, frames, runs, status in counted:
        if status != 0:
            raise PiCheckError(f"rescue-companion {' '.join(argv)}: exit status {status}")
        report[label] = ops_report(default_model_dir(), runs, frames)
    args.out.write_text(json.dumps(report, indent=2) + "\n")
    for label, rep in report.items():
        if not isinstance(rep, dict):
            print(f"{label}: {rep}")
            continue
        print(f"{label}: {rep['mmac_per_frame']} million multiply-accumulates a frame")
        for name, m in rep["models"].items():
            print(f"  {name}: {m['mmac_per_run']} M a run, {m['runs_per_frame']} runs a frame")
    return 0


def _compare(args: argparse.Namespace) -> int:
    result = compare_dirs(args.host, args.pi, args.box_px, args.position_m)
    for line in result.notes:
        print(f"note: {line}")
    for line in result.differences:
        print(f"DIFFERS: {line}")
    for key, value in result.figures.items():
        print(f"  {key}: {value}")
    (args.pi / "comparison.json").write_text(
        json.dumps(
            {"ok": result.ok, "differences": result.differences, "notes": result.notes}
            | {"figures": result.figures},
            indent=2,
        )
        + "\n"
    )
    if result.ok:
        print(
            f"pi-check: aarch64 and host agree (boxes within {args.box_px:g} px, "
            f"victims within {args.position_m:g} m)"
        )
        return 0
    print(f"pi-check: {len(result.differences)} differences beyond the tolerances")
    return 1


def _split_argv(items: list[str]) -> tuple[list[str], list[str]]:
    if "/" not in items:
        raise PiCheckError("ops: give DETECT_ARGS / REPLAY_ARGS")
    cut = items.index("/")
    return items[:cut], items[cut + 1 :]


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="tools/pi_check.py", description=__doc__.split("\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    c = sub.add_parser("compare", help="compare the aarch64 results with the host's")
    c.add_argument("host", type=Path)
    c.add_argument("pi", type=Path)
    c.add_argument("--box-px", type=float, default=BOX_PX)
    c.add_argument("--position-m", type=float, default=POSITION_M)
    o = sub.add_parser("ops", help="model runs a frame and multiply-accumulates a run")
    o.add_argument("out", type=Path)
    o.add_argument("--detect-frames", type=int, required=True)
    o.add_argument("--replay-frames", type=int, required=True)
    o.epilog = "then: -- DETECT_ARGS / REPLAY_ARGS (rescue-companion's arguments)"
    items = list(sys.argv[1:] if argv is None else argv)
    commands = items[items.index("--") + 1 :] if "--" in items else []
    args = parser.parse_args(items[: items.index("--")] if "--" in items else items)
    try:
        if args.command == "compare":
            return _compare(args)
        args.detect, args.replay = _split_argv(commands)
        return _ops(args)
    except PiCheckError as exc:
        print(f"pi-check: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
