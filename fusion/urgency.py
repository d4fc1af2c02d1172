"""Urgency class of a victim from its recent visibility observations.

The visibility estimate is the quality-weighted median of the last few
observations: one mis-segmented frame (a mask that leaked over debris, or a hand
half out of the image) cannot move it. The class follows the estimate with
hysteresis: it changes only when the estimate leaves the current class's band
widened by ``hysteresis_pct`` on each side, so a victim measured at 9-11 % keeps
one class instead of flapping between CRITICAL and MEDIUM.
"""

from __future__ import annotations

from collections.abc import Sequence

from fusion.types import Urgency

# Visibility band of each class in percent (Urgency.from_visibility's thresholds).
_BANDS: dict[Urgency, tuple[float, float]] = {
    Urgency.CRITICAL: (0.0, 10.0),
    Urgency.MEDIUM: (10.0, 50.0),
    Urgency.LIGHT: (50.0, 100.0),
}


def weighted_median(values: Sequence[float], weights: Sequence[float]) -> float:
    """The value where the cumulative weight first reaches half the total.

    Ties at exactly half average the two neighbours, so equal weights give the
    ordinary median. All-zero weights count every value equally.
    """
    if not values:
        raise ValueError("weighted_median of no values")
    if len(values) != len(weights):
        raise ValueError(f"{len(values)} values but {len(weights)} weights")
    if min(weights) < 0.0:
        raise ValueError("weights must be >= 0")
    total = sum(weights)
    if total <= 0.0:
        weights, total = [1.0] * len(values), float(len(values))
    pairs = sorted(zip(values, weights, strict=True))
    half = 0.5 * total
    cumulative = 0.0
    for i, (value, weight) in enumerate(pairs):
        cumulative += weight
        if abs(cumulative - half) <= 1e-12 * total and i + 1 < len(pairs):
            return 0.5 * (value + pairs[i + 1][0])
        if cumulative > half:
            return value
    return pairs[-1][0]


def classify(current: Urgency | None, visibility_pct: float, hysteresis_pct: float) -> Urgency:
    """The class for ``visibility_pct``, keeping ``current`` within its band widened
    by ``hysteresis_pct``. Without a current class: the plain class."""
    if current is not None:
        lo, hi = _BANDS[current]
        if lo - hysteresis_pct <= visibility_pct <= hi + hysteresis_pct:
            return current
    return Urgency.from_visibility(min(100.0, max(0.0, visibility_pct)))
