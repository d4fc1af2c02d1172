"""Score reported victims against the ground truth of a recorded or live mission.

Matching: one-to-one (Hungarian, scipy's linear_sum_assignment) on the distance from
a report to a true victim, gated at ``gate_m`` (1 m). The distance to a victim is
the smaller of the distances to its body centre and to the centroid of its
uncovered part: a detector that sees only a hand reports the hand, and either
place is where rescuers dig.

- recall: matched true victims / true victims (None when there are none);
- recall in view: the same over the victims that came into the camera's view (the
  truth's ``first_in_view_unix_s`` is set: at least ``MIN_VIEW_PX`` body pixels on
  some frame). A victim the route never showed is a miss of the mission's coverage,
  not of perception; both figures are given, recall is the target;
- false victims: reports within ``gate_m`` of no true victim;
- duplicates: unmatched reports within the gate of a true victim (the same person
  reported under another ID), counted per true victim;
- localisation error: median, 95th percentile and max over matched pairs;
- urgency accuracy: share of matched pairs whose class equals the truth;
- covariance consistency: for reports that carry ``cov_ne_m2``, the share of matched
  pairs whose error lies inside the reported 95 % ellipse (squared Mahalanobis
  distance to the matched point at most 5.99, chi-square with 2 dof); an honest
  covariance gives about 95 %;
- time to report: first report (``first_reported_unix_s``, else
  ``first_seen_unix_s``) minus the first frame where the victim was in view.

The report format (``load_report``): {"victims": [{"victim_id", "urgency",
"north_m", "east_m", "first_seen_unix_s", "first_reported_unix_s"?, "cov_ne_m2"?},
...]}; extra keys are ignored.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy.optimize import linear_sum_assignment

from fusion.kalman import mahalanobis2
from fusion.types import Urgency
from scenarios.errors import SimError
from scenarios.world import World

GATE_M = 1.0
# The largest position (m) or time (unix s) a file may hold: 1e10 s is the year 2286;
# beyond it differences of such values overflow to infinity in the figures.
MAX_VALUE = 1e10
CHI2_95_2DOF = 5.991


class ScoreInputError(SimError, ValueError):
    """A truth or report file cannot be used; the message names the file and key."""


@dataclass(frozen=True)
class TrueVictim:
    victim_id: int
    north_m: float
    east_m: float
    urgency: Urgency
    visible_north_m: float | None = None
    visible_east_m: float | None = None
    first_in_view_unix_s: float | None = None


@dataclass(frozen=True)
class GroundTruth:
    victims: tuple[TrueVictim, ...]
    # Whether each victim's first_in_view_unix_s was recorded (None then means the
    # victim never came into view) or is simply not known.
    view_known: bool = False


@dataclass(frozen=True)
class ReportedVictim:
    victim_id: int
    urgency: Urgency
    north_m: float
    east_m: float
    first_seen_unix_s: float
    first_reported_unix_s: float | None = None
    cov_ne_m2: tuple[tuple[float, float], tuple[float, float]] | None = None


@dataclass(frozen=True)
class Match:
    true_id: int
    reported_id: int
    error_m: float
    urgency_ok: bool
    time_to_report_s: float | None
    mahalanobis2: float | None = None  # error in the reported covariance; None without one


@dataclass(frozen=True)
class ScoreResult:
    true_victims: int
    reported: int
    matches: tuple[Match, ...]
    missed_ids: tuple[int, ...]
    false_victims: int
    duplicates: dict[int, int] = field(default_factory=dict)  # true id -> extra reports
    never_in_view_ids: tuple[int, ...] = ()  # true victims no frame showed
    view_known: bool = False  # the truth recorded which victims came into view

    @property
    def recall(self) -> float | None:
        return len(self.matches) / self.true_victims if self.true_victims else None

    @property
    def in_view(self) -> int:
        return self.true_victims - len(self.never_in_view_ids)

    @property
    def recall_in_view(self) -> float | None:
        """Recall over the victims that came into view; None where the truth does
        not say which did, or none did."""
        if not self.view_known or not self.in_view:
            return None
        found = sum(m.true_id not in self.never_in_view_ids for m in self.matches)
        return found / self.in_view

    def _errors(self) -> np.ndarray:
        return np.array([m.error_m for m in self.matches], float)

    @property
    def error_median_m(self) -> float | None:
        e = self._errors()
        return float(np.median(e)) if e.size else None

    @property
    def error_p95_m(self) -> float | None:
        e = self._errors()
        return float(np.percentile(e, 95)) if e.size else None

    @property
    def error_max_m(self) -> float | None:
        e = self._errors()
        return float(e.max()) if e.size else None

    @property
    def urgency_accuracy(self) -> float | None:
        if not self.matches:
            return None
        return sum(m.urgency_ok for m in self.matches) / len(self.matches)

    @property
    def inside_95_ellipse(self) -> float | None:
        return inside_95_ellipse(self.matches)

    @property
    def duplicate_count(self) -> int:
        return sum(self.duplicates.values())

    @property
    def time_to_report_s(self) -> tuple[float, ...]:
        return tuple(m.time_to_report_s for m in self.matches if m.time_to_report_s is not None)

    def as_dict(self) -> dict[str, Any]:
        ttr = self.time_to_report_s
        return {
            "true_victims": self.true_victims,
            "reported": self.reported,
            "matched": len(self.matches),
            "recall": self.recall,
            "recall_in_view": self.recall_in_view,
            "missed_ids": list(self.missed_ids),
            "never_in_view_ids": list(self.never_in_view_ids),
            "false_victims": self.false_victims,
            "duplicates": self.duplicate_count,
            "duplicates_per_true_victim": {str(k): v for k, v in self.duplicates.items()},
            "error_median_m": self.error_median_m,
            "error_p95_m": self.error_p95_m,
            "error_max_m": self.error_max_m,
            "urgency_accuracy": self.urgency_accuracy,
            "inside_95_ellipse": self.inside_95_ellipse,
            "time_to_report_median_s": float(np.median(ttr)) if ttr else None,
            "time_to_report_max_s": max(ttr) if ttr else None,
            "matches": [m.__dict__ for m in self.matches],
        }


def inside_95_ellipse(matches: Sequence[Match]) -> float | None:
    """Share of matches (with a covariance) whose error is inside the 95 % ellipse."""
    d2 = [m.mahalanobis2 for m in matches if m.mahalanobis2 is not None]
    return sum(x <= CHI2_95_2DOF for x in d2) / len(d2) if d2 else None


def _error_ne_m(t: TrueVictim, north_m: float, east_m: float) -> tuple[float, float]:
    """Report minus the nearer of the body centre and the visible part's centroid."""
    err = (north_m - t.north_m, east_m - t.east_m)
    if t.visible_north_m is not None and t.visible_east_m is not None:
        seen = (north_m - t.visible_north_m, east_m - t.visible_east_m)
        if math.hypot(*seen) < math.hypot(*err):
            err = seen
    return err


def _distance(t: TrueVictim, north_m: float, east_m: float) -> float:
    return math.hypot(*_error_ne_m(t, north_m, east_m))


def _mahalanobis2(t: TrueVictim, r: ReportedVictim) -> float | None:
    if r.cov_ne_m2 is None:
        return None
    err = np.array(_error_ne_m(t, r.north_m, r.east_m))
    cov = np.array(r.cov_ne_m2, float)
    if np.linalg.det(cov) <= 0.0:  # a singular covariance claims certainty: never consistent
        return math.inf
    d2, _det = mahalanobis2(err, cov)
    return float(d2)


def score(
    truth: GroundTruth, victims: Sequence[ReportedVictim], gate_m: float = GATE_M
) -> ScoreResult:
    """Match reports to the truth and measure (see the module docstring)."""
    tv, rv = truth.victims, list(victims)
    cost = np.array([[_distance(t, r.north_m, r.east_m) for r in rv] for t in tv], float)
    cost = cost.reshape(len(tv), len(rv))
    big = 1e6
    rows, cols = (
        linear_sum_assignment(np.where(cost <= gate_m, cost, big)) if cost.size else ([], [])
    )
    matches: list[Match] = []
    used_r: set[int] = set()
    for i, j in zip(rows, cols, strict=True):
        if cost[i, j] > gate_m:
            continue
        t, r = tv[i], rv[j]
        used_r.add(j)
        reported_at = (
            r.first_reported_unix_s if r.first_reported_unix_s is not None else r.first_seen_unix_s
        )
        ttr = None if t.first_in_view_unix_s is None else reported_at - t.first_in_view_unix_s
        matches.append(
            Match(
                t.victim_id,
                r.victim_id,
                float(cost[i, j]),
                r.urgency == t.urgency,
                ttr,
                _mahalanobis2(t, r),
            )
        )
    duplicates: dict[int, int] = {}
    false_victims = 0
    for j in range(len(rv)):
        if j in used_r:
            continue
        near = [i for i in range(len(tv)) if cost[i, j] <= gate_m]
        if near:
            nearest = min(near, key=lambda i: cost[i, j])
            duplicates[tv[nearest].victim_id] = duplicates.get(tv[nearest].victim_id, 0) + 1
        else:
            false_victims += 1
    matched_ids = {m.true_id for m in matches}
    return ScoreResult(
        true_victims=len(tv),
        reported=len(rv),
        matches=tuple(matches),
        missed_ids=tuple(t.victim_id for t in tv if t.victim_id not in matched_ids),
        false_victims=false_victims,
        duplicates=duplicates,
        never_in_view_ids=tuple(t.victim_id for t in tv if t.first_in_view_unix_s is None)
        if truth.view_known
        else (),
        view_known=truth.view_known,
    )


# -- files --------------------------------------------------------------------------


def _read_json(path: Path) -> Any:
    try:
        return json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError) as exc:
        raise ScoreInputError(f"{path}: cannot read: {exc}") from None
    except json.JSONDecodeError as exc:
        raise ScoreInputError(f"{path}: not valid JSON: {exc}") from None


def _field(item: dict[str, Any], key: str, where: str, kind: type, optional: bool = False) -> Any:
    if key not in item or item[key] is None:
        if optional:
            return None
        raise ScoreInputError(f"{where}.{key}: missing")
    value = item[key]
    ok = isinstance(value, kind) and not isinstance(value, bool)
    if kind is float:
        ok = isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)
    if not ok:
        raise ScoreInputError(f"{where}.{key} = {value!r}: expected {kind.__name__}")
    if kind is float and not -MAX_VALUE <= value <= MAX_VALUE:
        raise ScoreInputError(f"{where}.{key} = {value!r}: outside +-{MAX_VALUE:g}")
    return float(value) if kind is float else value


def _urgency(item: dict[str, Any], where: str) -> Urgency:
    text = _field(item, "urgency", where, str)
    try:
        return Urgency[text.upper()]
    except KeyError:
        raise ScoreInputError(
            f"{where}.urgency = {text!r}: expected LIGHT, MEDIUM or CRITICAL"
        ) from None


def _victim_list(data: Any, path: Path) -> list[dict[str, Any]]:
    items = data.get("victims") if isinstance(data, dict) else None
    if not isinstance(items, list) or not all(isinstance(v, dict) for v in items):
        raise ScoreInputError(f'{path}: expected {{"victims": [{{...}}, ...]}}')
    return items


def truth_from_dict(data: Any, path: Path = Path("ground_truth.json")) -> GroundTruth:
    out = []
    items = _victim_list(data, path)
    for k, v in enumerate(items):
        where = f"{path}: victims[{k}]"
        out.append(
            TrueVictim(
                victim_id=_field(v, "victim_id", where, int),
                north_m=_field(v, "north_m", where, float),
                east_m=_field(v, "east_m", where, float),
                urgency=_urgency(v, where),
                visible_north_m=_field(v, "visible_north_m", where, float, optional=True),
                visible_east_m=_field(v, "visible_east_m", where, float, optional=True),
                first_in_view_unix_s=_first_in_view(v, where),
            )
        )
    return GroundTruth(tuple(out), all("first_in_view_unix_s" in v for v in items))


def _first_in_view(item: dict[str, Any], where: str) -> float | None:
    """The first time either camera saw the victim: the colour camera's
    ``first_in_view_unix_s`` or, in a mission recorded with the thermal camera, its
    ``first_warm_in_view_unix_s``, whichever came first."""
    seen = [
        _field(item, key, where, float, optional=True)
        for key in ("first_in_view_unix_s", "first_warm_in_view_unix_s")
    ]
    times = [t for t in seen if t is not None]
    return min(times) if times else None


def report_from_dict(data: Any, path: Path = Path("report.json")) -> list[ReportedVictim]:
    out = []
    for k, v in enumerate(_victim_list(data, path)):
        where = f"{path}: victims[{k}]"
        out.append(
            ReportedVictim(
                victim_id=_field(v, "victim_id", where, int),
                urgency=_urgency(v, where),
                north_m=_field(v, "north_m", where, float),
                east_m=_field(v, "east_m", where, float),
                first_seen_unix_s=_field(v, "first_seen_unix_s", where, float),
                first_reported_unix_s=_field(
                    v, "first_reported_unix_s", where, float, optional=True
                ),
                cov_ne_m2=_covariance(v, where),
            )
        )
    return out


def _covariance(
    item: dict[str, Any], where: str
) -> tuple[tuple[float, float], tuple[float, float]] | None:
    cov = item.get("cov_ne_m2")
    if cov is None:
        return None
    try:
        (a, b), (c, d) = cov
        out = ((float(a), float(b)), (float(c), float(d)))
    except (TypeError, ValueError):
        out = None
    if out is None or not all(abs(x) <= MAX_VALUE for row in out for x in row):
        raise ScoreInputError(
            f"{where}.cov_ne_m2 = {cov!r}: expected a 2x2 list of numbers within +-{MAX_VALUE:g}"
        )
    (a, b), (c, d) = out
    if not (a > 0.0 and d > 0.0 and abs(b - c) <= 1e-6 * (a + d) and a * d - b * c > 0.0):
        raise ScoreInputError(
            f"{where}.cov_ne_m2 = {cov!r}: not a covariance (symmetric, positive definite)"
        )
    return out


def truth_of_world(
    world: World, first_in_view_unix_s: dict[int, float] | None = None
) -> GroundTruth:
    """The ground truth of a world held in memory (a live mission's; a recorded one
    has its ground_truth.json): each victim's centre, visible part and urgency, and
    when it first came into view where that is known."""
    seen = first_in_view_unix_s or {}
    return GroundTruth(
        tuple(
            TrueVictim(
                v.victim_id,
                v.north_m,
                v.east_m,
                v.urgency,
                None if math.isnan(v.visible_north_m) else v.visible_north_m,
                None if math.isnan(v.visible_east_m) else v.visible_east_m,
                seen.get(v.victim_id),
            )
            for v in world.victims
        ),
        first_in_view_unix_s is not None,
    )


def load_truth(path: Path) -> GroundTruth:
    return truth_from_dict(_read_json(path), Path(path))


def load_report(path: Path) -> list[ReportedVictim]:
    return report_from_dict(_read_json(path), Path(path))


def format_score(result: ScoreResult) -> str:
    """Human-readable lines for the CLI."""

    def f(x: float | None, unit: str = "", digits: int = 2) -> str:
        return "n/a" if x is None else f"{x:.{digits}f}{unit}"

    def pct(x: float | None) -> str:
        return "n/a" if x is None else f"{x:.0%}"

    d = result.as_dict()
    recall = result.recall
    lines = [
        f"true victims {result.true_victims}, reported {result.reported}, matched {len(result.matches)}",
        f"recall {'n/a' if recall is None else f'{recall:.0%}'}"
        + (f" (missed ids {list(result.missed_ids)})" if result.missed_ids else ""),
        *(
            [
                f"recall of the {result.in_view} victims that came into view "
                f"{pct(result.recall_in_view)} (never in view: ids {list(result.never_in_view_ids)})"
            ]
            if result.never_in_view_ids
            else []
        ),
        f"false victims {result.false_victims}",
        f"duplicate IDs {result.duplicate_count}"
        + (f" (per true victim {d['duplicates_per_true_victim']})" if result.duplicates else ""),
        f"localisation error median {f(result.error_median_m, ' m')}, p95 {f(result.error_p95_m, ' m')}, max {f(result.error_max_m, ' m')}",
        f"urgency accuracy {'n/a' if result.urgency_accuracy is None else f'{result.urgency_accuracy:.0%}'}",
        f"errors inside the reported 95% ellipse {'n/a' if result.inside_95_ellipse is None else f'{result.inside_95_ellipse:.0%}'}",
        f"time from first sight to first report: median {f(d['time_to_report_median_s'], ' s', 1)}, max {f(d['time_to_report_max_s'], ' s', 1)}",
    ]
    return "\n".join(lines)
