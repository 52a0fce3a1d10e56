"""Arrival order at an all-way stop, as WATonoBus keeps it: who stopped at a line first goes first."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from lastmile.core.geometry import point_in_polygon
from lastmile.core.object_class import ObjectClass
from lastmile.core.objects import TRACK_COLUMNS, TrackedObjects

_X, _Y, _VX, _VY, _CLS = (TRACK_COLUMNS.index(c) for c in ("x_m", "y_m", "vx_mps", "vy_mps", "class_id"))


@dataclass(frozen=True, slots=True)
class EntryLine:
    """Another entry's stop line: midpoint and the direction traffic arrives in."""

    stop_line_id: int
    mid_x_m: float
    mid_y_m: float
    heading_rad: float


@dataclass(slots=True)
class _Waiting:
    arrived_s: float
    x_m: float
    y_m: float
    last_seen_s: float


@dataclass(slots=True)
class ArrivalOrder:
    """Records when other vehicles stopped at the other entries and when the shuttle did.

    A waiting vehicle is forgotten when it drives off (moves ``depart_m`` from where it waited) or its
    track is gone for ``forget_s``. The shuttle may go once nobody who arrived earlier still waits,
    the box is clear of vehicles and of pedestrians and cyclists (they always go first).
    """

    entries: tuple[EntryLine, ...]
    box: np.ndarray
    stop_zone_m: float = 8.0
    depart_m: float = 2.5
    forget_s: float = 1.5
    tie_s: float = 0.3
    waiting: dict[int, _Waiting] = field(default_factory=dict)
    ego_arrived_s: float | None = None

    def reset(self) -> None:
        self.waiting.clear()
        self.ego_arrived_s = None

    def observe(self, t_s: float, tracks: TrackedObjects) -> None:
        seen: set[int] = set()
        for tid, row in zip(tracks.ids.tolist(), tracks.table.tolist(), strict=True):
            if int(row[_CLS]) not in (ObjectClass.CAR, ObjectClass.UNKNOWN):
                continue
            x, y = row[_X], row[_Y]
            known = self.waiting.get(tid)
            if known is not None:
                seen.add(tid)
                known.last_seen_s = t_s
                if math.hypot(x - known.x_m, y - known.y_m) > self.depart_m:
                    del self.waiting[tid]
                continue
            if math.hypot(row[_VX], row[_VY]) > 0.5:
                continue
            for line in self.entries:
                dx, dy = line.mid_x_m - x, line.mid_y_m - y
                c, s = math.cos(line.heading_rad), math.sin(line.heading_rad)
                along, lateral = dx * c + dy * s, -dx * s + dy * c
                if -1.0 < along < self.stop_zone_m and abs(lateral) < 2.5:
                    self.waiting[tid] = _Waiting(t_s, x, y, t_s)
                    seen.add(tid)
                    break
        for tid in [t for t, w in self.waiting.items() if t_s - w.last_seen_s > self.forget_s]:
            del self.waiting[tid]

    def ego_stopped(self, t_s: float) -> None:
        if self.ego_arrived_s is None:
            self.ego_arrived_s = t_s

    def owed(self) -> list[int]:
        """Vehicles that arrived before the shuttle and still wait."""
        if self.ego_arrived_s is None:
            return list(self.waiting)
        return [t for t, w in self.waiting.items() if w.arrived_s < self.ego_arrived_s - self.tie_s]

    def box_occupied(self, tracks: TrackedObjects) -> int:
        """Id of a track inside the intersection box, else -1."""
        for tid, row in zip(tracks.ids.tolist(), tracks.table.tolist(), strict=True):
            if point_in_polygon(row[_X], row[_Y], self.box):
                return int(tid)
        return -1
