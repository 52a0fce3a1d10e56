"""The kinds of event a run log holds: one enum, so that writers and readers cannot drift apart.

The run log stores the value (a plain string in JSON); ``EventKind`` is a ``StrEnum``, so a kind read
back from a file compares equal to its member. The required fields of each kind are in
:data:`lastmile.recorder.run_log.EVENT_SCHEMAS`.
"""

from __future__ import annotations

from enum import StrEnum


class EventKind(StrEnum):
    """Every event kind the loop, the referee, the operators and the fleet link write."""

    # The referee (simulator ground truth; never seen by the vehicle).
    COLLISION = "collision"
    TAKEOVER = "takeover"
    RULE_VIOLATION = "rule_violation"
    STOP_SERVED = "stop_served"
    STOP_MISSED = "stop_missed"
    PASSENGER_BOARDED = "passenger_boarded"
    PASSENGER_ALIGHTED = "passenger_alighted"
    DROP_OFF_REQUESTED = "drop_off_requested"
    """A rider on board pressed the drop-off button (Snow Lion's unscheduled drop-off)."""
    DROP_OFF_SERVED = "drop_off_served"
    """That rider got off (at the kerb, or at a stop), measured as the shuttle moved off again."""
    MIN_TTC = "min_ttc"
    INTERSECTION_ENTRY = "intersection_entry"
    SIGNAL_ENTRY = "signal_entry"
    GIVE_WAY_ENTRY = "give_way_entry"
    """The shuttle's front crossed a give-way line or a two-way stop's line: whether it stood before it."""
    LOOP_COMPLETED = "loop_completed"
    ROAD_USER = "road_user"
    """Another road user first logged: its id and class (positions go to the agents table)."""
    # The scenario's operators.
    OPERATOR_ESTOP = "operator_estop"
    OPERATOR_RELEASE = "operator_release"
    # The loop: injected faults, the vehicle software and the vehicle safety.
    FAULT_START = "fault_start"
    FAULT_END = "fault_end"
    STACK_CRASH = "stack_crash"
    HARDWARE_WATCHDOG = "hardware_watchdog"
    SAFETY = "safety"
    LOCALIZATION = "localization"
    """What holds the vehicle's pose (GNSS, landmarks, dead reckoning) or the GNSS fix quality changed."""
    STATE_CHANGE = "state_change"
    EMERGENCY_STOP = "emergency_stop"
    HMI = "hmi"
    RECORDING = "recording"
    # The fleet link.
    V2I_ANTICIPATION = "v2i_anticipation"
    FLEET_UNPLANNED_STOP = "fleet_unplanned_stop"
    FLEET_TRIP_DONE = "fleet_trip_done"
