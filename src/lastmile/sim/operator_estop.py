"""The operator's e-stop button as a scenario plays it: pressed in a given behaviour state, released later.

ISO 22737 asks for an emergency stop from every state of the system. The scenario names the state; the
operator presses the button the first time the stack reports it while the shuttle moves at least
``min_speed_mps``, and releases it (confirming the cause
is gone) once the shuttle has stood still for ``release_s``, as an operator would after checking.
"""

from __future__ import annotations

from enum import Enum

from lastmile.core.vehicle_messages import BehaviourState

STANDSTILL_MPS = 0.05
"""Below this the operator sees the shuttle as stopped (the fail-safe arbiter's standstill)."""


class EStopAction(Enum):
    PRESS = "press"
    RELEASE = "release"


class OperatorEStop:
    """Decides, tick by tick, when the operator presses and releases the e-stop."""

    def __init__(self, in_state: str, release_s: float, min_speed_mps: float = 0.0) -> None:
        self.in_state = in_state
        self.min_speed_mps = min_speed_mps
        self.release_s = release_s
        self.pressed_s: float | None = None
        self.released_s: float | None = None
        self._still_since_s: float | None = None

    def step(self, t_s: float, state: BehaviourState | None, speed_mps: float) -> EStopAction | None:
        """The operator's action at ``t_s`` given the state the stack reports and the shuttle's speed."""
        if not self.in_state or self.released_s is not None:
            return None
        if self.pressed_s is None:
            if state is not None and state.value == self.in_state and abs(speed_mps) >= self.min_speed_mps:
                self.pressed_s = t_s
                return EStopAction.PRESS
            return None
        if abs(speed_mps) >= STANDSTILL_MPS:
            self._still_since_s = None
            return None
        if self._still_since_s is None:
            self._still_since_s = t_s
        if t_s - self._still_since_s >= self.release_s:
            self.released_s = t_s
            return EStopAction.RELEASE
        return None
