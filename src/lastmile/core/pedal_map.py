"""GEM's brake pedal map, b = 0.28 ln(a) + 0.90 clipped to [0, 1], and its inverse.

It lives in core because three layers use it: the twist controller (control) commands the brake with
it, the actuator gate (safety) turns an enforced deceleration into a brake pedal with it, and the
simulator's pedal plant (sim) brakes by its inverse. GEM published the map (its section II); it is the
only pedal data among the papers.
"""

from __future__ import annotations

import math

GEM_BRAKE_LOG_GAIN = 0.28
GEM_BRAKE_OFFSET = 0.90


def gem_brake_pedal(
    decel_mps2: float, gain: float = GEM_BRAKE_LOG_GAIN, offset: float = GEM_BRAKE_OFFSET
) -> float:
    """GEM's open-loop brake map b = gain ln(a) + offset for a deceleration magnitude a, in [0, 1]."""
    if decel_mps2 <= 0.0:
        return 0.0
    return min(max(gain * math.log(decel_mps2) + offset, 0.0), 1.0)


def brake_decel_mps2(
    brake: float, gain: float = GEM_BRAKE_LOG_GAIN, offset: float = GEM_BRAKE_OFFSET
) -> float:
    """Deceleration (positive, m/s^2) of a brake pedal position in [0, 1] (GEM's map inverted)."""
    if brake <= 0.0:
        return 0.0
    return math.exp((min(brake, 1.0) - offset) / gain)
