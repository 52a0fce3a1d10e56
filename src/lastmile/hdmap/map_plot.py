"""A PNG of a map with its service route and stops (matplotlib, no display needed)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from lastmile.hdmap.model import DRIVABLE_SUBTYPES, HDMap
from lastmile.hdmap.service_route import ServiceRoute

MARGIN_M = 30.0  # around the route (or the map) in the picture


def plot_map_check(hdmap: HDMap, route: ServiceRoute | None, path: Path) -> Path:
    """Draw lanelets, curbs, crosswalks, stop lines, signals, landmarks, the route and its stops.

    The view is the route and its surroundings when a route is given, else the whole map.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(10, 10))
    for lid, info in hdmap.lanelets.items():
        if lid < 0:
            continue  # a two-way lanelet's other direction: the same outline
        poly = hdmap.polygon_of(lid)
        colour = "#d9d9d9" if info.subtype in DRIVABLE_SUBTYPES else "#eef3e8"
        ax.fill(poly[:, 0], poly[:, 1], color=colour, lw=0, zorder=1)
    for area in hdmap.areas:
        if area.subtype == "building" and len(area.polygon) >= 3:
            ax.fill(area.polygon[:, 0], area.polygon[:, 1], color="#b5a48c", lw=0, zorder=1)
    for curb in hdmap.curbs:
        ax.plot(curb.xy_m[:, 0], curb.xy_m[:, 1], color="black", lw=0.6, zorder=2)
    for cw in hdmap.crosswalks:
        ax.fill(cw.polygon[:, 0], cw.polygon[:, 1], color="#f2d24b", alpha=0.7, lw=0, zorder=2)
    for sl in hdmap.stop_lines:
        ax.plot(sl.line[:, 0], sl.line[:, 1], color="#c0392b", lw=2.0, zorder=3)
    heads = hdmap.traffic_lights
    if heads:
        ax.plot([h.x_m for h in heads], [h.y_m for h in heads], "^", color="#27ae60", ms=6, zorder=4)
    poles = np.array([lm.xy[0] for lm in hdmap.landmarks if lm.kind == "light_pole"]).reshape(-1, 2)
    signs = np.array([np.asarray(lm.xy).mean(axis=0) for lm in hdmap.landmarks if lm.kind == "sign"])
    if len(poles):
        ax.plot(poles[:, 0], poles[:, 1], ".", color="#555555", ms=3, zorder=3, label="poles")
    if len(signs):
        ax.plot(signs[:, 0], signs[:, 1], "s", color="#2e86c1", ms=3, zorder=3, label="signs")
    title = f"{hdmap.name}"
    if route is not None:
        line = np.vstack([route.polyline.xy_m, route.polyline.xy_m[:1]])
        ax.plot(line[:, 0], line[:, 1], color="#1f5fbf", lw=2.0, zorder=5, label="service route")
        for stop in route.stops:
            x, y, _ = route.polyline.point_at(stop.route_s_m)
            ax.plot([stop.x_m], [stop.y_m], "o", color="#e74c3c", ms=6, zorder=6)
            ax.plot([stop.x_m, x], [stop.y_m, y], color="#e74c3c", lw=0.8, zorder=6)
            ax.annotate(
                stop.name, (stop.x_m, stop.y_m), fontsize=7, xytext=(4, 4), textcoords="offset points"
            )
        lo = route.polyline.xy_m.min(axis=0) - MARGIN_M
        hi = route.polyline.xy_m.max(axis=0) + MARGIN_M
        title += f": {route.name}, {route.length_m:.0f} m, {len(route.stops)} stops"
    else:
        x0, y0, x1, y1 = hdmap.bounds_m
        lo, hi = np.array([x0, y0]) - MARGIN_M, np.array([x1, y1]) + MARGIN_M
    ax.set_xlim(float(lo[0]), float(hi[0]))
    ax.set_ylim(float(lo[1]), float(hi[1]))
    ax.set_aspect("equal")
    ax.set_xlabel("x (m, map frame)")
    ax.set_ylabel("y (m)")
    ax.set_title(title, fontsize=10)
    if ax.get_legend_handles_labels()[0]:
        ax.legend(loc="upper right", fontsize=7)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)
    return path
