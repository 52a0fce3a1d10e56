"""Offset paths around a stationary obstacle through the adjacent lane: a small lattice of quintic moves.

When decision orders a pass (:class:`~lastmile.core.vehicle_messages.PassRequest`), the path's lateral
offset d(s) goes out over a quintic lane-offset curve (zero slope and curvature at both ends, as
aUToronto's quintic lattice edges and ``hdmap.lane_change``), holds beside the obstacle, and comes back
over a second quintic once the body's rear is past it. Candidates vary the held offset (the obstacle's
left edge plus the body clearance, plus ``extra_offsets_m``) and the move length (shares of the
comfortable length: peak lateral acceleration ``comfort_lateral_accel_mps2`` at ``speed_mps``, never
below what the steering can follow). Each candidate's body, placed along the path (rear axle on it,
body on its tangent), is checked against

- the road surface: every corner inside the map's drivable area, the left side inside the request's
  ``max_d_m``;
- every track: standing ones keep ``clearance_m`` (the one passed) or ``min_clearance_m`` (others);
  moving ones, predicted at constant velocity to when the shuttle gets there at ``speed_mps``, keep
  ``min_clearance_m``;

and the feasible ones are scored (Snow Lion's J_d + J_o form): offset from the lane, lateral
acceleration, the inverse of the least clearance, and a short move. No feasible candidate: the in-lane
path, for which decision stops behind the obstacle. A committed pass keeps its chosen candidate.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from lastmile.core.geometry import FloatArray
from lastmile.core.polyline import Polyline
from lastmile.core.route_obstacles import RouteObstacle
from lastmile.core.vehicle_messages import BehaviourDecision, BehaviourState, PassRequest
from lastmile.planning.local_path import CurbLookup, LocalPathConfig, LocalPathPlanner
from lastmile.planning.pass_path_config import PassPathConfig
from lastmile.planning.road_edge import BodyPlacement, DrivableLookup

QUINTIC_PEAK = 10.0 / math.sqrt(3.0)
"""max |d²σ/du²| of the quintic smoothstep σ(u) = 10u³ - 15u⁴ + 6u⁵ on [0, 1]."""


@dataclass(frozen=True, slots=True)
class PassCandidate:
    """One lattice candidate: held offset (rear axle), move length, and its cost (inf: infeasible)."""

    offset_m: float
    length_m: float
    cost: float
    min_clearance_m: float


class OffsetPassPlanner(LocalPathPlanner):
    """The potential-field/Bezier planner, and passes by the adjacent lane when decision orders one.

    Args:
        drivable: the map's drivable-area test (None: not checked, for synthetic tests only).
        max_curvature_1pm: the tightest curvature the vehicle steers (tan(max steer) / wheelbase).
    """

    def __init__(
        self,
        route: Polyline,
        half_width_m: float,
        config: LocalPathConfig | None = None,
        curb_right_d_m: CurbLookup | None = None,
        body_behind_m: float = 0.0,
        body_ahead_m: float = 0.0,
        drivable: DrivableLookup | None = None,
        max_curvature_1pm: float = 0.2,
        body: BodyPlacement | None = None,
    ) -> None:
        super().__init__(
            route, half_width_m, config, curb_right_d_m, body_behind_m, body_ahead_m, drivable, body
        )
        self.max_curvature_1pm = max_curvature_1pm
        self.pass_config: PassPathConfig = self.config.passing
        self.body_behind_m, self.body_ahead_m = body_behind_m, body_ahead_m
        self.chosen: tuple[int, PassCandidate] | None = None
        self.last_candidates: list[PassCandidate] = []

    def offsets_m(
        self, s_m: FloatArray, decision: BehaviourDecision, obstacles: list[RouteObstacle], ego_d_m: float
    ) -> FloatArray:
        req = decision.pass_request
        if req is None or decision.state not in (BehaviourState.NORMAL_DRIVING, BehaviourState.INTERSECTION):
            self.chosen = None
            return super().offsets_m(s_m, decision, obstacles, ego_d_m)
        ego_s = float(s_m[0]) + self.config.behind_m
        base = super().offsets_m(s_m, decision, obstacles, ego_d_m)
        look = self._lookout_m(s_m, req, ego_s)
        chosen = self._choose(req, ego_s, ego_d_m, obstacles) if req.approved else None
        if chosen is None:
            if not req.approved:
                self.chosen = None
            return np.maximum(base, look)
        start, end = self._rear_axle_span(req, ego_s)
        return pass_offsets_m(s_m, start, end, chosen.offset_m, chosen.length_m, look)

    def _lookout_m(self, s_m: FloatArray, req: PassRequest, ego_s_m: float) -> FloatArray:
        """The look-out offset inside the lane, reached over ``lookout_ramp_m`` as the front gets to
        the waiting point, held from there."""
        lap = self._lap(req, ego_s_m)
        at = req.wait_s_m + lap - self.body_ahead_m  # the rear axle with the front at the wait point
        u = np.clip(
            (np.asarray(s_m, dtype=float) - (at - self.pass_config.lookout_ramp_m))
            / self.pass_config.lookout_ramp_m,
            0.0,
            1.0,
        )
        return req.lookout_d_m * _smoothstep5(u)

    # --- the lattice --------------------------------------------------------------------------------
    def _lap(self, req: PassRequest, ego_s_m: float) -> float:
        """What brings the request's s (the front's lap) into the rear axle's lap on a loop."""
        if not self.route.closed:
            return 0.0
        return ego_s_m + self.route.ds_m(ego_s_m, req.start_s_m) - req.start_s_m

    def _rear_axle_span(self, req: PassRequest, ego_s_m: float) -> tuple[float, float]:
        """Route s (in the rear axle's lap) where the rear axle must be fully out, and may come back."""
        lap = self._lap(req, ego_s_m)
        out_by = req.start_s_m + lap - self.body_ahead_m
        back_from = req.end_s_m + lap + self.body_behind_m + self.pass_config.return_gap_m
        return out_by, back_from

    def comfortable_length_m(self, offset_m: float) -> float:
        c = self.pass_config
        kappa = min(
            c.comfort_lateral_accel_mps2 / max(c.speed_mps, 0.1) ** 2, c.steer_share * self.max_curvature_1pm
        )
        return math.sqrt(QUINTIC_PEAK * abs(offset_m) / kappa)

    def _choose(
        self, req: PassRequest, ego_s_m: float, ego_d_m: float, obstacles: list[RouteObstacle]
    ) -> PassCandidate | None:
        c = self.pass_config
        least = req.left_d_m + c.clearance_m + self.half_width_m
        most = req.max_d_m - self.half_width_m - c.edge_margin_m
        if req.committed and self.chosen is not None and self.chosen[0] == req.track_id:
            # A begun pass keeps its move (re-choosing mid-move would swerve), moved out further only
            # when the obstacle's left edge is seen further out: radar tracks a car from the side it
            # sees, and its left edge crept 0.3 m towards the passing shuttle.
            kept = self.chosen[1]
            if kept.offset_m < least <= most:
                kept = dataclasses.replace(kept, offset_m=least)
                self.chosen = (req.track_id, kept)
            return kept
        start, end = self._rear_axle_span(req, ego_s_m)
        candidates = []
        for extra in c.extra_offsets_m:
            offset = least + extra
            if offset > most:
                continue
            base_length = self.comfortable_length_m(offset)
            for share in c.length_shares:
                length = base_length * share
                if QUINTIC_PEAK * offset / length**2 > self.max_curvature_1pm * c.steer_limit_share:
                    continue  # beyond what the steering can follow with room for the tracking error
                if start - length < ego_s_m - 0.5 and not req.committed:
                    continue  # too late to begin this move from where the shuttle is
                candidates.append(self._score(req, ego_s_m, offset, length, start, end, obstacles))
        self.last_candidates = candidates
        feasible = [k for k in candidates if math.isfinite(k.cost)]
        if not feasible:
            self.chosen = None
            return None
        best = min(feasible, key=lambda k: k.cost)
        self.chosen = (req.track_id, best)
        return best

    def _score(
        self,
        req: PassRequest,
        ego_s_m: float,
        offset_m: float,
        length_m: float,
        start_m: float,
        end_m: float,
        obstacles: list[RouteObstacle],
    ) -> PassCandidate:
        c = self.pass_config
        s = np.arange(start_m - length_m, end_m + length_m + 0.5, 0.5)
        d = pass_offsets_m(s, start_m, end_m, offset_m, length_m, self._lookout_m(s, req, ego_s_m))
        corners = self._body_corners_sd(s, d)  # (N, 4, 2) s, d
        if not self._on_road(corners, req):
            return PassCandidate(offset_m, length_m, math.inf, 0.0)
        clearance = self._least_clearance_m(s, corners, req, ego_s_m, obstacles)
        if clearance is None:
            return PassCandidate(offset_m, length_m, math.inf, 0.0)
        lat_accel = c.speed_mps**2 * QUINTIC_PEAK * offset_m / length_m**2
        cost = (
            c.w_offset * offset_m
            + c.w_lateral_accel * lat_accel
            + c.w_clearance / max(clearance, 0.05)
            + c.w_length / length_m
        )
        return PassCandidate(offset_m, length_m, cost, clearance)

    def _body_corners_sd(self, s_m: FloatArray, d_m: FloatArray) -> FloatArray:
        """The body's corners in route (s, d) with the rear axle at (s, d), along the path's tangent."""
        psi = np.arctan(np.gradient(d_m, s_m))
        cos, sin = np.cos(psi)[:, None], np.sin(psi)[:, None]
        along = np.array([-self.body_behind_m, -self.body_behind_m, self.body_ahead_m, self.body_ahead_m])
        side = np.array([-self.half_width_m, self.half_width_m, -self.half_width_m, self.half_width_m])
        cs = s_m[:, None] + along[None, :] * cos - side[None, :] * sin
        cd = d_m[:, None] + along[None, :] * sin + side[None, :] * cos
        return np.stack([cs, cd], axis=-1)

    def _on_road(self, corners: FloatArray, req: PassRequest) -> bool:
        if float(corners[..., 1].max()) > req.max_d_m - self.pass_config.edge_margin_m + 1e-9:
            return False
        if self.drivable is None:
            return True
        flat = corners.reshape(-1, 2)
        base = self.route.points_at(flat[:, 0])
        tangent = self.route.points_at(flat[:, 0] + 0.5) - self.route.points_at(flat[:, 0] - 0.5)
        heading = np.arctan2(tangent[:, 1], tangent[:, 0])
        xy = base + flat[:, 1:2] * np.c_[-np.sin(heading), np.cos(heading)]
        return bool(np.all(self.drivable(xy)))

    def _least_clearance_m(
        self,
        s_m: FloatArray,
        corners: FloatArray,
        req: PassRequest,
        ego_s_m: float,
        obstacles: list[RouteObstacle],
    ) -> float | None:
        """The least gap from the body to the tracks it meets (None: one comes closer than allowed)."""
        c = self.pass_config
        lo_s, hi_s = corners[..., 0].min(axis=1), corners[..., 0].max(axis=1)
        lo_d, hi_d = corners[..., 1].min(axis=1), corners[..., 1].max(axis=1)
        t_s = np.maximum(s_m - ego_s_m, 0.0) / max(c.speed_mps, 0.5)
        least = math.inf
        for o in obstacles:
            o_s = ego_s_m + self.route.ds_m(ego_s_m, o.s_m) if self.route.closed else o.s_m
            moving = o.speed_mps > 0.5
            centre_s = o_s + (o.v_s_mps * t_s if moving else 0.0)
            centre_d = o.d_m + (o.v_d_mps * t_s if moving else 0.0)
            gap_s = np.maximum(centre_s - o.length_m / 2.0 - hi_s, lo_s - centre_s - o.length_m / 2.0)
            gap_d = np.maximum(centre_d - o.width_m / 2.0 - hi_d, lo_d - centre_d - o.width_m / 2.0)
            beside = gap_s < 0.0
            if not np.any(beside):
                continue
            gap = float(gap_d[beside].min())
            need = c.clearance_m if o.track_id == req.track_id else c.min_clearance_m
            if gap < need - 0.05:
                return None
            least = min(least, gap)
        return least


def pass_offsets_m(
    s_m: FloatArray,
    out_by_m: float,
    back_from_m: float,
    offset_m: float,
    length_m: float,
    from_d_m: FloatArray | float = 0.0,
) -> FloatArray:
    """d(s): ``from_d_m`` (the look-out offset), a quintic out to ``offset_m`` ending at ``out_by_m``,
    held, a quintic back to 0 from ``back_from_m`` (both over ``length_m``)."""
    s = np.asarray(s_m, dtype=float)
    up = _smoothstep5(np.clip((s - (out_by_m - length_m)) / length_m, 0.0, 1.0))
    down = _smoothstep5(np.clip((s - back_from_m) / length_m, 0.0, 1.0))
    before = np.broadcast_to(np.asarray(from_d_m, dtype=float), s.shape)
    return before + (offset_m - before) * up - offset_m * down


def _smoothstep5(u: FloatArray) -> FloatArray:
    return u * u * u * (10.0 - 15.0 * u + 6.0 * u * u)
