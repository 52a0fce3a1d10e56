"""The INTERSECTION state: stop at an all-way stop line, stand, go in arrival order (WATonoBus IV-B)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lastmile.core.vehicle_messages import BehaviourState, StopReason
from lastmile.decision.behaviour_memory import BehaviourMemory, Cycle, DecisionContext, Outcome
from lastmile.decision.right_of_way import ArrivalOrder, EntryLine
from lastmile.decision.stop_constraints import StopConstraint
from lastmile.hdmap.layers import RouteStopLine, SLayerDatabase


@dataclass(frozen=True, slots=True)
class AllWayStops:
    """The map's all-way stops, by id: conflict box (K, 2) polygon in map metres and entry lines."""

    boxes: dict[int, np.ndarray]
    entries: dict[int, tuple[EntryLine, ...]]

    @staticmethod
    def from_layers(layers: SLayerDatabase, entry_heading_back_m: float) -> AllWayStops:
        """Each entry line's midpoint, and its lanelet's heading ``entry_heading_back_m`` before the end."""
        boxes: dict[int, np.ndarray] = {}
        entries: dict[int, tuple[EntryLine, ...]] = {}
        hdmap = layers.hdmap
        for aws in hdmap.all_way_stops:
            boxes[aws.id] = np.asarray(aws.conflict_polygon, dtype=float)
            lines = []
            for sl in hdmap.stop_lines:
                if sl.all_way_stop_id != aws.id:
                    continue
                lanelet = hdmap.lanelets[sl.lanelet_id]
                heading = lanelet.centerline.heading_at(lanelet.centerline.length_m - entry_heading_back_m)
                mid = np.asarray(sl.line, dtype=float).mean(axis=0)
                lines.append(EntryLine(sl.id, float(mid[0]), float(mid[1]), heading))
            entries[aws.id] = tuple(lines)
        return AllWayStops(boxes=boxes, entries=entries)


def next_all_way_stop_line(ctx: DecisionContext, front_s_m: float) -> tuple[float, int] | None:
    """(route s, row in ``stop_lines``) of the nearest all-way stop line not yet passed."""
    best: tuple[float, int] | None = None
    for i, rl in enumerate(ctx.layers.stop_lines):
        if rl.all_way_stop_id is None:
            continue
        ahead = ctx.ahead_m(rl.s_m, front_s_m)
        if ahead > -ctx.config.stop_line_passed_m and (
            best is None or ahead < ctx.ahead_m(best[0], front_s_m)
        ):
            best = (rl.s_m, i)
    return best


def handle_intersection(
    ctx: DecisionContext, junctions: AllWayStops, mem: BehaviourMemory, cy: Cycle
) -> Outcome:
    """Stop at the line, stand ``full_stop_s``, then go once nobody who arrived earlier waits and the
    box is clear; intersection handling ends ``intersection_cleared_m`` past the line."""
    visit = mem.intersection
    rl = ctx.layers.stop_lines[visit.line_index] if visit.line_index is not None else None
    if rl is None:
        mem.enter(BehaviourState.NORMAL_DRIVING, cy.t_s, "no stop line")
        return Outcome(cy.speed_cap_mps, "cruise")
    aws_id = rl.all_way_stop_id
    if aws_id is None or aws_id not in junctions.boxes:
        mem.enter(BehaviourState.NORMAL_DRIVING, cy.t_s, "stop line without an all-way stop")
        return Outcome(cy.speed_cap_mps, "cruise")
    arrival = _arrival_order(junctions, mem, rl, aws_id)
    arrival.observe(cy.t_s, cy.inp.tracks)
    to_line = ctx.ahead_m(rl.s_m, cy.front_s_m)
    if visit.go:
        if to_line < -ctx.config.intersection_cleared_m:
            _leave_intersection(mem, cy.t_s)
            return Outcome(cy.speed_cap_mps, "cleared intersection")
        return Outcome(cy.speed_cap_mps, "crossing intersection")
    return _wait_at_line(ctx, mem, arrival, rl, to_line, cy)


def _arrival_order(
    junctions: AllWayStops, mem: BehaviourMemory, rl: RouteStopLine, aws_id: int
) -> ArrivalOrder:
    """The arrival order at this junction, made afresh when the shuttle comes to another one."""
    visit = mem.intersection
    if visit.arrival is None or visit.arrival.box is not junctions.boxes[aws_id]:
        entries = tuple(e for e in junctions.entries[aws_id] if e.stop_line_id != rl.stop_line.id)
        visit.arrival = ArrivalOrder(entries=entries, box=junctions.boxes[aws_id])
    return visit.arrival


def _wait_at_line(
    ctx: DecisionContext,
    mem: BehaviourMemory,
    arrival: ArrivalOrder,
    rl: RouteStopLine,
    to_line: float,
    cy: Cycle,
) -> Outcome:
    """Stand at the line; go (set ``go``) after a full stop when it is the shuttle's turn."""
    c, visit, t_s = ctx.config, mem.intersection, cy.t_s
    if to_line < c.stop_line_reach_m and cy.inp.speed_mps < c.line_stopped_mps:
        arrival.ego_stopped(t_s)
        if visit.stopped_at_line_since_s is None:
            visit.stopped_at_line_since_s = t_s
    owed = arrival.owed()
    inside = arrival.box_occupied(cy.inp.tracks)
    standing_s = t_s - visit.stopped_at_line_since_s if visit.stopped_at_line_since_s is not None else -1.0
    stood = standing_s >= c.full_stop_s
    if standing_s >= c.full_stop_s + c.unclaimed_turn_s:
        # Whoever stopped first and still stands (it has not moved off its line) leaves us the turn.
        owed = []
    if stood and not owed and inside < 0:
        visit.go = True
        return Outcome(cy.speed_cap_mps, "right of way: go")
    risk = inside if inside >= 0 else (owed[0] if owed else -1)
    cy.constraints.append(
        StopConstraint(rl.s_m - c.stop_line_setback_m, "stop_line", risk, False, StopReason.STOP_LINE)
    )
    why = (
        f"yield to {len(owed)} earlier arrivals" if owed else ("box occupied" if inside >= 0 else "full stop")
    )
    return Outcome(cy.speed_cap_mps, why)


def _leave_intersection(mem: BehaviourMemory, t_s: float) -> None:
    visit = mem.intersection
    visit.go = False
    visit.stopped_at_line_since_s = None
    visit.line_index = None
    if visit.arrival is not None:
        visit.arrival.reset()
    mem.enter(BehaviourState.NORMAL_DRIVING, t_s, "intersection cleared")
