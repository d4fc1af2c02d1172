"""World-frame victim tracker: one filterpy Kalman filter per victim.

Each track estimates a static floor point x = [north, east] with

    F = I                      the victim does not move...
    Q = q dt I                 ...but a random walk of q m^2/s lets a wrong early fix move
    H = I                      observations are floor points
    R = observation covariance from geolocation

Time: a victim under rubble does not move, so being out of view teaches nothing
about where it is. The random walk runs only for ``max_unseen_growth_s`` after a
track's last detection: P grows by at most q times that, however long the absence
(15 minutes elsewhere, or a restart the next day), so an old track never becomes
broad enough to match everything. And no pair further apart than
``max_match_distance_m`` is ever associated, excluded or merged, whatever its
chi-square: that is the metric bound on how far a person's fix strays from itself.

Position: the filter's mean and covariance decide which detections are a victim's
(steps 2, 3 and 6 below); where the victim is reported to lie is the geometric
median of the newest ``position_fixes`` fixes its filter took (``fusion.track``):
a body's fixes stray more than their covariance says, and the filter, which
trusts it and weighs the newest fixes most, followed a few stray ones.

Per ``update`` (one processed camera frame, with or without detections):

1. predict every track to ``now_unix_s``;
2. gate each (track, observation) pair by the Mahalanobis distance
   d^2 = y^T S^-1 y, S = P + R, against ``gate_chi2`` (and the metric bound); assign with the Hungarian
   method over the gated pairs, cost d^2 + ln det S (the negative log-likelihood,
   so a broad track does not steal a detection from a sharp one);
3. matched tracks are updated and gain ``hit_log_odds`` (none from an observation
   that does not ``support`` one: a warm find whose height is not known yet, which
   may be warmth flat on the floor; a RESCUED or FALSE_ALARM
   track absorbs its observations: no support, no events; a lone part, a hand or a
   face, of a victim already seen as a body supports it without moving it: where a
   hand lies is not where its body lies. Nor does it count for the victim's
   visibility while the victim has been detected as a body at least as often as it
   has as a lone part; once the lone part is detected more often, little of the body
   shows, and the part's few percent count: an exposed arm taken once for a person
   at 2 m and then seen as a lone hand four times read MEDIUM instead of CRITICAL);
   an unmatched observation within ``new_track_exclusion_chi2`` of a live track is
   an outlier or a duplicate detection of it and is dropped, as is one within
   ``merge_chi2`` of another observation starting a track in the same frame (else
   one victim detected twice per frame, or a 1-in-100 noise outlier, would spawn a
   ghost that steals detections, confirms and later merges); the remaining
   unmatched observations start tentative tracks;
4. tentative tracks in view (``in_view(north, east)``: the pipeline's counts only
   points within ``miss_max_range_m``) but not detected gain ``miss_log_odds``;
   they are confirmed at ``confirm_log_odds`` and die below ``delete_log_odds`` or
   when unseen for ``tentative_timeout_s``;
5. confirmed victims are never deleted; unseen for ``not_seen_recently_s`` they
   become NOT_SEEN_RECENTLY, and CONFIRMED again when seen;
6. two confirmed victims whose difference is within ``merge_chi2`` merge: the older
   ID survives with the fused estimate, the younger becomes MERGED. A tentative
   track within ``merge_chi2`` of a confirmed victim, or within ``same_victim_m`` of
   one it was never detected in the same frame with, is not confirmed (it is most
   likely a stray fix of that victim: two people side by side are two detections in
   one frame, one body's scattered fixes are not); it waits until it separates, or
   dies. It is not fused into the victim either: clutter next to a victim must not
   pull it.

The gating, assignment and closeness tests of steps 2, 3 and 6 are
``fusion.association``; a track's state and its two outward forms (the ``Victim``
snapshot, the stored ``TrackRecord``) are ``fusion.track``.

Identity: every track has a ``track_id``; a victim ID (``victim_id``) is given only
on confirmation, from this instance's counter starting at ``first_id``, so the HQ
sees victims 1, 2, 3 rather than the numbers of clutter that never confirmed.
Neither number is ever reused. Tentative tracks show ``victim_id == 0``.

The caller must call ``update`` for every processed frame, also when it holds no
detections: that is where the negative evidence comes from.
"""

from __future__ import annotations

import logging
import math
from collections import deque
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from fusion import registry as codec
from fusion.association import associate, closest_pair, near, same_point
from fusion.camera import FloatArray
from fusion.kalman import kalman_update
from fusion.params import TrackerParams
from fusion.registry import EventKind, TrackEvent, Victim
from fusion.track import Track, new_filter, record_of, track_of, victim_of
from fusion.types import Cue, Observation, Sensor, TrackState, Urgency
from fusion.urgency import classify, weighted_median

log = logging.getLogger(__name__)

_ABSORBING = (TrackState.RESCUED, TrackState.FALSE_ALARM)
_CONFIRMED = (TrackState.CONFIRMED, TrackState.NOT_SEEN_RECENTLY)
_OPERATOR_STATES = (TrackState.RESCUED, TrackState.FALSE_ALARM, TrackState.CONFIRMED)


class VictimTracker:
    """Tracks victims on the floor of the local NED frame. Not thread-safe: one
    processing thread owns it."""

    def __init__(self, params: TrackerParams, first_id: int = 1) -> None:
        if first_id < 1:
            raise ValueError(f"first_id must be >= 1, got {first_id}")
        self._params = params
        self._next_victim_id = first_id
        self._next_track_id = 1
        self._tracks: dict[int, Track] = {}  # by track_id, in creation order
        self._by_victim: dict[int, Track] = {}

    # -- queries -----------------------------------------------------------------

    def victims(self, include_tentative: bool = False) -> list[Victim]:
        """Snapshots of all victims (every state but tentative, unless asked)."""
        return [
            victim_of(t)
            for t in self._tracks.values()
            if include_tentative or t.state != TrackState.TENTATIVE
        ]

    def victim(self, victim_id: int) -> Victim:
        """The snapshot of one victim; KeyError when unknown."""
        return victim_of(self._lookup(victim_id))

    def resolve(self, victim_id: int) -> int:
        """The surviving victim ID for an ID that may have been merged away."""
        track = self._lookup(victim_id)
        while track.merged_into is not None:
            track = self._by_victim[track.merged_into]
        return track.victim_id

    def _lookup(self, victim_id: int) -> Track:
        try:
            return self._by_victim[victim_id]
        except KeyError:
            known = ", ".join(str(v) for v in self._by_victim) or "none"
            raise KeyError(f"no victim with id {victim_id} (known ids: {known})") from None

    # -- the update cycle --------------------------------------------------------

    def update(
        self,
        observations: Sequence[Observation],
        now_unix_s: float,
        in_view: Callable[[float, float], bool],
        sensor: Sensor = Sensor.COLOUR,
        looked_at: Callable[[float, float], bool] | None = None,
    ) -> list[TrackEvent]:
        """Fuse one frame's observations (possibly none) taken at ``now_unix_s`` by
        ``sensor``'s camera, whose view ``in_view`` is. ``looked_at`` (the colour
        camera's): where it had a clear look, lit and in range; a track only the
        thermal camera has found, looked at there and not detected, shows the eye
        nothing of its body (see TrackerParams.covered_after_looks)."""
        if not math.isfinite(now_unix_s):
            raise ValueError(f"now_unix_s must be finite, got {now_unix_s!r}")
        events: list[TrackEvent] = []
        live = [t for t in self._tracks.values() if t.state != TrackState.MERGED]
        for t in live:
            t.matched = False
        p = self._predict(live, now_unix_s)
        pairs, d2 = associate(live, p, observations, self._params)
        self._correct(live, p, observations, pairs)
        for i, j in pairs:
            self._hit(live[i], observations[j], events)
        self._note_seen_together([live[i] for i, _ in pairs])
        self._spawn(live, observations, pairs, d2, now_unix_s)
        self._negative_evidence(live, in_view, sensor)
        if looked_at is not None and sensor == Sensor.COLOUR:
            self._colour_looks(live, looked_at, events)
        self._life_cycle(live, now_unix_s, events)
        self._merge(events)
        return events

    def _spawn(
        self,
        live: list[Track],
        observations: Sequence[Observation],
        pairs: list[tuple[int, int]],
        d2: np.ndarray,
        now_unix_s: float,
    ) -> None:
        """Start tentative tracks from unmatched observations, except those within
        ``new_track_exclusion_chi2`` of a live track (an outlier or a duplicate
        detection of it; absorbed, if that track is RESCUED/FALSE_ALARM) and those
        within ``merge_chi2`` of another observation starting a track in this frame."""
        paired_obs = {j for _, j in pairs}
        near_pairs = near(live, observations, self._params.max_match_distance_m)
        excluded = (
            np.any((d2 <= self._params.new_track_exclusion_chi2) & near_pairs, axis=0)
            if len(live)
            else np.zeros(len(observations), dtype=bool)
        )
        started: list[Observation] = []
        for j, obs in enumerate(observations):
            if j in paired_obs:
                continue
            if excluded[j]:
                log.debug("observation at (%.2f, %.2f) near a track", obs.north_m, obs.east_m)
                continue
            if any(same_point(obs, other, self._params) for other in started):
                log.debug("duplicate new detection at (%.2f, %.2f)", obs.north_m, obs.east_m)
                continue
            started.append(obs)
            self._start(obs, now_unix_s)

    def _predict(self, live: list[Track], now_unix_s: float) -> FloatArray:
        """Predict every track to ``now_unix_s``; returns the stacked P (T, 2, 2).

        With F = I the filter's predict (x = F x, P = F P F^T + Q) reduces to
        P = P + q dt I, done here for all tracks in one numpy operation (one
        ``kf.predict`` call per track would cost 50 x 7 us at 50 tracks).
        """
        if not live:
            return np.zeros((0, 2, 2))
        t_filter = np.array([t.t_filter_unix_s for t in live])
        # The random walk runs only up to max_unseen_growth_s after the last detection;
        # dt <= 0: the wall clock stepped back, or the same frame: nothing to predict.
        growth_end = np.array([t.last_seen_unix_s for t in live]) + self._params.max_unseen_growth_s
        dt = np.maximum(0.0, np.minimum(now_unix_s, growth_end) - t_filter)
        p = np.array([t.kf.P for t in live])
        p = p + (self._params.process_noise_m2_s * dt)[:, None, None] * np.eye(2)
        for t, p_t in zip(live, p, strict=True):
            t.kf.P = p_t
            t.t_filter_unix_s = max(t.t_filter_unix_s, now_unix_s)
        return p

    @staticmethod
    def _correct(
        live: list[Track],
        p: FloatArray,
        observations: Sequence[Observation],
        pairs: list[tuple[int, int]],
    ) -> None:
        """The Kalman update of every matched track, in one batch (see kalman_update);
        results go back into each track's filter."""
        # A lone part of a victim seen whole (its hand, 0.5-0.8 m from where the body
        # lies) is support for it, not a fix of its position.
        pairs = [(i, j) for i, j in pairs if not _part_of_body(live[i], observations[j])]
        if not pairs:
            return
        ti = [i for i, _ in pairs]
        oj = [j for _, j in pairs]
        x = np.array([live[i].x for i in ti])
        z = np.array([(observations[j].north_m, observations[j].east_m) for j in oj])
        r = np.array([observations[j].cov_ne_m2 for j in oj])
        x_new, p_new = kalman_update(x, p[ti], z, r)
        for k, (i, j) in enumerate(pairs):
            live[i].kf.x = x_new[k].reshape(2, 1)
            live[i].kf.P = p_new[k]
            live[i].add_fix(observations[j].t_unix_s, float(z[k, 0]), float(z[k, 1]))

    def _hit(self, t: Track, obs: Observation, events: list[TrackEvent]) -> None:
        """Bookkeeping of a matched track (its filter is already updated)."""
        t.matched = True
        t.observations += 1
        t.first_seen_unix_s = min(t.first_seen_unix_s, obs.t_unix_s)
        t.last_seen_unix_s = max(t.last_seen_unix_s, obs.t_unix_s)
        if t.state in _ABSORBING:
            return  # the operator has decided: no support, urgency or events
        p = self._params
        if obs.supports:
            t.log_odds = min(p.max_log_odds, t.log_odds + p.hit_log_odds)
        if t.state == TrackState.NOT_SEEN_RECENTLY:
            t.state = TrackState.CONFIRMED
            events.append(TrackEvent(EventKind.SEEN_AGAIN, victim_of(t)))
        if obs.part_only:
            t.part_hits += 1
        else:
            t.body_hits += 1
        if obs.sensor == Sensor.THERMAL:
            t.warm_hits += 1
        t.cues |= obs.cue
        if obs.part_only and t.part_hits <= t.body_hits:
            return  # a lone hand says little of how much shows of a body seen as often
        t.history.append((obs.t_unix_s, obs.visibility_pct, obs.quality))
        if self._reclassify(t) and t.state == TrackState.CONFIRMED:
            events.append(TrackEvent(EventKind.URGENCY_CHANGED, victim_of(t)))

    @staticmethod
    def _note_seen_together(matched: list[Track]) -> None:
        """Tentative tracks detected in the same frame as a confirmed one are another
        body, however near (``same_victim_m`` does not hold them back)."""
        confirmed = {t.track_id for t in matched if t.state in _CONFIRMED}
        for t in matched:
            if t.state == TrackState.TENTATIVE:
                t.seen_with |= confirmed

    def _colour_looks(
        self, live: list[Track], looked_at: Callable[[float, float], bool], events: list[TrackEvent]
    ) -> None:
        """Count the colour camera's clear looks at the tracks only the thermal camera
        has found; enough of them cap the visibility (TrackerParams.covered_after_looks)."""
        for t in live:
            if t.matched or t.cues != Cue.WARM or t.state in _ABSORBING:
                continue
            x = t.x
            if not looked_at(float(x[0]), float(x[1])):
                continue
            t.colour_looks += 1
            if self._reclassify(t) and t.state == TrackState.CONFIRMED:
                events.append(TrackEvent(EventKind.URGENCY_CHANGED, victim_of(t)))

    def _reclassify(self, t: Track) -> bool:
        """Refresh the visibility estimate and the class; True if the class changed."""
        p = self._params
        t.visibility_pct = weighted_median([h[1] for h in t.history], [h[2] for h in t.history])
        if t.cues == Cue.WARM and t.colour_looks >= p.covered_after_looks:
            t.visibility_pct = min(t.visibility_pct, p.covered_visibility_pct)
        urgency = classify(t.urgency, t.visibility_pct, self._params.urgency_hysteresis_pct)
        changed = urgency != t.urgency
        t.urgency = urgency
        return changed

    def _start(self, obs: Observation, now_unix_s: float) -> None:
        t = Track(
            track_id=self._next_track_id,
            kf=new_filter(np.array([obs.north_m, obs.east_m]), np.array(obs.cov_ne_m2)),
            state=TrackState.TENTATIVE,
            log_odds=self._params.hit_log_odds if obs.supports else 0.0,
            observations=1,
            first_seen_unix_s=obs.t_unix_s,
            last_seen_unix_s=obs.t_unix_s,
            t_filter_unix_s=now_unix_s,
            history=deque(
                [(obs.t_unix_s, obs.visibility_pct, obs.quality)],
                maxlen=self._params.urgency_window,
            ),
            urgency=Urgency.from_visibility(obs.visibility_pct),
            visibility_pct=obs.visibility_pct,
            matched=True,
            body_hits=0 if obs.part_only else 1,
            part_hits=1 if obs.part_only else 0,
            warm_hits=1 if obs.sensor == Sensor.THERMAL else 0,
            cues=obs.cue,
            fixes=deque(
                [(obs.t_unix_s, obs.north_m, obs.east_m)], maxlen=self._params.position_fixes
            ),
        )
        self._next_track_id += 1
        self._tracks[t.track_id] = t

    def _negative_evidence(
        self, live: list[Track], in_view: Callable[[float, float], bool], sensor: Sensor
    ) -> None:
        """Tentative tracks in this camera's view but not detected lose support. The
        colour camera's misses do not count against a track only the thermal camera
        has seen: it cannot see warmth under thin cover or in the dark. The thermal
        camera's count against every track: a person it has in view is warm."""
        miss = self._params.miss_log_odds
        for t in live:
            if t.state == TrackState.TENTATIVE and not t.matched:
                if sensor == Sensor.COLOUR and t.cues == Cue.WARM:
                    continue
                x = t.x
                if in_view(float(x[0]), float(x[1])):
                    t.log_odds += miss

    def _life_cycle(self, live: list[Track], now_unix_s: float, events: list[TrackEvent]) -> None:
        p = self._params
        confirmed = [t for t in live if t.state in _CONFIRMED]
        for t in live:
            if t.state == TrackState.TENTATIVE:
                if t.log_odds >= p.confirm_log_odds:
                    if not self._near_a_victim(t, confirmed):
                        self._confirm(t, events)
                        confirmed.append(t)
                    # else: a stray fix of a known victim; it waits, tentative, until
                    # it separates from the victim or dies
                elif (
                    t.log_odds < p.delete_log_odds
                    or now_unix_s - t.last_seen_unix_s > p.tentative_timeout_s
                ):
                    del self._tracks[t.track_id]
            elif (
                t.state == TrackState.CONFIRMED
                and now_unix_s - t.last_seen_unix_s > p.not_seen_recently_s
            ):
                t.state = TrackState.NOT_SEEN_RECENTLY
                events.append(TrackEvent(EventKind.NOT_SEEN_RECENTLY, victim_of(t)))

    def _near_a_victim(self, t: Track, confirmed: list[Track]) -> bool:
        """Whether tentative ``t`` is likely a stray fix of a confirmed victim: within
        ``merge_chi2``, or within ``same_victim_m`` of one it was never seen with."""
        p = self._params
        if closest_pair([t], confirmed, p.merge_chi2, p.max_match_distance_m) is not None:
            return True
        return any(
            math.hypot(float(t.x[0] - c.x[0]), float(t.x[1] - c.x[1])) < p.same_victim_m
            for c in confirmed
            if c.track_id not in t.seen_with
        )

    def _confirm(self, t: Track, events: list[TrackEvent]) -> None:
        t.state = TrackState.CONFIRMED
        t.victim_id = self._next_victim_id
        self._next_victim_id += 1
        self._by_victim[t.victim_id] = t
        log.info("victim %d confirmed at (%.2f, %.2f)", t.victim_id, *t.x)
        events.append(TrackEvent(EventKind.CONFIRMED, victim_of(t)))

    # -- merging -------------------------------------------------------------------

    def _merge(self, events: list[TrackEvent]) -> None:
        while True:
            confirmed = [t for t in self._tracks.values() if t.state in _CONFIRMED]
            p = self._params
            pair = closest_pair(confirmed, confirmed, p.merge_chi2, p.max_match_distance_m)
            if pair is None:
                return
            a, b = pair
            older, younger = (a, b) if a.victim_id < b.victim_id else (b, a)
            self._fuse(older, younger, events)

    def _fuse(self, older: Track, younger: Track, events: list[TrackEvent]) -> None:
        """Fold the confirmed ``younger`` into ``older``; younger becomes MERGED."""
        # Independent estimates of one point, fused in information form:
        # P = (P1^-1 + P2^-1)^-1, x = P (P1^-1 x1 + P2^-1 x2)
        i1, i2 = np.linalg.inv(older.kf.P), np.linalg.inv(younger.kf.P)
        p = np.linalg.inv(i1 + i2)
        x = p @ (i1 @ older.x + i2 @ younger.x)
        older.kf.x = x.reshape(2, 1)
        older.kf.P = 0.5 * (p + p.T)
        older.observations += younger.observations
        older.first_seen_unix_s = min(older.first_seen_unix_s, younger.first_seen_unix_s)
        older.last_seen_unix_s = max(older.last_seen_unix_s, younger.last_seen_unix_s)
        if younger.state == TrackState.CONFIRMED:
            older.state = TrackState.CONFIRMED
        merged = sorted([*older.history, *younger.history])
        older.history = deque(merged, maxlen=self._params.urgency_window)
        older.log_odds = max(older.log_odds, younger.log_odds)
        older.body_hits += younger.body_hits
        older.part_hits += younger.part_hits
        older.warm_hits += younger.warm_hits
        older.colour_looks += younger.colour_looks
        older.cues |= younger.cues
        older.take_fixes(younger)
        for t in self._tracks.values():  # seen beside the younger ID: beside the victim
            if younger.track_id in t.seen_with:
                t.seen_with.add(older.track_id)
        younger.state = TrackState.MERGED
        younger.merged_into = older.victim_id
        log.info("victim %d merged into %d", younger.victim_id, older.victim_id)
        events.append(TrackEvent(EventKind.MERGED, victim_of(younger)))
        if self._reclassify(older) and older.state == TrackState.CONFIRMED:
            events.append(TrackEvent(EventKind.URGENCY_CHANGED, victim_of(older)))

    # -- operator ------------------------------------------------------------------

    def mark(self, victim_id: int, state: TrackState, now_unix_s: float) -> TrackEvent:
        """Apply an operator's decision: RESCUED, FALSE_ALARM, or CONFIRMED to reopen.

        A merged ID is applied to the victim it was merged into. Unknown ID: KeyError.
        """
        if state not in _OPERATOR_STATES:
            names = ", ".join(s.name for s in _OPERATOR_STATES)
            raise ValueError(f"operator can mark a victim {names}, not {state.name}")
        track = self._by_victim[self.resolve(victim_id)]
        log.info("operator marked victim %d %s at %.3f", track.victim_id, state.name, now_unix_s)
        track.state = state
        return TrackEvent(EventKind.OPERATOR, victim_of(track))

    # -- persistence ---------------------------------------------------------------

    def snapshot(self) -> dict[str, Any]:
        """The whole registry as JSON-serialisable data (format in fusion.registry)."""
        return codec.encode(
            self._next_victim_id,
            self._next_track_id,
            [record_of(t) for t in self._tracks.values()],
        )

    @classmethod
    def restore(cls, params: TrackerParams, snapshot: Any) -> VictimTracker:
        """A tracker that continues exactly where ``snapshot()`` left off.

        Raises FusionError naming the first malformed field.
        """
        next_victim_id, next_track_id, records = codec.decode(snapshot)
        tracker = cls(params, first_id=next_victim_id)
        tracker._next_track_id = next_track_id
        for rec in records:
            t = track_of(rec, params.urgency_window, params.position_fixes)
            tracker._tracks[t.track_id] = t
            if t.victim_id:
                tracker._by_victim[t.victim_id] = t
        codec.check_links(tracker._by_victim.keys(), [r.merged_into for r in records])
        return tracker


def _part_of_body(t: Track, obs: Observation) -> bool:
    """A lone part (a hand, a face) matched to a victim already seen as a body."""
    return obs.part_only and t.body_hits > 0
