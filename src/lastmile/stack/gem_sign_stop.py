"""GEM's LiDAR sign detector (its section VI) as a stop of the stack: ``[stack.gem_sign_stop]``.

Each LiDAR rig frame the raw chain has processed (its weather noise left out) goes through GEM's five
stages (:func:`lastmile.perception.signs.detect_sign`: field of view, intensity >= 85, radius and
statistical outlier removal, a RANSAC plane facing the vehicle). GEM returns the nearest sign only, so
the points are first narrowed to the shuttle's corridor: ahead of the front bumper along the route, up
to the detector's range, and within ``corridor_right_m`` right / ``corridor_left_m`` left of the route
(the lane's centre line), which is where the signs for the shuttle's own lane stand (the backs of the
opposite approach's plates, further left, are not; a plate across a junction faces sideways and fails
GEM's facing test). A detection is placed in the map with the stack's own pose estimate at the frame's
stamp.

Which plates count (``check``): ``gem`` stops at every facing plate, as GEM does (its course had
only stop signs; LiDAR cannot read the plate). ``map_checked`` (the default) counts a detection only
when a mapped stop sign (``STOP_SIGN_TYPES``: de206, us:R1-1, stop) across the shuttle's heading lies within
``match_radius_m`` of it: the map says what the plate is, the detector confirms it is there and gives
the distance. The campus has bus-stop (de224) and crosswalk (de350) plates beside its lane, which
``gem`` would stop at.

The stop: the front bumper ``setback_m`` before the sign's along-route position; where the map has a
stop line from ``line_before_sign_m`` before to ``line_after_sign_m`` past the sign, ``setback_m``
before that line instead (UVC 11-403(b): stop at a marked line). From the detection on, GEM's constant
deceleration ``a = v_i^2 / (2 d)`` (``v_i`` the speed at the first detection, ``d`` the gap to the stop
point then) caps the speed at ``sqrt(2 a gap)``, and decision's stop point is set there, so the
longitudinal law ends in a stop. After a full stop (decision's stop-sign parameters: below 0.1 m/s for
1 s within 3 m of the point) the sign is served: it is remembered in the map frame and its later
detections give no stop, until it is behind the rear axle (out of GEM's field of view); on a loop the
next lap stops again. Decision's own rules keep running (an all-way stop's arrival order still holds
the shuttle at the line).

A plate first seen so close that GEM's deceleration would exceed ``max_decel_mps2`` (decision's
comfort deceleration, 1.8 m/s^2) is not stopped for, and is counted (our addition; GEM has no limit).

Limits: one sign at a time (GEM's stages keep one plane); the corridor follows the route, not a pass or
a pull-over's path; the detection is placed with the pose estimate, whose error it inherits; the
option does nothing in the pull-over, onboarding and merging states; a real stop sign first seen too
late (occluded until close) is passed. The default stack does not run it.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from enum import StrEnum

import numpy as np

from lastmile.core.errors import ConfigError
from lastmile.core.geometry import SE2
from lastmile.core.polyline import Polyline
from lastmile.core.vehicle_messages import LocalizationEstimate
from lastmile.decision.traffic_light_rule import TrafficLightRuleConfig
from lastmile.hdmap.layers import SLayerDatabase
from lastmile.hdmap.loader import STOP_SIGN_TYPES
from lastmile.perception.merge import MERGED_COLUMNS
from lastmile.perception.pipeline import LidarPipelineResult
from lastmile.perception.signs import SignDetectorConfig, detect_sign, stop_deceleration_mps2

_INTENSITY = MERGED_COLUMNS.index("intensity")
"""Column of the intensity in a merged cloud."""
_NEW_APPROACH_FRAMES = 50
"""A plate not detected for this many rig frames (5 s at 10 Hz) is approached anew."""
_SAMPLE_M = 0.25
"""Spacing of the route samples the corridor test measures against."""


class SignCheck(StrEnum):
    """Which detected plates are stop signs."""

    GEM = "gem"
    """Every facing plate in the corridor (GEM's own course had only stop signs)."""
    MAP_CHECKED = "map_checked"
    """Only a plate with a mapped stop sign facing the shuttle within ``match_radius_m``."""


@dataclass(frozen=True, slots=True, kw_only=True)
class GemSignStopSettings:
    """``[stack.gem_sign_stop]``: the table's presence turns the stop on.

    Attributes:
        check: which plates count (:class:`SignCheck`; default ``map_checked``).
        detector: GEM's five stages (``[stack.gem_sign_stop.detector]``, GEM's values).
        corridor_right_m: how far right of the route a sign may stand: half a 3.65 m (12 ft) lane
            plus MUTCD 2A.19's 12 ft (3.66 m) lateral offset from the travelled way's edge.
        corridor_left_m: how far left: the lane's own half and its left edge (a sign further left is
            the opposite approach's, or a median's).
        setback_m: the front bumper stops this far before the sign (or its line): decision's
            ``stop_before_line_m`` (0.5 m).
        line_before_sign_m, line_after_sign_m: a mapped stop line within this window of the sign is
            its line (after: MUTCD 3B.16's farthest placement of a stop line, 30 ft = 9.1 m).
        match_radius_m: a detection is the same sign as a remembered one, and (``map_checked``) a
            mapped stop sign's, within this (the plate's 0.6 m plus a 1.4 m allowance for the pose
            estimate; a junction's signs stand at least ~6 m apart).
        min_decel_mps2: GEM's deceleration is at least this (a sign detected at rest or crawling
            would otherwise cap the speed near zero): GEM's own case, 3 m/s detected at 10 m, gives
            9 / 20 = 0.45 m/s^2 (the paper prints 0.15).
        max_decel_mps2: a plate first seen so close that GEM's deceleration would exceed this is not
            stopped for (counted as too late): decision's comfort deceleration for an amber light
            (1.8 m/s^2, inside Snow Lion's -1.83 envelope). Our addition: GEM has no such limit, and
            in snow its stages find plates in snow returns 4-10 m ahead (measured), which it would
            brake for at up to 280 m/s^2 of demand; a real plate is seen 28-40 m ahead.
        seed: RANSAC's draws (one seed, one run).
    """

    check: SignCheck = SignCheck.MAP_CHECKED
    detector: SignDetectorConfig = field(default_factory=SignDetectorConfig)
    corridor_right_m: float = 5.5
    corridor_left_m: float = 2.0
    setback_m: float = TrafficLightRuleConfig().stop_before_line_m
    line_before_sign_m: float = 2.0
    line_after_sign_m: float = 9.1
    match_radius_m: float = 2.0
    min_decel_mps2: float = 0.45
    max_decel_mps2: float = TrafficLightRuleConfig().comfort_decel_mps2
    seed: int = 0

    def __post_init__(self) -> None:
        if not isinstance(self.check, SignCheck):
            raise ConfigError(
                f"stack.gem_sign_stop.check: expected one of {[c.value for c in SignCheck]}, "
                f"got {self.check!r}"
            )
        for name in (
            "corridor_right_m",
            "corridor_left_m",
            "match_radius_m",
            "min_decel_mps2",
            "max_decel_mps2",
        ):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0.0):
                raise ConfigError(f"stack.gem_sign_stop.{name}: expected a positive number, got {v}")
        for name in ("setback_m", "line_before_sign_m", "line_after_sign_m"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0.0):
                raise ConfigError(f"stack.gem_sign_stop.{name}: expected a number >= 0, got {v}")
        if self.max_decel_mps2 < self.min_decel_mps2:
            raise ConfigError(
                "stack.gem_sign_stop.max_decel_mps2: expected at least min_decel_mps2 "
                f"({self.min_decel_mps2}), got {self.max_decel_mps2}"
            )


@dataclass(slots=True)
class KnownSign:
    """A sign the detector found, in the map frame; ``served`` once the shuttle stood its full stop."""

    key: str
    xy_m: np.ndarray
    route_s_m: float
    stop_s_m: float
    decel_mps2: float
    served: bool = False
    stopped_since_s: float | None = None


@dataclass(slots=True)
class SignStats:
    """What the detector saw, for the run's report (per mapped sign: its id; else ``unmapped``)."""

    frames: int = 0
    frames_unplaced: int = 0
    detections: int = 0
    detections_rejected: int = 0
    """Detections the map check turned down (no mapped stop sign facing the shuttle near them)."""
    too_late: int = 0
    """Plates first seen too close to stop at ``max_decel_mps2``: not stopped for."""
    stops: int = 0
    passed_unserved: int = 0
    """Signs left behind without a full stop (the shuttle was pulling over, say)."""
    per_sign: dict[str, dict[str, list[float]]] = field(default_factory=dict)
    cpu_ms: list[float] = field(default_factory=list)

    def record(self, key: str, name: str, value: float) -> None:
        self.per_sign.setdefault(key, {}).setdefault(name, []).append(value)


def _normal_angle(plate_xy: np.ndarray) -> float:
    """The direction of a mapped plate's normal (either face: Lanelet2 fixes no drawing direction for a
    ``traffic_sign`` line string), from its first and last points."""
    dx, dy = plate_xy[-1] - plate_xy[0]
    return math.atan2(dx, -dy)


class GemSignStop:
    """GEM's detector on each processed rig frame, and the stop it asks for."""

    def __init__(
        self,
        settings: GemSignStopSettings,
        layers: SLayerDatabase,
        front_from_rear_axle_m: float,
        stop_rule: TrafficLightRuleConfig,
    ) -> None:
        self.settings = settings
        self.route: Polyline = layers.centerline
        self.front_m = front_from_rear_axle_m
        self.stop_rule = stop_rule
        self.rng = np.random.default_rng(settings.seed)
        signs = [lm for lm in layers.hdmap.landmarks if lm.kind == "sign"]
        self.mapped_ids = [str(lm.id) for lm in signs]
        self.mapped_xy = np.array([lm.xy.mean(axis=0) for lm in signs]).reshape(-1, 2)
        self.mapped_stop = np.array([lm.subtype.strip().lower() in STOP_SIGN_TYPES for lm in signs], bool)
        self.mapped_normal = np.array([_normal_angle(lm.xy) for lm in signs])
        self.line_s = np.array([rl.s_m for rl in layers.stop_lines])
        self.signs: list[KnownSign] = []
        self.stats = SignStats()
        self._speed_mps = 0.0
        self._last_seen: dict[str, int] = {}  # the frame each plate was last detected in

    # --------------------------------------------------------------------------------------------
    def update_from(
        self, result: LidarPipelineResult, estimate: LocalizationEstimate, rear_s_m: float | None
    ) -> None:
        """:meth:`update` with a processed rig frame, its weather noise left out (as the chain has it)."""
        keep = ~np.asarray(result.noise, dtype=bool)
        self.update(np.asarray(result.cloud.points[keep]), estimate, rear_s_m)

    def update(self, xyzi: np.ndarray, estimate: LocalizationEstimate, rear_s_m: float | None) -> None:
        """Run GEM's stages on the frame's corridor and remember an accepted sign.

        Args:
            xyzi: (N, >= 4) base-frame points of one rig frame: x, y, z (m), intensity (0..255).
            estimate: the stack's pose estimate at the frame's stamp.
            rear_s_m: the route s of the rear axle (the stack's last projection; None: not yet known).
        """
        st = self.stats
        st.frames += 1
        if not estimate.valid or rear_s_m is None:
            st.frames_unplaced += 1
            return
        t0 = time.thread_time()
        pose = estimate.map_from_base
        rear = self.route.project(pose.x_m, pose.y_m, hint_s_m=rear_s_m, window_m=10.0).s_m
        front_s = rear + self.front_m
        self._speed_mps = max(estimate.speed_mps, 0.0)  # GEM's v_i; a reversing estimate is a standstill
        self._forget_behind(rear)
        pts = np.asarray(xyzi, dtype=np.float64)
        cand = pts[(pts[:, 0] > 0.0) & (pts[:, _INTENSITY] >= self.settings.detector.min_intensity)]
        keep = self._in_corridor(pose, cand[:, :2], front_s)
        det = detect_sign(cand[keep, :3], cand[keep, _INTENSITY], self.rng, self.settings.detector)
        if det is not None:
            self._on_detection(pose, det.centroid_m[:2], det.distance_m, front_s)
        st.cpu_ms.append((time.thread_time() - t0) * 1e3)

    def _in_corridor(self, pose: SE2, xy_base: np.ndarray, front_s_m: float) -> np.ndarray:
        """(N,) bool: points ahead of the front bumper along the route, within the detector's range
        and the corridor's lateral window of the route."""
        if len(xy_base) == 0:
            return np.zeros(0, dtype=bool)
        reach = self.settings.detector.max_range_m
        s = front_s_m + np.arange(0.0, reach + _SAMPLE_M, _SAMPLE_M)
        line = self.route.points_at(s)
        ahead = self.route.points_at(s + _SAMPLE_M) - line
        unit = ahead / np.maximum(np.linalg.norm(ahead, axis=1, keepdims=True), 1e-9)
        xy = pose.apply_points(xy_base)
        rel = xy[:, None, :] - line[None, :, :]  # (N, K, 2)
        k = np.argmin(np.einsum("nkj,nkj->nk", rel, rel), axis=1)
        r, u = rel[np.arange(len(xy)), k], unit[k]
        along = r[:, 0] * u[:, 0] + r[:, 1] * u[:, 1]
        d = u[:, 0] * r[:, 1] - u[:, 1] * r[:, 0]  # left positive
        s_pt = s[k] + along
        c = self.settings
        return (
            (s_pt > front_s_m)
            & (s_pt <= front_s_m + reach)
            & (d <= c.corridor_left_m)
            & (-d <= c.corridor_right_m)
        )

    def _on_detection(self, pose: SE2, centroid_base: np.ndarray, range_m: float, front_s_m: float) -> None:
        st, c = self.stats, self.settings
        st.detections += 1
        xy = pose.apply_points(centroid_base.reshape(1, 2))[0]
        key, mapped_ok = self._mapped(xy, pose.yaw_rad)
        if key != "unmapped":
            # Distance error against the map (never the simulator's truth): where the plate is, and
            # the range the detector gave beside the range from the estimated pose to the mapped plate.
            i = self.mapped_ids.index(key)
            st.record(key, "position_error_m", float(np.hypot(*(xy - self.mapped_xy[i]))))
            mapped_range = float(np.hypot(*(self.mapped_xy[i] - (pose.x_m, pose.y_m))))
            st.record(key, "range_error_m", range_m - mapped_range)
        st.record(key, "range_m", range_m)
        # The first detection of each approach to a plate (one unseen for 5 s is a new approach).
        if st.frames - self._last_seen.get(key, -_NEW_APPROACH_FRAMES) >= _NEW_APPROACH_FRAMES:
            st.record(key, "first_range_m", range_m)
        self._last_seen[key] = st.frames
        if c.check is SignCheck.MAP_CHECKED and not mapped_ok:
            st.detections_rejected += 1
            return
        known = next((k for k in self.signs if np.hypot(*(k.xy_m - xy)) <= c.match_radius_m), None)
        sign_s = self.route.project(float(xy[0]), float(xy[1]), hint_s_m=front_s_m, window_m=60.0).s_m
        if known is None:
            stop_s = self._stop_s(sign_s)
            gap = max(self.route.ds_m(front_s_m, stop_s), self.stop_rule.gap_floor_m)
            decel = max(-stop_deceleration_mps2(self._speed_mps, gap), c.min_decel_mps2)
            if decel > c.max_decel_mps2:
                st.too_late += 1
                return
            self.signs.append(
                KnownSign(key=key, xy_m=xy, route_s_m=sign_s, stop_s_m=stop_s, decel_mps2=decel)
            )
            st.record(key, "decel_mps2", decel)
        elif not known.served:
            # A nearer look places the plate better (more points: GEM's ~40 at 10 m).
            known.xy_m, known.route_s_m, known.stop_s_m = xy, sign_s, self._stop_s(sign_s)

    def _mapped(self, xy: np.ndarray, yaw_rad: float) -> tuple[str, bool]:
        """The nearest mapped plate within the match radius (``unmapped``: none), and whether a mapped
        stop sign facing the shuttle (GEM's facing cosine) is within it."""
        if len(self.mapped_xy) == 0:
            return "unmapped", False
        dist = np.hypot(*(self.mapped_xy - xy).T)
        near = dist <= self.settings.match_radius_m
        if not near.any():
            return "unmapped", False
        nearest = int(np.argmin(dist))
        # GEM's facing test on the mapped plate: its normal along the shuttle's heading (|cos| >= 0.9).
        facing = np.abs(np.cos(self.mapped_normal - yaw_rad)) >= self.settings.detector.min_facing
        return self.mapped_ids[nearest], bool((near & self.mapped_stop & facing).any())

    def _stop_s(self, sign_s_m: float) -> float:
        """Where the front stops for a sign at ``sign_s_m``: before its mapped line, else before it."""
        c = self.settings
        if len(self.line_s):
            ds = np.array([self.route.ds_m(sign_s_m, s) for s in self.line_s])
            near = (ds >= -c.line_before_sign_m) & (ds <= c.line_after_sign_m)
            if near.any():
                return float(self.line_s[near][np.argmin(np.abs(ds[near]))]) - c.setback_m
        return sign_s_m - c.setback_m

    def _forget_behind(self, rear_s_m: float) -> None:
        """Drop the signs behind the rear axle (out of GEM's field of view): the next lap stops again."""
        kept = []
        for k in self.signs:
            if self.route.ds_m(rear_s_m, k.route_s_m) >= 0.0:
                kept.append(k)
            elif not k.served:
                self.stats.passed_unserved += 1
        self.signs = kept

    # --------------------------------------------------------------------------------------------
    def _active(self, front_s_m: float) -> KnownSign | None:
        """The nearest unserved sign whose stop point is not yet behind the front."""
        at = self.stop_rule.at_line_m
        live = [k for k in self.signs if not k.served and self.route.ds_m(front_s_m, k.stop_s_m) > -at]
        return min(live, key=lambda k: self.route.ds_m(front_s_m, k.stop_s_m), default=None)

    def step(self, t_s: float, front_s_m: float, speed_mps: float) -> tuple[float | None, str]:
        """(front-bumper stop s or None, why), every decision cycle: the full stop, then on."""
        k = self._active(front_s_m)
        if k is None:
            return None, ""
        r = self.stop_rule
        gap = self.route.ds_m(front_s_m, k.stop_s_m)
        if gap < r.at_line_m and speed_mps < r.stopped_mps:
            if k.stopped_since_s is None:
                k.stopped_since_s = t_s
            if t_s - k.stopped_since_s >= r.full_stop_s:
                k.served = True
                self.stats.stops += 1
                return None, f"GEM sign detector: sign {k.key} stopped, go"
        else:
            k.stopped_since_s = None
        return k.stop_s_m, f"GEM sign detector: stop sign {k.key} {gap:.1f} m ahead"

    def cap_mps(self, cap_mps: float, front_s_m: float) -> float:
        """GEM's constant deceleration to the active sign's stop point: sqrt(2 a gap), at most ``cap_mps``."""
        k = self._active(front_s_m)
        if k is None:
            return cap_mps
        gap = max(self.route.ds_m(front_s_m, k.stop_s_m), 0.0)
        return min(cap_mps, math.sqrt(2.0 * k.decel_mps2 * gap))

    def counters(self) -> dict[str, int]:
        """The stack report's counters of this option."""
        st = self.stats
        return {
            "gem_sign_frames": st.frames,
            "gem_sign_frames_unplaced": st.frames_unplaced,
            "gem_sign_detections": st.detections,
            "gem_sign_detections_rejected": st.detections_rejected,
            "gem_sign_too_late": st.too_late,
            "gem_sign_stops": st.stops,
            "gem_sign_passed_unserved": st.passed_unserved,
        }

    def summary(self) -> dict[str, float | int | None]:
        """Per mapped sign: detections, first ranges, distance errors (medians), and the CPU per call."""
        out: dict[str, float | int | None] = {}
        for key, rec in sorted(self.stats.per_sign.items()):
            p = f"gem_sign_{key}_"
            out[p + "detections"] = len(rec["range_m"])
            for name in ("first_range_m", "decel_mps2"):
                if name in rec:
                    out[p + name + "_max"] = float(max(rec[name]))
                    out[p + name + "_min"] = float(min(rec[name]))
            for name in ("position_error_m", "range_error_m"):
                if name in rec:
                    v = np.asarray(rec[name])
                    out[p + name + "_median"] = float(np.median(v))
                    out[p + name + "_max_abs"] = float(np.max(np.abs(v)))
        if self.stats.cpu_ms:
            out["gem_sign_cpu_p50_ms"] = float(np.median(self.stats.cpu_ms))
            out["gem_sign_cpu_p95_ms"] = float(np.percentile(self.stats.cpu_ms, 95))
        return out
