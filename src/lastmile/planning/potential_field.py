"""Potential-field nudge: shift the path inside the lane around obstacles that leave room to pass."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from lastmile.core.geometry import FloatArray
from lastmile.core.route_obstacles import RouteObstacle


@dataclass(frozen=True, slots=True, kw_only=True)
class PotentialFieldConfig:
    """Repulsion from obstacles and attraction to the lane centre.

    Attributes:
        clearance_m: lateral gap wanted between the shuttle's side and an obstacle it passes.
        influence_m: how far before and after an obstacle the path starts and ends shifting.
        max_speed_mps: obstacles faster than this along the route are traffic, not to be nudged around.
    """

    clearance_m: float = 0.5
    influence_m: float = 12.0
    max_speed_mps: float = 0.5


def nudge_offsets_m(
    s_m: FloatArray,
    obstacles: list[RouteObstacle],
    half_width_m: float,
    lane_left_d_m: float,
    lane_right_d_m: float,
    config: PotentialFieldConfig,
) -> FloatArray:
    """Lateral offsets d(s) (left positive) that pass obstacles partly in the lane, bounded by the lane.

    Each obstacle pushes the path away from its side with a smooth (cosine-shaped) bump over
    ``influence_m``; bumps on the same side take the maximum, the lane centre pulls back elsewhere.
    Offsets stop at the lane boundary minus the half width: an obstacle that leaves no room is not
    nudged around (decision making stops for it instead).
    """
    s = np.asarray(s_m, dtype=float)
    left = np.zeros_like(s)
    right = np.zeros_like(s)
    max_left = max(0.0, lane_left_d_m - half_width_m - 0.1)
    max_right = min(0.0, lane_right_d_m + half_width_m + 0.1)
    for o in obstacles:
        if abs(o.v_s_mps) > config.max_speed_mps:
            continue
        # The edge facing the lane centre is the one the shuttle must clear.
        near_edge = o.d_m + o.width_m / 2.0 if o.d_m < 0 else o.d_m - o.width_m / 2.0
        if o.d_m < 0:
            need = near_edge + config.clearance_m + half_width_m  # move left by this much
            if need <= 0.0 or need > max_left:
                continue
            target = need
        else:
            need = near_edge - config.clearance_m - half_width_m  # move right to this offset
            if need >= 0.0 or need < max_right:
                continue
            target = need
        lo = o.s_m - o.length_m / 2.0
        hi = o.s_m + o.length_m / 2.0
        w = config.influence_m
        bump = np.where(
            (s >= lo) & (s <= hi),
            1.0,
            np.where(
                (s > lo - w) & (s < lo),
                0.5 - 0.5 * np.cos(math.pi * (s - (lo - w)) / w),
                np.where((s > hi) & (s < hi + w), 0.5 + 0.5 * np.cos(math.pi * (s - hi) / w), 0.0),
            ),
        )
        if target > 0:
            left = np.maximum(left, target * bump)
        else:
            right = np.minimum(right, target * bump)
    return left + right
