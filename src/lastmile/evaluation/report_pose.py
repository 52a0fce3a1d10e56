"""The report's localization-error and cross-track-error section: a plot over time and a summary table."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure
from matplotlib.patches import Patch

from lastmile.evaluation.pose_errors import BAND_SIGMAS, PoseErrors, source_name, source_spans

POSE_PNG = "localization_error.png"

_SOURCE_COLOURS = {
    "gnss": "#c7e9c0",
    "landmarks": "#c6dbef",
    "dead_reckoning": "#fdd0a2",
    "scan_matching": "#dadaeb",
    "amcl": "#bcbddc",
    "invalid": "#ef3b2c",
}
_DPI = 100


def _shade_sources(ax: Any, spans: list[tuple[float, float, str]]) -> list[Patch]:
    """Shade each position source's spans; one legend patch per source present."""
    by_source: dict[str, list[tuple[float, float]]] = {}
    for start, end, source in spans:
        by_source.setdefault(source, []).append((start, max(end - start, 1e-3)))
    patches = []
    for source, ranges in by_source.items():
        colour = _SOURCE_COLOURS.get(source, "#d9d9d9")
        ax.broken_barh(
            ranges, (0.0, 1.0), transform=ax.get_xaxis_transform(), facecolors=colour, alpha=0.6, zorder=0
        )
        patches.append(Patch(facecolor=colour, alpha=0.6, label=f"pose held by {source}"))
    return patches


def plot_pose_errors(errors: PoseErrors, path: Path) -> bool:
    """Localization error (along, lateral, total) with the stack's band, and the cross-track errors,
    over time with the position sources shaded. False (nothing written) when the log has no rows."""
    if len(errors) == 0:
        return False
    fig = Figure(figsize=(11.0, 6.5), dpi=_DPI, layout="constrained")
    ax_e, ax_x = fig.subplots(2, 1, sharex=True)
    spans = source_spans(errors)
    patches = _shade_sources(ax_e, spans)
    _shade_sources(ax_x, spans)
    t = errors.t_s
    ax_e.fill_between(
        t, -errors.band_m, errors.band_m, color="#969696", alpha=0.35, lw=0, label=f"±{BAND_SIGMAS} sigma"
    )
    ax_e.plot(t, errors.along_m, color="#08519c", lw=1.0, label="along-track")
    ax_e.plot(t, errors.lateral_m, color="#a50f15", lw=1.0, label="lateral")
    ax_e.plot(t, errors.total_m, color="#252525", lw=0.8, ls=":", label="total")
    ax_e.axhline(0.0, color="k", lw=0.5)
    ax_e.set_ylabel("estimate - truth [m]")
    ax_e.set_title(
        "Localization error of the stack's estimate (band: its reported 1.96-sigma; shading: what held "
        "the pose)",
        fontsize=9,
    )
    handles, _ = ax_e.get_legend_handles_labels()
    ax_e.legend(handles=[*handles, *patches], loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=7)
    ax_x.plot(t, errors.path_d_m, color="#238b45", lw=1.0, label="from the planned path")
    ax_x.plot(t, errors.route_d_m, color="#6a51a3", lw=0.8, alpha=0.8, label="from the route centre line")
    ax_x.axhline(0.0, color="k", lw=0.5)
    ax_x.set_ylabel("true cross-track [m] (left +)")
    ax_x.set_xlabel("time [s]")
    ax_x.set_title("Cross-track error of the true rear axle", fontsize=9)
    ax_x.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=7)
    fig.savefig(path, dpi=_DPI)
    return True


def _stats(values: np.ndarray) -> str:
    a = np.abs(values)
    a = a[np.isfinite(a)]
    if not len(a):
        return "n/a | n/a | n/a"
    p50, p95 = np.percentile(a, [50.0, 95.0])
    return f"{p50:.3f} | {p95:.3f} | {a.max():.3f}"


def pose_error_lines(errors: PoseErrors, has_plot: bool) -> list[str]:
    """Markdown: the plot and |error| p50 / p95 / max per quantity, and per position source."""
    if len(errors) == 0:
        return ["No localization estimates in the run log.", ""]
    valid = errors.valid
    lines = [
        *([f"![localization and cross-track error over time]({POSE_PNG})", ""] if has_plot else []),
        f"{int(valid.sum())} of {len(errors)} estimates valid (one per planning cycle).",
        "",
        "| absolute error [m] | p50 | p95 | max |",
        "|---|---:|---:|---:|",
        f"| localization, total | {_stats(errors.total_m)} |",
        f"| localization, along-track | {_stats(errors.along_m)} |",
        f"| localization, lateral | {_stats(errors.lateral_m)} |",
        f"| cross-track from the planned path | {_stats(errors.path_d_m)} |",
        f"| cross-track from the route centre line, in lane | {_stats(errors.route_d_m[errors.in_lane])} |",
        f"| cross-track from the route centre line, all | {_stats(errors.route_d_m)} |",
        "",
        "| pose held by | estimates | total error p95 [m] | reported 1.96-sigma p95 [m] |",
        "|---|---:|---:|---:|",
    ]
    for code in sorted(set(errors.source_code.tolist())):
        rows = errors.source_code == code
        name = source_name(int(code))
        total_p95 = _stats(errors.total_m[rows]).split(" | ")[1]
        band_p95 = _stats(errors.band_m[rows]).split(" | ")[1]
        lines.append(f"| {name} | {int(rows.sum())} | {total_p95} | {band_p95} |")
    return [*lines, ""]
