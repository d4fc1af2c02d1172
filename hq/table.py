"""The live terminal table: every victim and robot, readable at a glance.

Most urgent first. VICTIM is the HQ's name for the person (``CRIT07``: urgency, or
RESC / FALSE, and the HQ's number), as QGC's map label, the console card and the
robots' announcements say it. VISIBLE is the share of the body a robot sees, in percent (of
several robots, the lowest: the most buried view); urgency in colour (CRITICAL red,
MEDIUM orange, LIGHT green) when the output is a terminal, plain text otherwise. Rescued and false-alarm
victims are dimmed. ``ACK`` counts operator actions still waiting for the robot's
acknowledgement. CUES says what saw the person, on any robot: ``body`` (the colour
camera's person models), ``part`` (only an exposed part: a hand, a face), ``warm``
(the thermal camera); ``-`` when the robots do not say. A robot's line ends with its
closer looks (``looks on: 3 made, 1 confirmed, 1 aborted``). Rendering is pure (text in, text out); the app decides when to
redraw (at most 2 Hz).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from fusion.types import Cue, TrackState, Urgency
from hq.records import Robot
from hq.view import HqVictim
from mavlink_io.statustext import RETIRED_LABEL, URGENCY_LABEL, callsign

_RESET = "\x1b[0m"
_DIM = "\x1b[2m"
_BOLD = "\x1b[1m"
_URGENCY_COLOUR = {
    Urgency.CRITICAL: "\x1b[1;97;41m",  # bold white on red
    Urgency.MEDIUM: "\x1b[1;38;5;208m",  # bold orange (256 colours; yellow on 8-colour terms)
    Urgency.LIGHT: "\x1b[32m",  # green
}
CLEAR_SCREEN = "\x1b[H\x1b[2J"
_STATUS_FLAGS = (  # RESCUE_STATUS_FLAGS bits worth a glance
    (1, "VEH"),
    (2, "CAM"),
    (4, "HQ"),
    (16, "GEO"),
    (64, "SIGN"),
)
_ROBOT_SILENT_S = 5.0  # a robot unheard this long is shown as silent
_CUE_SHORT = {Cue.COLOUR_BODY: "body", Cue.COLOUR_PART: "part", Cue.WARM: "warm"}


@dataclass(frozen=True)
class Header:
    sysid: int | None  # None: reading a registry file, not running
    links: Sequence[str]
    reports_stored: int
    signing: bool
    warning: str | None = None  # e.g. the disk is full: shown in red under the title


def age(seconds: float) -> str:
    """A short age: 4s, 2m05s, 1h02m."""
    s = max(0, int(seconds))
    if s < 60:
        return f"{s}s"
    if s < 3600:
        return f"{s // 60}m{s % 60:02d}s"
    return f"{s // 3600}h{(s % 3600) // 60:02d}m"


def _position(v: HqVictim) -> str:
    if v.lat_deg is not None and v.lon_deg is not None:
        return f"{v.lat_deg:.6f},{v.lon_deg:.6f}"
    return f"N{v.north_m:+.1f} E{v.east_m:+.1f}"


def cues_short(cues: Cue) -> str:
    """``body+warm``; ``-`` when not known."""
    return "+".join(word for cue, word in _CUE_SHORT.items() if cues & cue) or "-"


def _paint(text: str, code: str, colour: bool) -> str:
    return f"{code}{text}{_RESET}" if colour else text


def victim_rows(victims: Sequence[HqVictim], now_unix_s: float, colour: bool) -> list[str]:
    head = (
        f"{'VICTIM':<8} {'URGENCY':<9}{'VISIBLE':>7} {'STATE':<17} {'ROBOT:VICTIM':<16}"
        f"{'POSITION':<24}{'±m':>5} {'SEEN':>7} {'ACK':>3} CUES"
    )
    rows = [_paint(head, _BOLD, colour)]
    for v in victims:
        srcs = " ".join(f"{r}:{i}" for r, i in v.sources)
        # The HQ's name for the person, as QGC's map label, the console card and the
        # robots' announcements after the HQ's answer say it (CRIT07).
        name = callsign(RETIRED_LABEL.get(v.state, URGENCY_LABEL[v.urgency]), v.hq_id)
        urgency = f"{v.urgency.name:<9}"
        done = v.state in (TrackState.RESCUED, TrackState.FALSE_ALARM)
        state = v.state.name + ("?" if v.actions_pending else "")
        line_rest = (
            f"{f'{v.visibility_pct:.0f}%':>7} {state:<17} {srcs:<16}{_position(v):<24}"
            f"{v.sigma_m:>5.1f} {age(now_unix_s - v.last_seen_unix_s):>7} "
            f"{v.actions_pending or '':>3} {cues_short(v.cues)}"
        )
        if done:
            rows.append(_paint(f"{name:<8} {urgency}{line_rest}", _DIM, colour))
        else:
            urgency_cell = _paint(urgency, _URGENCY_COLOUR[v.urgency], colour)
            rows.append(f"{name:<8} {urgency_cell}{line_rest}")
    if not victims:
        rows.append("   (no victims reported yet)")
    return rows


def robot_rows(robots: Sequence[Robot], now_unix_s: float, colour: bool) -> list[str]:
    rows = [
        _paint(
            f"{'ROBOT':>5} {'HEARD':>7} {'FPS':>5} {'CONF':>4} {'OUTBOX':>6}  HEALTH", _BOLD, colour
        )
    ]
    for r in robots:
        silent = now_unix_s - r.last_heard_unix_s > _ROBOT_SILENT_S
        heard = age(now_unix_s - r.last_heard_unix_s)
        st = r.status
        if st is None:
            line = f"{r.sysid:>5} {heard:>7} {'':>5} {'':>4} {'':>6}  (no RESCUE_STATUS yet)"
        else:
            health = " ".join(
                name if st.flags & bit else f"-{name.lower()}" for bit, name in _STATUS_FLAGS
            )
            line = (
                f"{r.sysid:>5} {heard:>7} {st.fps:>5.1f} "
                f"{st.victims_confirmed:>4} {st.outbox_pending:>6}  {health}  {st.look_words()}"
            )
        rows.append(_paint(line + "  SILENT", "\x1b[33m", colour) if silent else line)
    if not robots:
        rows.append("   (no robot heard yet)")
    return rows


def render(
    header: Header,
    victims: Sequence[HqVictim],
    robots: Sequence[Robot],
    now_unix_s: float,
    *,
    colour: bool,
) -> str:
    critical = sum(
        1
        for v in victims
        if v.urgency == Urgency.CRITICAL
        and v.state not in (TrackState.RESCUED, TrackState.FALSE_ALARM)
    )
    waiting = sum(v.actions_pending for v in victims)
    title = (
        f"rescue-hq{'' if header.sysid is None else f'  sysid {header.sysid}'}"
        f"  {' '.join(header.links)}"
        f"{'  signed' if header.signing else ''}  |  victims {len(victims)}"
        f" ({critical} critical open)  reports {header.reports_stored}"
        f"  waiting for ack {waiting}"
    )
    lines = [_paint(title, _BOLD, colour)]
    if header.warning:
        lines.append(_paint(header.warning, _URGENCY_COLOUR[Urgency.CRITICAL], colour))
    lines.append("")
    lines += victim_rows(victims, now_unix_s, colour)
    lines.append("")
    lines += robot_rows(robots, now_unix_s, colour)
    return "\n".join(lines) + "\n"
