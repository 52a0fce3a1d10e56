"""Parameters of the offset-pass planner (:mod:`lastmile.planning.pass_path`), ``[stack.path.passing]``."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True, slots=True, kw_only=True)
class PassPathConfig:
    """Parameters of :class:`OffsetPassPlanner`.

    Attributes:
        clearance_m: the gap kept between the body and the obstacle passed (decision's ``clearance_m``).
        min_clearance_m: the least gap to any other track (the in-path test's corridor margin).
        extra_offsets_m: offsets beyond the least one tried (more room, more of the other lane).
        length_shares: shares of the comfortable move length tried (shorter: steeper, more comfort cost).
        speed_mps: the speed the move's comfort and the tracks' timing are reckoned with (decision's cap).
        comfort_lateral_accel_mps2: the move's peak lateral acceleration (``hdmap.lane_change``'s 1.0).
        steer_share: the comfortable move uses at most this share of the tightest curvature the vehicle
            steers (``hdmap.lane_change``'s 0.5) ...
        steer_limit_share: ... and a shortened one at most this share (room for the tracking error).
        edge_margin_m: the body's left side stays this far inside ``max_d_m``.
        return_gap_m: the body's rear clears the obstacle's front by this before moving back.
        lookout_ramp_m: the move to the look-out offset inside the lane (waiting to pass) is this long.
        w_offset, w_lateral_accel, w_clearance, w_length: cost weights (per m, per m/s^2, per 1/m,
            per 1/m).
    """

    clearance_m: float = 1.0
    min_clearance_m: float = 0.5
    extra_offsets_m: tuple[float, ...] = (0.0, 0.3, 0.6)
    length_shares: tuple[float, ...] = (1.0, 0.8, 0.65)
    speed_mps: float = 4.0
    comfort_lateral_accel_mps2: float = 1.0
    steer_share: float = 0.5
    steer_limit_share: float = 0.8
    edge_margin_m: float = 0.3
    return_gap_m: float = 1.0
    lookout_ramp_m: float = 15.0
    w_offset: float = 1.0
    w_lateral_accel: float = 2.0
    w_clearance: float = 0.5
    w_length: float = 5.0
