"""The run log: the ego trace, sparse agent positions and the referee's events of one closed-loop run.

The runner fills a ``run_log_writer.RunLogWriter`` while the loop runs and calls its ``finish``; the
evaluation reads the resulting :class:`RunLog` (in memory or from a run directory via
:meth:`RunLog.load`). The log holds only simulated quantities, so it is a pure function of the seed and the
configuration; wall-clock figures live apart in ``timing`` and never enter the metrics.

Ego trace: ``ego`` is an (N, 9) float64 array with the columns of :data:`EGO_COLUMNS`:

============== ======================================================================================
t_s            simulated time, strictly increasing
x_m, y_m       rear-axle position in the map frame (x east, y north)
yaw_rad        heading, counter-clockwise from the map x axis
speed_mps      longitudinal speed (negative when reversing)
accel_mps2     longitudinal acceleration (negative when braking)
steer_front_rad front-wheel steering angle, positive to the left (NaN when unknown)
state_code     index into :data:`STATE_NAMES` (-1 when unknown)
route_s_m      arc length along the service route (NaN when unknown)
============== ======================================================================================

Event kinds written by the simulator (``data`` fields; extra fields are allowed and kept). Kinds outside
this table are accepted with any JSON-able data, so new sources can log without a schema change.

- ``collision`` {agent_id: int, agent_class: str, at_fault: bool, ego_speed_mps: float}
- ``takeover`` {reason: str} with reason "imminent_collision" | "left_drivable_area" | "stall" |
  "stack_request"
- ``rule_violation`` {rule: str, detail: str} with rule "stop_line" | "right_of_way" | "speed_limit" |
  "drivable_area" | "crosswalk_yield"
- ``stop_served`` {stop_id: str, curb_gap_m: float (the door, on the shuttle's right side, to the curb
  when stopped), body_gap_m: float, optional (the least gap of the whole right side; < 0: over the curb
  line; logs before it lack it), longitudinal_error_m: float, boarded: int, alighted: int}, logged as the
  door closes; runs since issue #21 add left_waiting: int (riders still waiting at the stop then) and
  seats_free: int
- ``stop_missed`` {stop_id: str, waiting: int}
- ``passenger_boarded`` {passenger_id: int, stop_id: str, wait_s: float}
- ``passenger_alighted`` {passenger_id: int, stop_id: str, ride_s: float}
- ``state_change`` {from: str, to: str, reason: str}
- ``emergency_stop`` {reason: str}
- ``hmi`` {screen: str ("front" | "rear" | "inside"), text: str, sound: str, light: str (autonomy-state
  light colour), cue: str (the announced behaviour, e.g. "yielding_pedestrian", "takeover_requested")}
- ``min_ttc`` {ttc_s: float, agent_id: int}, logged when time-to-collision drops below 3 s
- ``intersection_entry`` {order_ok: bool, ...}
- ``loop_completed`` {loop: int}

Files in a run directory: ``run_log.json`` (format tag, meta, events, timing), ``ego.npz`` (array
``ego``), ``agents.npz`` (arrays ``t_s``, ``agent_id``, ``xy_m``) and ``localization.npz`` (array
``localization``, the stack's estimate per planning cycle: ``run_localization.py``; run directories
written before it existed read as an empty table).
"""

from __future__ import annotations

import json
import math
import os
import zipfile
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from lastmile.core.errors import LastmileError
from lastmile.core.run_events import EventKind
from lastmile.recorder.run_localization import RunLocalization, RunLocalizationError

EGO_COLUMNS = (
    "t_s",
    "x_m",
    "y_m",
    "yaw_rad",
    "speed_mps",
    "accel_mps2",
    "steer_front_rad",
    "state_code",
    "route_s_m",
)
"""Column names of :attr:`RunLog.ego`, in order."""

EGO_INDEX = {name: i for i, name in enumerate(EGO_COLUMNS)}
"""Column index by name."""

STATE_NAMES = ("normal_driving", "intersection", "pullover", "onboarding", "merging", "emergency_stop")
"""Behaviour states by ``state_code`` (the values of ``core.vehicle_messages.BehaviourState``)."""

UNKNOWN_STATE = -1

# Columns that may hold NaN ("not known"); everything else in a row must be finite.
_NULLABLE_COLUMNS = ("steer_front_rad", "route_s_m")

RUN_LOG_FILE = "run_log.json"
EGO_FILE = "ego.npz"
AGENTS_FILE = "agents.npz"
LOCALIZATION_FILE = "localization.npz"
FORMAT_TAG = "lastmile.run_log"
FORMAT_VERSION = 1

EVENT_SCHEMAS: dict[EventKind, dict[str, str]] = {
    EventKind.COLLISION: {
        "agent_id": "int",
        "agent_class": "str",
        "at_fault": "bool",
        "ego_speed_mps": "float",
    },
    EventKind.TAKEOVER: {"reason": "str"},
    EventKind.RULE_VIOLATION: {"rule": "str", "detail": "str"},
    EventKind.STOP_SERVED: {
        "stop_id": "str",
        "curb_gap_m": "float",
        "longitudinal_error_m": "float",
        "boarded": "int",
        "alighted": "int",
    },
    EventKind.STOP_MISSED: {"stop_id": "str", "waiting": "int"},
    EventKind.PASSENGER_BOARDED: {"passenger_id": "int", "stop_id": "str", "wait_s": "float"},
    EventKind.PASSENGER_ALIGHTED: {"passenger_id": "int", "stop_id": "str", "ride_s": "float"},
    EventKind.DROP_OFF_REQUESTED: {"passenger_id": "int", "route_s_m": "float"},
    EventKind.DROP_OFF_SERVED: {
        "passenger_id": "int",
        "stop_id": "str",
        "curb_gap_m": "float",
        "body_gap_m": "float",
        "wait_s": "float",
        "route_s_m": "float",
    },
    EventKind.STATE_CHANGE: {"from": "str", "to": "str", "reason": "str"},
    EventKind.EMERGENCY_STOP: {"reason": "str"},
    EventKind.HMI: {"screen": "str", "text": "str", "sound": "str", "light": "str", "cue": "str"},
    EventKind.MIN_TTC: {"ttc_s": "float", "agent_id": "int"},
    EventKind.INTERSECTION_ENTRY: {"order_ok": "bool"},
    EventKind.GIVE_WAY_ENTRY: {
        "stop_line_id": "int",
        "line_kind": "str",
        "stopped_before": "bool",
        "stood_s": "float",
    },
    EventKind.LOOP_COMPLETED: {"loop": "int"},
    EventKind.ROAD_USER: {"agent_id": "int", "agent_class": "str"},
    EventKind.FAULT_START: {"kind": "str", "target": "str"},
    EventKind.FAULT_END: {"kind": "str", "target": "str"},
    EventKind.STACK_CRASH: {"error": "str"},
    EventKind.SAFETY: {"level": "str", "mrm": "str", "reason": "str"},
    EventKind.LOCALIZATION: {"source": "str", "gnss": "str", "pos_std_m": "float"},
    EventKind.HARDWARE_WATCHDOG: {"reason": "str"},
    EventKind.OPERATOR_ESTOP: {"state": "str"},
    EventKind.OPERATOR_RELEASE: {"state": "str"},
    EventKind.RECORDING: {"path": "str", "trigger": "str"},
}
"""Required ``data`` fields (name -> "int" | "float" | "bool" | "str") of the known event kinds."""

TAKEOVER_REASONS = ("imminent_collision", "left_drivable_area", "stall", "stack_request")
RULES = ("stop_line", "right_of_way", "speed_limit", "drivable_area", "crosswalk_yield")


class RunLogError(LastmileError):
    """A run log (in memory or on disk) is malformed, incomplete or unreadable."""


def _numpy_default(value: Any) -> Any:
    # NumPy scalars and arrays sneak in from the simulator; JSON wants plain Python values.
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(f"{type(value).__name__} {value!r} is not JSON-able")


def json_clean(value: Any, where: str) -> Any:
    """``value`` as it will read back from JSON (tuples become lists, NumPy scalars plain numbers)."""
    try:
        text = json.dumps(value, allow_nan=False, default=_numpy_default)
    except (TypeError, ValueError) as exc:
        raise RunLogError(
            f"{where}: expected JSON-able data (str, finite numbers, bool, None, lists, str-keyed dicts), "
            f"got {exc}"
        ) from None
    return json.loads(text)


def _type_ok(kind: str, value: Any) -> bool:
    if kind == "bool":
        return isinstance(value, bool)
    if kind == "int":
        return isinstance(value, int) and not isinstance(value, bool)
    if kind == "float":
        return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)
    return isinstance(value, str)


def check_event(kind: str, data: Mapping[str, Any], where: str) -> None:
    """Check the required fields of a known event kind.

    Raises:
        RunLogError: naming the event, the field, the expected type and what arrived.
    """
    if not isinstance(kind, str) or not kind:
        raise RunLogError(f"{where}: expected a non-empty event kind string, got {kind!r}")
    known = kind in EventKind.__members__.values()
    for name, expected in (EVENT_SCHEMAS.get(EventKind(kind), {}) if known else {}).items():
        if name not in data:
            raise RunLogError(f"{where}: {kind} event expected field {name!r} ({expected}), got {dict(data)}")
        if not _type_ok(expected, data[name]):
            raise RunLogError(f"{where}: {kind}.{name} expected {expected}, got {data[name]!r}")


@dataclass(frozen=True, kw_only=True)
class RunMeta:
    """What produced a run: seed, conditions, scenario and a JSON-able echo of the configuration.

    Attributes:
        seed: the root seed of the run.
        weather: weather preset name ("clear", "rain", "snow", ...).
        perception_mode: which perception produced the run ("sensors", "oracle", ...); every report
            states it because oracle runs are ablations, not results.
        scenario_name, map_name: names for reports.
        tick_s: base period of the loop, > 0.
        duration_s: simulated duration asked for, >= 0 (the trace may end earlier).
        config: JSON-able echo of scenario and configuration; evaluation reads the optional keys
            ``expected_distance_m``, ``speed_limit_mps``, ``speed_tolerance_mps`` and ``speed_hold_s``.
    """

    seed: int
    weather: str
    perception_mode: str
    scenario_name: str
    map_name: str
    tick_s: float
    duration_s: float
    config: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if isinstance(self.seed, bool) or not isinstance(self.seed, int | np.integer):
            raise RunLogError(f"RunMeta.seed: expected an integer, got {self.seed!r}")
        object.__setattr__(self, "seed", int(self.seed))
        for name in ("weather", "perception_mode", "scenario_name", "map_name"):
            value = getattr(self, name)
            if not isinstance(value, str):
                raise RunLogError(f"RunMeta.{name}: expected a string, got {value!r}")
        for name, low in (("tick_s", 0.0), ("duration_s", 0.0)):
            value = getattr(self, name)
            ok = isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)
            if not ok or value < low or (name == "tick_s" and value == 0.0):
                bound = "> 0" if name == "tick_s" else ">= 0"
                raise RunLogError(f"RunMeta.{name}: expected a finite number {bound}, got {value!r}")
            object.__setattr__(self, name, float(value))
        if not isinstance(self.config, dict):
            raise RunLogError(f"RunMeta.config: expected a dict, got {type(self.config).__name__}")
        object.__setattr__(self, "config", json_clean(self.config, "RunMeta.config"))

    def to_json(self) -> dict[str, Any]:
        return {
            "seed": self.seed,
            "weather": self.weather,
            "perception_mode": self.perception_mode,
            "scenario_name": self.scenario_name,
            "map_name": self.map_name,
            "tick_s": self.tick_s,
            "duration_s": self.duration_s,
            "config": self.config,
        }


@dataclass(frozen=True, kw_only=True)
class RunEvent:
    """Something the referee, the operator model or the stack reported at simulated time ``t_s``."""

    t_s: float
    kind: str
    data: dict[str, Any]

    def to_json(self) -> dict[str, Any]:
        return {"t_s": self.t_s, "kind": self.kind, "data": self.data}


def make_event(t_s: float, kind: str, data: Mapping[str, Any], where: str) -> RunEvent:
    """A checked event: a finite time, a known kind's fields (``where`` names the caller in errors)."""
    if isinstance(t_s, bool) or not isinstance(t_s, int | float | np.floating | np.integer):
        raise RunLogError(f"{where}: expected a time in seconds, got {t_s!r}")
    if not math.isfinite(float(t_s)):
        raise RunLogError(f"{where}: expected a finite time, got {t_s!r}")
    clean = json_clean(dict(data), f"{where} ({kind})")
    check_event(kind, clean, where)
    return RunEvent(t_s=float(t_s), kind=kind, data=clean)


@dataclass(frozen=True, eq=False)
class RunAgents:
    """Sparse positions of other road users for plots (struct of arrays, one row per agent sample).

    Attributes:
        t_s: (M,) float64 simulated times, non-decreasing.
        agent_id: (M,) int64 agent ids.
        xy_m: (M, 2) float32 map positions; float32 keeps the table small and is still better than 1 mm
            within 8 km of the map origin, which is plenty for plots.
    """

    t_s: np.ndarray
    agent_id: np.ndarray
    xy_m: np.ndarray

    def __post_init__(self) -> None:
        t = np.array(self.t_s, dtype=np.float64).reshape(-1)
        ids = np.array(self.agent_id, dtype=np.int64).reshape(-1)
        xy = np.array(self.xy_m, dtype=np.float32)
        if xy.size == 0:
            xy = xy.reshape(0, 2)
        if xy.ndim != 2 or xy.shape[1] != 2 or not (len(t) == len(ids) == len(xy)):
            raise RunLogError(
                f"RunAgents: expected t_s (M,), agent_id (M,), xy_m (M, 2) of one length, got "
                f"{t.shape}, {ids.shape}, {xy.shape}"
            )
        if not (np.all(np.isfinite(t)) and np.all(np.isfinite(xy))):
            raise RunLogError("RunAgents: expected finite times and positions, got NaN or inf")
        for name, arr in (("t_s", t), ("agent_id", ids), ("xy_m", xy)):
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)

    @classmethod
    def empty(cls) -> RunAgents:
        return cls(t_s=np.zeros(0), agent_id=np.zeros(0, dtype=np.int64), xy_m=np.zeros((0, 2)))

    def __len__(self) -> int:
        return len(self.t_s)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, RunAgents):
            return NotImplemented
        return (
            np.array_equal(self.t_s, other.t_s)
            and np.array_equal(self.agent_id, other.agent_id)
            and np.array_equal(self.xy_m, other.xy_m)
        )

    __hash__ = None  # type: ignore[assignment]


def _check_ego(ego: np.ndarray, where: str) -> np.ndarray:
    arr = np.array(ego, dtype=np.float64)
    if arr.size == 0:
        arr = arr.reshape(0, len(EGO_COLUMNS))
    if arr.ndim != 2 or arr.shape[1] != len(EGO_COLUMNS):
        raise RunLogError(f"{where}: expected an (N, {len(EGO_COLUMNS)}) ego array, got shape {arr.shape}")
    for i, name in enumerate(EGO_COLUMNS):
        bad = np.isinf(arr[:, i]) if name in _NULLABLE_COLUMNS else ~np.isfinite(arr[:, i])
        if np.any(bad):
            row = int(np.argmax(bad))
            raise RunLogError(f"{where}: expected finite {name}, got {arr[row, i]} in row {row}")
    if len(arr) > 1 and not np.all(np.diff(arr[:, 0]) > 0.0):
        row = int(np.argmax(np.diff(arr[:, 0]) <= 0.0)) + 1
        raise RunLogError(
            f"{where}: expected strictly increasing t_s, got {arr[row, 0]} after {arr[row - 1, 0]} "
            f"in row {row}"
        )
    codes = arr[:, EGO_INDEX["state_code"]]
    bad = (codes != np.round(codes)) | (codes < UNKNOWN_STATE) | (codes >= len(STATE_NAMES))
    if np.any(bad):
        row = int(np.argmax(bad))
        raise RunLogError(
            f"{where}: expected state_code an integer in [-1, {len(STATE_NAMES) - 1}], got {codes[row]} "
            f"in row {row}"
        )
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True, eq=False, kw_only=True)
class RunLog:
    """One run: meta, the ego trace, events, sparse agents and wall-clock timing.

    Attributes:
        meta: what produced the run.
        ego: (N, 9) float64, read-only, columns :data:`EGO_COLUMNS`, strictly increasing ``t_s``.
        events: in time order (stable for equal times).
        agents: sparse positions of other road users, for plots only.
        localization: the stack's localization estimate per planning cycle and the true pose's
            cross-track errors (``run_localization.py``); empty where the runner logged none.
        timing: wall-clock figures (per-module compute time, real-time factor); reports show them,
            metrics never use them because they differ between identical runs.
    """

    meta: RunMeta
    ego: np.ndarray
    events: tuple[RunEvent, ...] = ()
    agents: RunAgents = field(default_factory=RunAgents.empty)
    localization: RunLocalization = field(default_factory=RunLocalization.empty)
    timing: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        object.__setattr__(self, "ego", _check_ego(self.ego, "RunLog.ego"))
        events = tuple(self.events)
        if any(not isinstance(e, RunEvent) for e in events):
            raise RunLogError("RunLog.events: expected RunEvent items, got another type")
        object.__setattr__(self, "events", tuple(sorted(events, key=lambda e: e.t_s)))
        if not isinstance(self.localization, RunLocalization):
            got = type(self.localization).__name__
            raise RunLogError(f"RunLog.localization: expected a RunLocalization, got {got}")
        object.__setattr__(self, "timing", json_clean(dict(self.timing), "RunLog.timing"))

    def __len__(self) -> int:
        return len(self.ego)

    def column(self, name: str) -> np.ndarray:
        """(N,) read-only view of one ego column, by its name in :data:`EGO_COLUMNS`."""
        if name not in EGO_INDEX:
            raise RunLogError(f"RunLog.column: expected one of {list(EGO_COLUMNS)}, got {name!r}")
        return self.ego[:, EGO_INDEX[name]]

    def events_of(self, *kinds: str) -> tuple[RunEvent, ...]:
        """The events of the given kinds, in time order."""
        wanted = set(kinds)
        return tuple(e for e in self.events if e.kind in wanted)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, RunLog):
            return NotImplemented
        return (
            self.meta == other.meta
            and np.array_equal(self.ego, other.ego, equal_nan=True)
            and self.events == other.events
            and self.agents == other.agents
            and self.localization == other.localization
            and self.timing == other.timing
        )

    __hash__ = None  # type: ignore[assignment]

    # --- files -----------------------------------------------------------------------------
    def save(self, run_dir: str | os.PathLike[str]) -> Path:
        """Write ``run_log.json``, ``ego.npz``, ``agents.npz`` and ``localization.npz`` into ``run_dir``
        (created if needed).

        Returns:
            The path of ``run_log.json``.
        """
        out = Path(run_dir)
        out.mkdir(parents=True, exist_ok=True)
        doc = {
            "format": FORMAT_TAG,
            "version": FORMAT_VERSION,
            "ego_columns": list(EGO_COLUMNS),
            "meta": self.meta.to_json(),
            "events": [e.to_json() for e in self.events],
            "timing": self.timing,
        }
        # Write then rename, so that a sweep killed mid-write never leaves a half file behind.
        _write_atomic(out / RUN_LOG_FILE, json.dumps(doc, indent=1, allow_nan=False).encode())
        _save_npz(out / EGO_FILE, ego=self.ego)
        _save_npz(
            out / AGENTS_FILE, t_s=self.agents.t_s, agent_id=self.agents.agent_id, xy_m=self.agents.xy_m
        )
        _save_npz(out / LOCALIZATION_FILE, localization=self.localization.table)
        return out / RUN_LOG_FILE

    @classmethod
    def load(cls, run_dir: str | os.PathLike[str]) -> RunLog:
        """Read a run directory written by :meth:`save`.

        Raises:
            RunLogError: naming the file that is missing, unreadable or malformed.
        """
        root = Path(run_dir)
        json_path = root / RUN_LOG_FILE
        try:
            doc = json.loads(json_path.read_text(encoding="utf-8"))
        except FileNotFoundError:
            raise RunLogError(f"{json_path}: expected a run log file, got no such file") from None
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise RunLogError(f"{json_path}: expected run log JSON, got unreadable content ({exc})") from None
        if not isinstance(doc, dict) or doc.get("format") != FORMAT_TAG:
            got = doc.get("format") if isinstance(doc, dict) else type(doc).__name__
            raise RunLogError(f"{json_path}: expected format {FORMAT_TAG!r}, got {got!r}")
        if doc.get("version") != FORMAT_VERSION:
            raise RunLogError(f"{json_path}: expected version {FORMAT_VERSION}, got {doc.get('version')!r}")
        if doc.get("ego_columns") != list(EGO_COLUMNS):
            raise RunLogError(
                f"{json_path}: expected ego_columns {list(EGO_COLUMNS)}, got {doc.get('ego_columns')}"
            )
        try:
            meta_doc = doc["meta"]
            events_doc = doc["events"]
            timing = doc.get("timing", {})
        except KeyError as exc:
            raise RunLogError(f"{json_path}: expected key {exc}, got keys {sorted(doc)}") from None
        if not isinstance(meta_doc, dict) or not isinstance(events_doc, list):
            raise RunLogError(f"{json_path}: expected meta as an object and events as a list")
        expected_meta = set(RunMeta.__dataclass_fields__)
        if set(meta_doc) != expected_meta:
            raise RunLogError(
                f"{json_path}: meta expected keys {sorted(expected_meta)}, got {sorted(meta_doc)}"
            )
        try:
            meta = RunMeta(**meta_doc)
        except RunLogError as exc:
            raise RunLogError(f"{json_path}: {exc}") from None
        events = []
        for i, item in enumerate(events_doc):
            where = f"{json_path}: events[{i}]"
            if not isinstance(item, dict) or set(item) != {"t_s", "kind", "data"}:
                raise RunLogError(f"{where}: expected an object with t_s, kind, data, got {item!r}")
            if not isinstance(item["data"], dict):
                raise RunLogError(f"{where}: expected data as an object, got {item['data']!r}")
            events.append(make_event(item["t_s"], item["kind"], item["data"], where))
        ego = _load_npz(root / EGO_FILE, ("ego",))["ego"]
        agents_doc = _load_npz(root / AGENTS_FILE, ("t_s", "agent_id", "xy_m"))
        localization = _load_localization(root / LOCALIZATION_FILE)
        try:
            agents = RunAgents(
                t_s=agents_doc["t_s"], agent_id=agents_doc["agent_id"], xy_m=agents_doc["xy_m"]
            )
            return cls(
                meta=meta,
                ego=_check_ego(ego, str(root / EGO_FILE)),
                events=tuple(events),
                agents=agents,
                localization=localization,
                timing=timing if isinstance(timing, dict) else {},
            )
        except RunLogError as exc:
            raise RunLogError(f"{root}: {exc}") from None


def _write_atomic(path: Path, payload: bytes) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_bytes(payload)
    os.replace(tmp, path)


def _save_npz(path: Path, **arrays: np.ndarray) -> None:
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "wb") as handle:
        np.savez_compressed(handle, **arrays)  # type: ignore[arg-type]
    os.replace(tmp, path)


def _load_npz(path: Path, keys: Sequence[str]) -> dict[str, np.ndarray]:
    try:
        with np.load(path, allow_pickle=False) as data:
            missing = [k for k in keys if k not in data.files]
            if missing:
                raise RunLogError(f"{path}: expected arrays {list(keys)}, got {sorted(data.files)}")
            return {k: np.array(data[k]) for k in keys}
    except FileNotFoundError:
        raise RunLogError(f"{path}: expected an .npz array file, got no such file") from None
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as exc:
        raise RunLogError(f"{path}: expected an .npz array file, got unreadable content ({exc})") from None


def _load_localization(path: Path) -> RunLocalization:
    """The localization table; a run directory written before the table existed has none (empty)."""
    if not path.exists():
        return RunLocalization.empty()
    table = _load_npz(path, ("localization",))["localization"]
    try:
        return RunLocalization(table, str(path))
    except RunLocalizationError as exc:
        raise RunLogError(str(exc)) from None
