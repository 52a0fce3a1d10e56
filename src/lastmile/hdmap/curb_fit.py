"""A straight body beside a kerb that curves: where its rear axle rests, and how far its door is then.

A rigid body is straight; a kerb along a curve is not. Resting with its rear axle at the curb gap on
a kerb that bends away from the lane's side (the outside of a bend), the body's far corner swings
over the kerb by about l^2 / 2R (0.47 m for l = 3.75 m of body ahead of the rear axle on a 15 m
radius); on the inside of a bend its middle bulges towards the kerb. The heading the body rests at
lies between the path's at its rear axle (the rear wheels are kept straight at a kerb, so the rear
axle tracks the path) and the chord between its axles (both axles on the path), depending on how the
controller settled; neither is known in advance, so both count.

Two measures follow, and they are different things:

- the **body's gap**: the least gap of any point of its kerb side (corners included) to the kerb
  line. The rest offset keeps it at the pull-over's gap target at both headings: no part of the
  body comes nearer the kerb than the target, so it cannot strike or overhang it;
- the **door gap**: from the door (the middle of the kerb side) to the kerb, the step a rider takes.
  This is the curb gap a stop is judged by. With the body kept off the kerb it is the target plus
  the bend's bulge between the body's nearest point and its door (b^2 / 2R on the outside of a bend
  for b = half the body's length, 0 on the inside), so on a tight bend the target cannot be met; the
  route build moves such a platform (``service_route``).

On a straight kerb the rest offset is the plain one (kerb + gap + half width), exactly, and the door
gap is the target.
"""

from __future__ import annotations

import math

import numpy as np

from lastmile.core.polyline import Polyline
from lastmile.core.vehicle import VehicleGeometry

CURB_GAP_TARGET_M = 0.2
"""The gap a pull-over keeps between the shuttle's side and the kerb (``DecisionConfig.curb_gap_target_m``
defaults to it; the route build predicts door gaps with it)."""
SIDE_SAMPLE_M = 0.25
"""Spacing of the points along the body's kerb side that are checked against the kerb."""
FIT_ITERATIONS = 3
"""Shifts applied in turn; each moves the body by its worst shortfall (the chord's heading changes a
little with the offset, so a second shift settles it, a third confirms)."""
FIT_TOLERANCE_M = 1e-6
"""Shortfalls below this are rounding, not geometry: a straight kerb keeps its plain offset exactly."""


def _side_gaps_m(
    route: Polyline, rear_s_m: float, d_m: float, curb_d_m: float, geometry: VehicleGeometry
) -> list[np.ndarray]:
    """Gaps to the kerb line (route d ``curb_d_m``, right < 0) of the points along the body's right
    side, rear corner to front corner, door last; one array per heading (rear axle's, chord's)."""
    rear = _offset_point(route, rear_s_m, d_m)
    # The rear axle's heading is that of the offset line over the half wheelbase either side of it
    # (the rear wheels roll straight along what they last drove): a mapped line is a polygon, and its
    # heading at one point jumps by the angle of whichever vertex is nearest.
    half = geometry.wheelbase_m / 2.0
    tangent = _offset_point(route, rear_s_m + half, d_m) - _offset_point(route, rear_s_m - half, d_m)
    chord = _offset_point(route, rear_s_m + geometry.wheelbase_m, d_m) - rear
    n = max(2, math.ceil(geometry.length_m / SIDE_SAMPLE_M) + 1)  # both corners included
    door = geometry.length_m / 2.0 - geometry.rear_overhang_m
    along = np.append(np.linspace(-geometry.rear_overhang_m, geometry.front_from_rear_axle_m, n), door)
    out = []
    for axis in (tangent / float(np.hypot(*tangent)), chord / float(np.hypot(*chord))):
        right = np.array([axis[1], -axis[0]])
        side = rear + along[:, None] * axis + (geometry.width_m / 2.0) * right
        window = geometry.length_m + 5.0
        gaps = [
            route.project(x, y, hint_s_m=rear_s_m, window_m=window).d_m - curb_d_m for x, y in side.tolist()
        ]
        out.append(np.array(gaps))
    return out


def _offset_point(route: Polyline, s_m: float, d_m: float) -> np.ndarray:
    x, y, h = route.point_at(s_m)
    return np.array([x - d_m * math.sin(h), y + d_m * math.cos(h)])


def body_side_clearance_m(
    route: Polyline, rear_s_m: float, d_m: float, curb_d_m: float, geometry: VehicleGeometry
) -> float:
    """Least gap between the body's right side and the kerb line (route d ``curb_d_m``, right < 0).

    The body rests with its rear axle at route (``rear_s_m``, ``d_m``), headed either along the
    route at the rear axle or along the chord to the point of the same offset line a wheelbase
    further on; the lesser gap of the two counts.
    """
    return min(float(g.min()) for g in _side_gaps_m(route, rear_s_m, d_m, curb_d_m, geometry))


def door_gap_m(
    route: Polyline, rear_s_m: float, d_m: float, curb_d_m: float, geometry: VehicleGeometry
) -> float:
    """The door's gap to the kerb line for the body resting as in ``body_side_clearance_m``: the
    larger of the two headings' (the step a rider may face)."""
    return max(float(g[-1]) for g in _side_gaps_m(route, rear_s_m, d_m, curb_d_m, geometry))


def spot_offset_m(
    route: Polyline, rear_s_m: float, curb_d_m: float, gap_m: float, geometry: VehicleGeometry
) -> float:
    """Route d of the rear axle at rest: the plain offset, moved away from the kerb by as much as a
    curved kerb needs for the straight body to keep ``gap_m`` everywhere along its side."""
    d = curb_d_m + gap_m + geometry.width_m / 2.0
    for _ in range(FIT_ITERATIONS):
        shortfall = gap_m - body_side_clearance_m(route, rear_s_m, d, curb_d_m, geometry)
        if shortfall <= FIT_TOLERANCE_M:
            break
        d += shortfall
    return d


def rest_door_gap_m(
    route: Polyline, door_s_m: float, curb_d_m: float, gap_m: float, geometry: VehicleGeometry
) -> float:
    """The door gap of a pull-over whose door stops at route ``door_s_m`` beside a kerb at route d
    ``curb_d_m``, with the rest offset of ``spot_offset_m``: ``gap_m`` on a straight kerb, more where
    the kerb bends."""
    rear_s = door_s_m - (geometry.length_m / 2.0 - geometry.rear_overhang_m)
    d = spot_offset_m(route, rear_s, curb_d_m, gap_m, geometry)
    return door_gap_m(route, rear_s, d, curb_d_m, geometry)
