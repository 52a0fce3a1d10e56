"""Where the shuttle's rear axle rests beside a curb that curves: the whole straight body keeps the gap.

A rigid body is straight; a curb along a curve is not. Resting with its rear axle at the curb gap on
a kerb that bends away from the lane's side (the outside of a bend), the body's far corner swings
over the kerb by about l^2 / 2R (0.47 m for l = 3.75 m of body ahead of the rear axle on a 15 m
radius); on the inside of a bend its middle bulges towards the kerb. So the rest offset is found
for the body as it may stand: its heading somewhere between the path's at the rear axle (it drove
straight onto the spot) and the chord between its axles (both axles on the path; a tracking
controller leaves it in between), every point of its curb side at least the gap from the curb line
at both, nowhere closer. On a straight curb this is the plain offset (curb + gap + half width),
unchanged.
"""

from __future__ import annotations

import math

import numpy as np

from lastmile.core.polyline import Polyline
from lastmile.core.vehicle import VehicleGeometry

SIDE_SAMPLE_M = 0.25
"""Spacing of the points along the body's curb side that are checked against the curb."""
FIT_ITERATIONS = 3
"""Shifts applied in turn; each moves the body by its worst shortfall (the chord's heading changes a
little with the offset, so a second shift settles it, a third confirms)."""
FIT_TOLERANCE_M = 1e-6
"""Shortfalls below this are rounding, not geometry: a straight curb keeps its plain offset exactly."""


def body_side_clearance_m(
    route: Polyline, rear_s_m: float, d_m: float, curb_d_m: float, geometry: VehicleGeometry
) -> float:
    """Least gap between the body's right side and the curb line (route d ``curb_d_m``), right < 0.

    The body rests with its rear axle at route (``rear_s_m``, ``d_m``), headed either along the
    route at the rear axle or along the chord to the point of the same offset line a wheelbase
    further on; the lesser gap of the two counts.
    """
    rx, ry, rh = route.point_at(rear_s_m)
    fx, fy, fh = route.point_at(rear_s_m + geometry.wheelbase_m)
    rear = np.array([rx - d_m * math.sin(rh), ry + d_m * math.cos(rh)])
    front = np.array([fx - d_m * math.sin(fh), fy + d_m * math.cos(fh)])
    chord = front - rear
    n = max(2, math.ceil(geometry.length_m / SIDE_SAMPLE_M) + 1)  # both corners included
    along = np.linspace(-geometry.rear_overhang_m, geometry.front_from_rear_axle_m, n)
    least = math.inf
    for axis in (np.array([math.cos(rh), math.sin(rh)]), chord / float(np.hypot(*chord))):
        right = np.array([axis[1], -axis[0]])
        side = rear + along[:, None] * axis + (geometry.width_m / 2.0) * right
        for x, y in side.tolist():
            p = route.project(x, y, hint_s_m=rear_s_m, window_m=geometry.length_m + 5.0)
            least = min(least, p.d_m - curb_d_m)
    return least


def spot_offset_m(
    route: Polyline, rear_s_m: float, curb_d_m: float, gap_m: float, geometry: VehicleGeometry
) -> float:
    """Route d of the rear axle at rest: the plain offset, moved away from the curb by as much as a
    curved curb needs for the straight body to keep ``gap_m`` everywhere along its side."""
    d = curb_d_m + gap_m + geometry.width_m / 2.0
    for _ in range(FIT_ITERATIONS):
        shortfall = gap_m - body_side_clearance_m(route, rear_s_m, d, curb_d_m, geometry)
        if shortfall <= FIT_TOLERANCE_M:
            break
        d += shortfall
    return d
