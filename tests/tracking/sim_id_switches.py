"""Why a shuffled-arrival run has ID switches the in-order run has not (``benchmarks/tracking_sim.py``).

Instrumentation for the benchmark, not part of the tracker: :class:`IdObserver` records, at every scored
instant, which track hypothesis each published row is (its birth detection: stamp, source name, row,
the same in both runs), and the published-id bookkeeping's hand-over events (a replay retracting a
published track; an id given to a newly published track). :func:`explain` pairs each ID switch of the
shuffled run with one of the ordered run for the same object within :data:`PAIR_WINDOW_US`; the unpaired
ones are the *extra* switches, and each gets one cause from :data:`CAUSES`.

It reads the tracker's private bookkeeping (``_t``, ``_keys``, ``_source_codes``, the ``PublishedIds``
internals): this is a diagnostic beside the tests, which may look inside; the tracker does not depend on it.
"""

from __future__ import annotations

from collections import Counter, defaultdict
from dataclasses import dataclass, field

import numpy as np

from lastmile.tracking.autotrack import AutoTrack
from tests.tracking.sim_scene import FeedResult, Recording, matched

PAIR_WINDOW_US = 1_000_000
Key = tuple[int, str, int]  # birth stamp (us), birth source name, row of the birth detection

CAUSES = {
    "expired": "live-only track retracted by a replay; successor published after its id's reservation",
    "gate": "live-only track retracted by a replay; successor outside the gate of its predicted position",
    "no_replay": "live-only track involved, ended without a replay retracting it: nothing to hand over",
    "other_id": "live-only track retracted; successor took another retracted track's id",
    "in_use": "live-only track retracted; its id still in use or already handed to another track",
    "returned": "retracted track's id went to a successor, then the track itself came back (new id)",
    "timing": "both tracks published in order too, but not at these instants (promotion/expiry timing)",
    "matching": "same tracks as in order at both instants; the object matched differently (live position)",
}


@dataclass(slots=True)
class _Retired:
    stamp_us: int
    public_id: int
    expires_us: int
    xy_m: np.ndarray
    vxy_mps: np.ndarray


@dataclass(slots=True)
class _Assigned:
    now_us: int
    public_id: int
    xy_m: np.ndarray
    gate_m: float
    inherited: bool


@dataclass(slots=True)
class IdObserver:
    """Records the published hypotheses and the hand-over events of one fed tracker."""

    keys: dict[int, list[Key]] = field(default_factory=dict)  # scored instant -> published rows' keys
    retired: list[_Retired] = field(default_factory=list)
    assigned: dict[Key, _Assigned] = field(default_factory=dict)  # a key's first id
    _tracker: AutoTrack | None = None

    def _name(self, key: tuple[int, int, int]) -> Key:
        assert self._tracker is not None
        names = {code: name for name, code in self._tracker._source_codes.items()}
        return (key[0], names[key[1]], key[2])

    def attach(self, tracker: AutoTrack) -> None:
        self._tracker = tracker
        ids = tracker.published_ids
        retire, assign = ids.retire, ids.assign

        def logged_retire(before, xy_m, vxy_mps, stamp_us, expires_us, still_published) -> None:
            for i, key in enumerate(before):
                if key not in still_published and key in ids._ids:
                    self.retired.append(
                        _Retired(
                            stamp_us, ids._ids[key], int(expires_us[i]), xy_m[i].copy(), vxy_mps[i].copy()
                        )
                    )
            retire(before, xy_m, vxy_mps, stamp_us, expires_us, still_published)

        def logged_assign(keys, xy_m, gate_m, now_us) -> None:
            new = [i for i, k in enumerate(keys) if k not in ids._ids]
            next_before = ids._next
            assign(keys, xy_m, gate_m, now_us)
            for i in new:
                name = self._name(keys[i])
                pid = ids._ids[keys[i]]
                if name not in self.assigned:
                    self.assigned[name] = _Assigned(
                        now_us, pid, xy_m[i].copy(), float(gate_m[i]), pid < next_before
                    )

        ids.retire = logged_retire
        ids.assign = logged_assign

    def published(self, now_us: int, tracker: AutoTrack) -> None:
        rows = np.nonzero(tracker._t.full)[0]
        self.keys[now_us] = [self._name(k) for k in tracker._keys(rows)]


@dataclass(frozen=True, slots=True)
class Switch:
    stamp_us: int
    object_id: int
    before_id: int
    before_key: Key
    before_us: int  # the instant the object was last matched before the switch
    after_id: int
    after_key: Key


def switches(rec: Recording, result: FeedResult, obs: IdObserver) -> list[Switch]:
    """Every ID switch of a run, with the hypotheses on both sides (as ``sim_scene.score`` counts them)."""
    last: dict[int, tuple[int, Key, int]] = {}
    out = []
    for stamp, gi, ti in matched(rec, result):
        tids = result.published[stamp][0]
        gids = rec.truth[stamp][0]
        for g, t in zip(gi, ti, strict=True):
            gid, tid, key = int(gids[g]), int(tids[t]), obs.keys[stamp][t]
            if gid in last and last[gid][0] != tid:
                out.append(Switch(stamp, gid, last[gid][0], last[gid][1], last[gid][2], tid, key))
            last[gid] = (tid, key, stamp)
    return out


def _cause(sw: Switch, obs: IdObserver, ordered_at: dict[int, set[Key]], ordered_ever: set[Key]) -> str:
    if sw.before_key == sw.after_key:
        return "returned"
    if sw.before_key in ordered_at[sw.before_us] and sw.after_key in ordered_at[sw.stamp_us]:
        return "matching"
    if sw.before_key in ordered_ever and sw.after_key in ordered_ever:
        return "timing"
    new = obs.assigned[sw.after_key]
    if new.inherited:
        return "other_id"
    gone = [r for r in obs.retired if r.public_id == sw.before_id and r.stamp_us <= new.now_us]
    if not gone:
        return "no_replay"
    r = gone[-1]
    if r.expires_us < new.now_us:
        return "expired"
    dt_s = (new.now_us - r.stamp_us) * 1e-6
    if np.linalg.norm(new.xy_m - (r.xy_m + r.vxy_mps * dt_s)) > new.gate_m:
        return "gate"
    return "in_use"


def explain(
    rec: Recording,
    ordered: FeedResult,
    ordered_obs: IdObserver,
    shuffled: FeedResult,
    shuffled_obs: IdObserver,
) -> tuple[Counter[str], int]:
    """Causes of the shuffled run's extra switches, and how many of the ordered run's it does not have."""
    unpaired: dict[int, list[int]] = defaultdict(list)
    for sw in switches(rec, ordered, ordered_obs):
        unpaired[sw.object_id].append(sw.stamp_us)
    ordered_at = {t: set(k) for t, k in ordered_obs.keys.items()}
    ordered_ever = set().union(*ordered_at.values())
    causes: Counter[str] = Counter()
    for sw in switches(rec, shuffled, shuffled_obs):
        near = [t for t in unpaired[sw.object_id] if abs(t - sw.stamp_us) <= PAIR_WINDOW_US]
        if near:
            unpaired[sw.object_id].remove(min(near, key=lambda t: abs(t - sw.stamp_us)))
            continue
        causes[_cause(sw, shuffled_obs, ordered_at, ordered_ever)] += 1
    return causes, sum(len(v) for v in unpaired.values())
