"""Collecting a run log while the loop runs (the format and its reader are in ``run_log.py``)."""

from __future__ import annotations

import math
from array import array
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

from lastmile.core.run_events import EventKind
from lastmile.recorder.run_localization import (
    LOCALIZATION_COLUMNS,
    RunLocalization,
    RunLocalizationError,
)
from lastmile.recorder.run_log import (
    EGO_COLUMNS,
    RunAgents,
    RunEvent,
    RunLog,
    RunLogError,
    RunMeta,
    json_clean,
    make_event,
)


class RunLogWriter:
    """Collects a run while the loop runs; cheap enough for 50 Hz rows over hours of simulated time.

    Ego rows go into one flat ``array('d')`` (72 bytes a row, no per-row NumPy object); checks that
    need the whole trace (finiteness, state codes) run once in :meth:`finish`.
    """

    def __init__(self, meta: RunMeta) -> None:
        if not isinstance(meta, RunMeta):
            raise RunLogError(f"RunLogWriter: expected a RunMeta, got {type(meta).__name__}")
        self.meta = meta
        self._ego = array("d")
        self._last_t_s = -math.inf
        self._agent_t: list[np.ndarray] = []
        self._agent_ids: list[np.ndarray] = []
        self._agent_xy: list[np.ndarray] = []
        self._localization = array("d")
        self._events: list[RunEvent] = []
        self._timing: dict[str, Any] = {}
        self._finished = False

    @property
    def rows(self) -> int:
        return len(self._ego) // len(EGO_COLUMNS)

    def _check_open(self) -> None:
        if self._finished:
            raise RunLogError("RunLogWriter: expected an open writer, got one that finish() already closed")

    def add_ego_row(
        self,
        t_s: float,
        x_m: float,
        y_m: float,
        yaw_rad: float,
        speed_mps: float,
        accel_mps2: float,
        steer_front_rad: float,
        state_code: int,
        route_s_m: float,
    ) -> None:
        """Append one ego sample (units in the names; see the module docstring for conventions)."""
        # One comparison per row catches a loop that repeats or rewinds time (NaN fails it too).
        if not t_s > self._last_t_s or self._finished:
            self._check_open()
            raise RunLogError(f"RunLogWriter.add_ego_row: expected t_s > {self._last_t_s}, got {t_s!r}")
        self._last_t_s = t_s
        self._ego.extend(
            (t_s, x_m, y_m, yaw_rad, speed_mps, accel_mps2, steer_front_rad, state_code, route_s_m)
        )

    def add_localization_row(
        self,
        t_s: float,
        est_x_m: float,
        est_y_m: float,
        est_yaw_rad: float,
        pos_std_m: float,
        yaw_std_rad: float,
        source_code: int,
        true_x_m: float,
        true_y_m: float,
        true_yaw_rad: float,
        route_d_m: float,
        path_d_m: float,
    ) -> None:
        """Append one localization row (columns and conventions in ``run_localization.py``); the rows
        are checked once in :meth:`finish`, like the ego trace."""
        self._check_open()
        self._localization.extend(
            (
                t_s,
                est_x_m,
                est_y_m,
                est_yaw_rad,
                pos_std_m,
                yaw_std_rad,
                source_code,
                true_x_m,
                true_y_m,
                true_yaw_rad,
                route_d_m,
                path_d_m,
            )
        )

    def add_agent_rows(self, t_s: float, ids: Sequence[int] | npt.ArrayLike, xy: npt.ArrayLike) -> None:
        """Append the positions of several agents at one time.

        Args:
            t_s: simulated time.
            ids: (K,) integer agent ids.
            xy: (K, 2) map positions in metres.
        """
        self._check_open()
        id_arr = np.asarray(ids, dtype=np.int64).reshape(-1)
        xy_arr = np.asarray(xy, dtype=np.float32)
        if xy_arr.size == 0:
            xy_arr = xy_arr.reshape(0, 2)
        if xy_arr.ndim != 2 or xy_arr.shape != (len(id_arr), 2):
            raise RunLogError(
                f"RunLogWriter.add_agent_rows: expected xy of shape ({len(id_arr)}, 2), got {xy_arr.shape}"
            )
        if not (math.isfinite(t_s) and np.all(np.isfinite(xy_arr))):
            raise RunLogError("RunLogWriter.add_agent_rows: expected finite t_s and xy, got NaN or inf")
        self._agent_t.append(np.full(len(id_arr), float(t_s)))
        self._agent_ids.append(id_arr)
        self._agent_xy.append(xy_arr)

    def add_event(self, t_s: float, kind: EventKind, /, **data: Any) -> None:
        """Append an event; known kinds (:data:`EVENT_SCHEMAS`) must carry their fields.

        ``state_change`` has a field named ``from``: pass it as ``**{"from": ..., "to": ...}``.
        """
        self._check_open()
        self._events.append(make_event(t_s, kind, data, "RunLogWriter.add_event"))

    def add_events(self, events: Iterable[tuple[float, EventKind, Mapping[str, Any]]]) -> None:
        """Append ``(t_s, kind, data)`` triples, the form the simulator's referee collects."""
        self._check_open()
        for t_s, kind, data in events:
            self._events.append(make_event(t_s, kind, data, "RunLogWriter.add_events"))

    def set_timing(self, timing: Mapping[str, Any]) -> None:
        """Wall-clock figures, e.g. ``{"modules": {name: {"p50_ms", "p95_ms", "max_ms", "calls"}},
        "realtime_factor": float}``; shown in reports, never in metrics."""
        self._check_open()
        self._timing = json_clean(dict(timing), "RunLogWriter.set_timing")

    def finish(self) -> RunLog:
        """Close the writer and return the checked, read-only :class:`RunLog`."""
        self._check_open()
        self._finished = True
        ego = np.frombuffer(self._ego, dtype=np.float64).reshape(-1, len(EGO_COLUMNS)).copy()
        if self._agent_t:
            agents = RunAgents(
                t_s=np.concatenate(self._agent_t),
                agent_id=np.concatenate(self._agent_ids),
                xy_m=np.concatenate(self._agent_xy),
            )
        else:
            agents = RunAgents.empty()
        if len(agents) > 1 and np.any(np.diff(agents.t_s) < 0.0):
            raise RunLogError("RunLogWriter.finish: expected agent rows in time order, got times going back")
        rows = np.frombuffer(self._localization, dtype=np.float64).reshape(-1, len(LOCALIZATION_COLUMNS))
        try:
            localization = RunLocalization(rows.copy(), "RunLogWriter.finish: localization")
        except RunLocalizationError as exc:
            raise RunLogError(str(exc)) from None
        return RunLog(
            meta=self.meta,
            ego=ego,
            events=tuple(self._events),
            agents=agents,
            localization=localization,
            timing=self._timing,
        )
