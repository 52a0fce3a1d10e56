"""The V2I experiment's figure and report, after NUS's Fig. 12: cumulative time gained against laps.

Takes the experiment's numbers as plain data (it never runs the simulator).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt


def write_v2i_report(result: dict[str, Any], out_dir: Path) -> Path:
    """``result``: {"laps", "rate_hz", "seeds", "rows": [{"speed_mps", "vehicles", "cumulative_gain_s",
    "mean_lap_base_s", "mean_lap_infra_s"}, ...]}. Writes fig12.png and report.md; returns the report."""
    out_dir.mkdir(parents=True, exist_ok=True)
    rows = result["rows"]
    laps = list(range(1, result["laps"] + 1))
    fig, (ax_a, ax_b) = plt.subplots(1, 2, figsize=(11, 4.2))
    singles = [r for r in rows if r["vehicles"] == 1]
    for r in singles:
        ax_a.plot(laps, r["cumulative_gain_s"], marker=".", label=f"{r['speed_mps']:g} m/s")
    ax_a.set_title("(a) one vehicle")
    fastest = max(r["speed_mps"] for r in rows)
    for r in (r for r in rows if r["speed_mps"] == fastest):
        ax_b.plot(laps, r["cumulative_gain_s"], marker=".", label=f"{r['vehicles']} vehicles")
    ax_b.set_title(f"(b) several vehicles at {fastest:g} m/s")
    for ax in (ax_a, ax_b):
        ax.set_xlabel("laps")
        ax.set_ylabel("cumulative T_gain per vehicle (s)")
        ax.grid(alpha=0.3)
        ax.legend()
    fig.suptitle(f"Time gained with a crossing camera broadcasting at {result['rate_hz']:g} Hz")
    fig.tight_layout()
    fig.savefig(out_dir / "fig12.png", dpi=100)
    plt.close(fig)
    lines = [
        "# V2I experiment (NUS, section V)",
        "",
        f"Crossing camera at {result['rate_hz']:g} Hz; pedestrians arrive as a Poisson process of "
        f"1 per second; {result['laps']} laps; mean over seeds {list(result['seeds'])}.",
        "",
        "![cumulative time gained](fig12.png)",
        "",
        "| speed (m/s) | vehicles | mean lap, baseline (s) | mean lap, with camera (s) | "
        f"T_gain after {result['laps']} laps, per vehicle (s) |",
        "|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        lines.append(
            f"| {r['speed_mps']:g} | {r['vehicles']} | {r['mean_lap_base_s']:.2f} | "
            f"{r['mean_lap_infra_s']:.2f} | {r['cumulative_gain_s'][-1]:.1f} |"
        )
    path = out_dir / "report.md"
    path.write_text("\n".join(lines) + "\n")
    return path
