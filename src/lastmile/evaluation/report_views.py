"""The report's views of other road users: their tracks, the stops and intersections up close, and the
closest encounters (ego, the other user and the time to collision around it)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from matplotlib.collections import LineCollection, PolyCollection
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

from lastmile.core.run_events import EventKind
from lastmile.recorder import run_log

if TYPE_CHECKING:
    from lastmile.hdmap.model import HDMap

PLACES_PNG = "places.png"
ENCOUNTERS_PNG = "encounters.png"

ENCOUNTER_GAP_S = 2.0
"""``min_ttc`` samples of one road user closer than this in time belong to one encounter."""
ENCOUNTER_WINDOW_S = 6.0
"""An encounter view shows this long before and after its closest moment."""
MAX_ENCOUNTER_VIEWS = 6
"""Encounter panels at most: every collision first, then the closest encounters."""
PLACE_RADIUS_M = 30.0
"""Half the side of a stop's or intersection's inset: a bay, its approach and the crossing beside it."""
MAX_PLACE_VIEWS = 12

CLASS_COLOURS = {
    "car": "#9467bd",
    "pedestrian": "#d62728",
    "cyclist": "#2ca02c",
    "animal": "#8c564b",
    "unknown": "#7f7f7f",
}


@dataclass(frozen=True, slots=True, kw_only=True)
class Encounter:
    """One road user's approach: the run of ``min_ttc`` samples it caused, or a collision.

    Attributes:
        agent_id: the other road user.
        agent_class: its class ("car", "pedestrian", ...; "unknown" if never logged).
        t_start_s, t_end_s: first and last sample.
        t_min_s: when the time to collision was least (the collision's time for one).
        min_ttc_s: the least time to collision (0 for a collision).
        samples: (t_s, ttc_s) of every sample, in time order.
        collision: whether it ended in contact.
    """

    agent_id: int
    agent_class: str
    t_start_s: float
    t_end_s: float
    t_min_s: float
    min_ttc_s: float
    samples: tuple[tuple[float, float], ...]
    collision: bool = False


def road_user_classes(log: run_log.RunLog) -> dict[int, str]:
    """Each logged road user's class, from the ``road_user`` events (and collisions, which name it)."""
    classes = {
        int(e.data["agent_id"]): str(e.data["agent_class"]) for e in log.events_of(EventKind.ROAD_USER)
    }
    for e in log.events_of(EventKind.COLLISION):
        classes.setdefault(int(e.data["agent_id"]), str(e.data["agent_class"]).lower())
    return classes


def encounters(log: run_log.RunLog) -> list[Encounter]:
    """The ``min_ttc`` samples merged per road user and approach (gaps under :data:`ENCOUNTER_GAP_S`),
    and every collision, in time order."""
    classes = road_user_classes(log)
    open_runs: dict[int, list[tuple[float, float]]] = {}
    runs: list[tuple[int, list[tuple[float, float]]]] = []
    for e in log.events_of(EventKind.MIN_TTC):
        agent, sample = int(e.data["agent_id"]), (e.t_s, float(e.data["ttc_s"]))
        current = open_runs.get(agent)
        if current is not None and e.t_s - current[-1][0] <= ENCOUNTER_GAP_S:
            current.append(sample)
        else:
            open_runs[agent] = [sample]
            runs.append((agent, open_runs[agent]))
    out = []
    for agent, samples in runs:
        t_min, ttc_min = min(samples, key=lambda s: s[1])
        out.append(
            Encounter(
                agent_id=agent,
                agent_class=classes.get(agent, "unknown"),
                t_start_s=samples[0][0],
                t_end_s=samples[-1][0],
                t_min_s=t_min,
                min_ttc_s=ttc_min,
                samples=tuple(samples),
            )
        )
    for e in log.events_of(EventKind.COLLISION):
        agent = int(e.data["agent_id"])
        out.append(
            Encounter(
                agent_id=agent,
                agent_class=classes.get(agent, "unknown"),
                t_start_s=e.t_s,
                t_end_s=e.t_s,
                t_min_s=e.t_s,
                min_ttc_s=0.0,
                samples=((e.t_s, 0.0),),
                collision=True,
            )
        )
    return sorted(out, key=lambda enc: enc.t_start_s)


def draw_road_users(ax: Any, log: run_log.RunLog, t_range: tuple[float, float] | None = None) -> list[Line2D]:
    """Each road user's logged track, coloured by class; returns legend handles, one per class drawn."""
    agents = log.agents
    if not len(agents):
        return []
    classes = road_user_classes(log)
    keep = np.ones(len(agents), dtype=bool)
    if t_range is not None:
        keep = (agents.t_s >= t_range[0]) & (agents.t_s <= t_range[1])
    drawn: set[str] = set()
    for agent in np.unique(agents.agent_id[keep]):
        rows = keep & (agents.agent_id == agent)
        xy = agents.xy_m[rows]
        cls = classes.get(int(agent), "unknown")
        colour = CLASS_COLOURS.get(cls, CLASS_COLOURS["unknown"])
        ax.plot(xy[:, 0], xy[:, 1], color=colour, lw=0.9, alpha=0.7, zorder=2)
        ax.plot(*xy[-1], marker=">", color=colour, ms=3, zorder=2)
        drawn.add(cls)
    return [Line2D([], [], color=CLASS_COLOURS.get(c, "#7f7f7f"), lw=1.5, label=c) for c in sorted(drawn)]


def places(hdmap: HDMap) -> list[tuple[str, np.ndarray]]:
    """Every stop and intersection as (label, centre (2,)): the bays by their curb's middle, all-way
    stops by their conflict area, signalised junctions by their stop lines."""
    out = [(f"stop {s.id}", np.asarray(s.curb.xy_m)[len(s.curb.xy_m) // 2]) for s in hdmap.stops]
    out += [
        (f"all-way stop {a.id}", np.asarray(a.conflict_polygon).mean(axis=0)) for a in hdmap.all_way_stops
    ]
    by_signal: dict[int, list[np.ndarray]] = {}
    for line in hdmap.stop_lines:
        if line.signal_id is not None:
            by_signal.setdefault(line.signal_id, []).append(np.asarray(line.line))
    out += [(f"signal {sid}", np.concatenate(lines).mean(axis=0)) for sid, lines in sorted(by_signal.items())]
    return out[:MAX_PLACE_VIEWS]


def draw_hdmap(ax: Any, hdmap: HDMap, *, label_stops: bool = False) -> None:
    """The map under a plot: lane bounds, crosswalks, the stops' curbs (named with ``label_stops``) and
    the stop lines."""
    bounds = [
        xy
        for ll in hdmap.lanelets.values()
        if ll.subtype != "crosswalk"
        for xy in (ll.left.xy_m, ll.right.xy_m)
    ]
    ax.add_collection(LineCollection(bounds, colors="#9a9a9a", linewidths=0.6, zorder=1))
    crosswalks = [np.asarray(cw.polygon) for cw in hdmap.crosswalks]
    if crosswalks:
        ax.add_collection(
            PolyCollection(
                crosswalks, facecolors="none", edgecolors="#606060", hatch="////", linewidths=0.5, zorder=1
            )
        )
    curbs = [stop.curb.xy_m for stop in hdmap.stops]
    if curbs:
        ax.add_collection(LineCollection(curbs, colors="#1f4e79", linewidths=2.5, zorder=2))
    if label_stops:
        for stop in hdmap.stops:
            mid = stop.curb.xy_m[len(stop.curb.xy_m) // 2]
            ax.annotate(
                stop.id, mid, xytext=(4, -10), textcoords="offset points", fontsize=8, color="#1f4e79"
            )
    lines = [np.asarray(s.line) for s in hdmap.stop_lines]
    if lines:
        ax.add_collection(LineCollection(lines, colors="#000000", linewidths=1.5, zorder=2))


def _ego_xy(log: run_log.RunLog, t_range: tuple[float, float] | None = None) -> np.ndarray:
    t = log.column("t_s")
    keep = np.ones(len(t), dtype=bool) if t_range is None else (t >= t_range[0]) & (t <= t_range[1])
    return np.c_[log.column("x_m")[keep], log.column("y_m")[keep]]


def plot_places(log: run_log.RunLog, hdmap: HDMap, path: Path) -> bool:
    """A grid of insets, one per stop and intersection: the map, the driven path and the road users'
    tracks within :data:`PLACE_RADIUS_M`. Returns False (and writes nothing) for a map without any."""
    spots = places(hdmap)
    if not spots:
        return False
    cols = min(4, len(spots))
    rows = -(-len(spots) // cols)
    fig = Figure(figsize=(3.2 * cols, 3.2 * rows), dpi=100, layout="constrained")
    axes = np.atleast_1d(fig.subplots(rows, cols)).ravel()
    ego = _ego_xy(log)
    handles: list[Line2D] = []
    for ax, (label, centre) in zip(axes, spots, strict=False):
        draw_hdmap(ax, hdmap)
        if len(ego):
            ax.plot(ego[:, 0], ego[:, 1], color="#08519c", lw=1.2, zorder=3)
        handles = draw_road_users(ax, log) or handles
        ax.set_xlim(centre[0] - PLACE_RADIUS_M, centre[0] + PLACE_RADIUS_M)
        ax.set_ylim(centre[1] - PLACE_RADIUS_M, centre[1] + PLACE_RADIUS_M)
        ax.set_aspect("equal", adjustable="box")
        ax.set_title(label, fontsize=9)
        ax.tick_params(labelsize=6)
    for ax in axes[len(spots) :]:
        ax.set_axis_off()
    ego_handle = Line2D([], [], color="#08519c", lw=1.5, label="shuttle")
    fig.legend(handles=[ego_handle, *handles], loc="outside lower center", ncols=6, fontsize=7)
    fig.savefig(path)
    return True


def closest(found: Sequence[Encounter]) -> list[Encounter]:
    """Every collision, then the closest approaches, :data:`MAX_ENCOUNTER_VIEWS` at most, in time order."""
    ranked = sorted(found, key=lambda e: (not e.collision, e.min_ttc_s))
    return sorted(ranked[:MAX_ENCOUNTER_VIEWS], key=lambda e: e.t_min_s)


def plot_encounters(
    log: run_log.RunLog, hdmap: HDMap | None, chosen: Sequence[Encounter], path: Path
) -> bool:
    """Per encounter, the scene from above (ego path and the other user's track around the closest
    moment, both marked at it) over its time-to-collision samples. False (nothing written) if none."""
    if not chosen or len(log) < 2:
        return False
    fig = Figure(figsize=(3.4 * len(chosen), 6.4), dpi=100, layout="constrained")
    axes = fig.subplots(2, len(chosen), squeeze=False, height_ratios=(2.2, 1.0))
    t = log.column("t_s")
    agents = log.agents
    for k, enc in enumerate(chosen):
        top, bottom = axes[0, k], axes[1, k]
        window = (enc.t_min_s - ENCOUNTER_WINDOW_S, enc.t_min_s + ENCOUNTER_WINDOW_S)
        if hdmap is not None:
            draw_hdmap(top, hdmap)
        ego = _ego_xy(log, window)
        top.plot(ego[:, 0], ego[:, 1], color="#08519c", lw=1.5, zorder=3)
        at = np.array([np.interp(enc.t_min_s, t, log.column(c)) for c in ("x_m", "y_m")])
        top.plot(*at, marker="o", color="#08519c", ms=6, zorder=4)
        colour = CLASS_COLOURS.get(enc.agent_class, CLASS_COLOURS["unknown"])
        rows = (agents.agent_id == enc.agent_id) & (agents.t_s >= window[0]) & (agents.t_s <= window[1])
        centre = at
        if rows.any():
            xy, ts = agents.xy_m[rows], agents.t_s[rows]
            top.plot(xy[:, 0], xy[:, 1], color=colour, lw=1.5, zorder=3)
            other = np.array([np.interp(enc.t_min_s, ts, xy[:, 0]), np.interp(enc.t_min_s, ts, xy[:, 1])])
            top.plot(*other, marker="o", color=colour, ms=6, zorder=4)
            centre = (at + other) / 2.0
        half = 25.0
        top.set_xlim(centre[0] - half, centre[0] + half)
        top.set_ylim(centre[1] - half, centre[1] + half)
        top.set_aspect("equal", adjustable="box")
        what = "collision" if enc.collision else f"min TTC {enc.min_ttc_s:.2f} s"
        top.set_title(f"{enc.agent_class} {enc.agent_id} at {enc.t_min_s:.1f} s\n{what}", fontsize=9)
        top.tick_params(labelsize=6)
        ts_, ttc = np.array(enc.samples).T
        bottom.plot(ts_, ttc, marker=".", color=colour, lw=1.0)
        bottom.set_xlim(*window)
        bottom.set_ylim(bottom=0.0)
        bottom.set_xlabel("time [s]", fontsize=8)
        bottom.set_ylabel("TTC [s]", fontsize=8)
        bottom.tick_params(labelsize=6)
    fig.savefig(path)
    return True
