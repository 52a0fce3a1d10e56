"""Hand-made run logs with known answers for the evaluation tests."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from lastmile.recorder.run_log import RunLog, RunMeta
from lastmile.recorder.run_log_writer import RunLogWriter

TICK_S = 0.02


def make_log(
    speed_mps: np.ndarray,
    accel_mps2: np.ndarray | None = None,
    *,
    x_m: np.ndarray | None = None,
    y_m: np.ndarray | None = None,
    state: np.ndarray | int = 0,
    events: Sequence[tuple[float, str, dict[str, Any]]] = (),
    config: dict[str, Any] | None = None,
    seed: int = 1,
    tick_s: float = TICK_S,
    agents: bool = False,
) -> RunLog:
    """A 50 Hz log along the x axis; x integrates speed unless given; t_s = i * tick_s."""
    n = len(speed_mps)
    t = np.arange(n) * tick_s
    accel = np.zeros(n) if accel_mps2 is None else accel_mps2
    if x_m is None:
        x_m = np.concatenate([[0.0], np.cumsum(0.5 * (speed_mps[1:] + speed_mps[:-1]) * tick_s)])
    y = np.zeros(n) if y_m is None else y_m
    states = np.broadcast_to(np.asarray(state), (n,))
    meta = RunMeta(
        seed=seed,
        weather="clear",
        perception_mode="oracle",
        scenario_name="synthetic",
        map_name="straight",
        tick_s=0.01,
        duration_s=float(n * tick_s),
        config=config or {},
    )
    w = RunLogWriter(meta)
    for i in range(n):
        w.add_ego_row(
            float(t[i]),
            float(x_m[i]),
            float(y[i]),
            0.0,
            float(speed_mps[i]),
            float(accel[i]),
            0.0,
            int(states[i]),
            float(x_m[i]),
        )
        if agents and i % 25 == 0:
            w.add_agent_rows(float(t[i]), [1, 2], [[x_m[i] + 10.0, 3.0], [x_m[i] - 5.0, -3.0]])
    for t_s, kind, data in events:
        w.add_event(t_s, kind, **data)
    return w.finish()
