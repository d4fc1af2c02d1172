"""Coverage map on the radio: what the transport to rescue-hq costs, framing and acknowledgements included

Missions of the accuracy suite (whole lawnmower searches of 12 x 8 m worlds, the
colour camera at the suite's frame rate, rendered by the simulator), the map built
as the service builds it, and companion/reporting/coverage_sender.py sending it with the
default ``[coverage]`` (300 B/s, every 10 s; and at 600 B/s) on the mission's clock. The HQ's side
answers every piece 0.2 s after it was sent; "lossy" loses 10 % of the pieces and
10 % of the answers (seeded). Each piece and each answer is encoded by the project's
codec exactly as on the radio: inside TUNNEL, unsigned and signed. Target: well
within a 57,600-baud radio's 5,760 B/s shared with telemetry, reports and pictures.
"""

from __future__ import annotations

import random
from typing import Any

import numpy as np

from bench.accuracy import SUITE, SUITE_FPS
from bench.coverage import _pose
from companion.config import CoverageConfig
from companion.coverage import CoverageMapper, SharedGrid
from companion.reporting.coverage_sender import CoverageSender
from fusion.coverage import CoverageDelta
from fusion.params import GeolocationParams
from fusion.types import Sensor
from hq.wire import wrap_tunnel
from mavlink_io import coverage
from mavlink_io.codec import Codec
from mavlink_io.dialect import RESCUE_COVERAGE_ID
from mavlink_io.signing import Signing
from scenarios.motion import Trajectory, route_of
from scenarios.render import Renderer

MISSIONS = ("mixed", "lawnmower", "seed1")
ANSWER_DELAY_S = 0.2
KEY = bytes(range(32))


def _codecs(signed: bool) -> tuple[Codec, Codec]:
    signing = Signing(KEY, 1) if signed else None
    return Codec(1, 191, signing), Codec(245, 190, signing)


class _Link:
    """One sender and the HQ's answers to it, over a link that loses ``loss`` of each."""

    def __init__(
        self, grid: SharedGrid, loss: float, now: list[float], cfg: CoverageConfig
    ) -> None:
        self.rnd = random.Random(1)
        self.loss = loss
        self.now = now
        self.wire = {False: 0, True: 0}  # bytes on the radio, unsigned / signed, both ways
        self.answers: list[tuple[float, int]] = []  # (due, seq)
        self.codecs = {s: _codecs(s) for s in (False, True)}
        self.sender = CoverageSender(grid, cfg, self._send, clock=lambda: now[0], first_seq=1)
        self.backlog = 0

    def _send(self, seq: int, piece: CoverageDelta) -> None:
        for signed, (robot, _hq) in self.codecs.items():
            msg = coverage.piece_msg(robot.module, seq, piece)
            self.wire[signed] += len(robot.encode(wrap_tunnel(robot, msg, 0, 0)))
        if self.rnd.random() < self.loss:
            return
        for signed, (_robot, hq) in self.codecs.items():
            ack = hq.module.MAVLink_rescue_ack_message(1, 191, RESCUE_COVERAGE_ID, seq, 0)
            self.wire[signed] += len(hq.encode(wrap_tunnel(hq, ack, 1, 191)))
        if self.rnd.random() >= self.loss:
            self.answers.append((self.now[0] + ANSWER_DELAY_S, seq))

    def step(self) -> None:
        due = [a for a in self.answers if a[0] <= self.now[0]]
        for answer in due:
            self.answers.remove(answer)
            self.sender.on_ack(answer[1], 0)
        self.sender.poll()
        self.backlog = max(self.backlog, self.sender.pending)


def measure(key: str) -> dict[str, dict[str, float]]:
    """One mission, its map sent over a clean and a lossy link at once."""
    (scenario,) = [s for s in SUITE if s.key == key]
    world = scenario.make_world()
    camera = scenario.camera()
    trajectory = Trajectory(
        world.start_ne_m, world.start_heading_rad, route_of(world), speed_m_s=0.4, seed=world.seed
    )
    duration_s = trajectory.duration_s() + 2.0
    renderer = Renderer(world, camera)
    grid = SharedGrid()
    mapper = CoverageMapper(grid, GeolocationParams(), camera)
    now = [0.0]
    default, faster = CoverageConfig(), CoverageConfig(rate_bytes_s=600.0)
    links = {
        "no loss": _Link(grid, 0.0, now, default),
        "lossy": _Link(grid, 0.1, now, default),
        "600 B/s, lossy": _Link(grid, 0.1, now, faster),
    }
    frames = int(duration_s * SUITE_FPS)
    for i in range(frames):
        now[0] = t_s = (i + 0.5) / SUITE_FPS
        tp = trajectory.pose_at(t_s)
        mapper.add(_pose(tp), Sensor.COLOUR, renderer.render(tp, frame_key=i).image)
        for link in links.values():
            link.step()
    end_s = now[0]
    minutes = duration_s / 60.0
    out = {}
    for label, link in links.items():
        now[0] = end_s
        while link.sender.acked_version < grid.version and now[0] < end_s + 600.0:
            now[0] += 0.1
            link.step()
        out[label] = {
            "unsigned": link.wire[False] / minutes,
            "signed": link.wire[True] / minutes,
            "unsigned_s": link.wire[False] / (end_s + (now[0] - end_s)),
            "cells": len(grid.delta_since(0)),
            "pieces": link.sender.counters.pieces,
            "resends": link.sender.counters.resends,
            "backlog": link.backlog,
            "after_end_s": now[0] - end_s,
            "minutes": minutes,
        }
    return out


def run() -> dict[str, Any]:
    measured = [measure(k) for k in MISSIONS]
    out: dict[str, Any] = {}
    for label in ("no loss", "lossy", "600 B/s, lossy"):
        rows = [m[label] for m in measured]
        for k, r in zip(MISSIONS, rows, strict=True):
            out[f"{k}, {label}: pieces sent (resends) for cells looked at, mission minutes"] = (
                f"{r['pieces']} ({r['resends']}) for {r['cells']}, {r['minutes']:.1f}"
            )
            out[f"{k}, {label}: most pieces waiting; HQ holds all, s after the mission"] = (
                f"{r['backlog']}; {r['after_end_s']:.1f}"
            )
        uns = [r["unsigned"] for r in rows]
        sig = [r["signed"] for r in rows]
        per_s = [r["unsigned_s"] for r in rows]
        out[
            f"{label}: the mission's map on the radio, both ways, per mission minute, unsigned"
            " / signed, median"
        ] = f"{np.median(uns):.0f} / {np.median(sig):.0f} B"
        out[f"{label}: bytes a second while sending, both ways, unsigned, median / max"] = (
            f"{np.median(per_s):.0f} / {max(per_s):.0f}"
        )
    return out


if __name__ == "__main__":
    for name, value in run().items():
        print(f"{name}: {value}")
