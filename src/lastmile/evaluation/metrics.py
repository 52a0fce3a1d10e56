"""Metrics from a run log: Snow Lion's Table 2 set, safety, rules, service and a nuPlan-style score."""

from __future__ import annotations

import json
import math
import os
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType
from typing import Any

import numpy as np

from lastmile.core.errors import ConfigError, LastmileError
from lastmile.evaluation.pose_errors import POSE_METRICS, PoseErrors
from lastmile.evaluation.run_signals import SHUTTLE_COMFORT, SNOW_LION_COMFORT, ComfortLimits, RunSignals
from lastmile.recorder import run_log

MetricValue = float | int | str | None

SPEED_9KPH_MPS = 2.5
"""Snow Lion's "high speed" threshold, 9 km/h."""


TTC_THRESHOLD_S = 0.95
"""Time-to-collision below which the score's TTC term is 0 (nuPlan's value)."""

MIN_PROGRESS_RATIO = 0.2
"""Progress ratio below which the score is halved."""

SCORE_WEIGHTS: Mapping[str, float] = MappingProxyType(
    {"ttc": 5.0, "speed_limit": 4.0, "comfort": 2.0, "progress": 5.0}
)
"""Weights of the score's averaged terms (nuPlan's 5 / 4 / 2 / 5)."""

METRICS_FILE = "metrics.json"
TIMING_FILE = "timing.json"


class MetricsError(LastmileError):
    """A metrics or timing dict cannot be written or read (not JSON-able, missing, garbled)."""


@dataclass(frozen=True, slots=True)
class MetricResult:
    """A metric's value and whether it could be measured (``valid=False`` is written as null)."""

    value: MetricValue
    valid: bool = True


INVALID = MetricResult(None, False)


MetricFn = Callable[[RunSignals], MetricResult]
_REGISTRY: dict[str, MetricFn] = {}
_ONLY_WITH: dict[str, str] = {}
"""Metrics written only when the log holds an event of the given kind (a feature the run exercised)."""


def register_metric(name: str, only_with: str | None = None) -> Callable[[MetricFn], MetricFn]:
    """Decorator adding a metric function under ``name``; names are unique. With ``only_with`` (an event
    kind) the metric is left out of runs whose log has no such event, so adding a feature's metrics
    leaves the metrics of runs that never use it as they were."""

    def add(fn: MetricFn) -> MetricFn:
        if name in _REGISTRY:
            raise ConfigError(f"register_metric: expected a new metric name, got {name!r} twice")
        _REGISTRY[name] = fn
        if only_with is not None:
            _ONLY_WITH[name] = only_with
        return fn

    return add


def metric_names() -> tuple[str, ...]:
    """All registered metric names, in registration order."""
    return tuple(_REGISTRY)


def metric(name: str) -> MetricFn:
    """The metric function registered under ``name``."""
    if name not in _REGISTRY:
        raise ConfigError(f"metric: expected one of {sorted(_REGISTRY)}, got {name!r}")
    return _REGISTRY[name]


def _ok(value: MetricValue) -> MetricResult:
    return MetricResult(value, True)


def _mean(values: list[float]) -> MetricResult:
    return _ok(float(np.mean(values))) if values else INVALID


def _max(values: list[float]) -> MetricResult:
    return _ok(max(values)) if values else INVALID


def _field(sig: RunSignals, kind: str, name: str) -> list[float]:
    return [float(e.data[name]) for e in sig.events(kind)]


def _count(kind: str) -> MetricFn:
    return lambda sig: _ok(len(sig.events(kind)))


# --- run identity ----------------------------------------------------------------------------------
def _meta_field(name: str) -> MetricFn:
    return lambda sig: _ok(getattr(sig.log.meta, name))


for _name in ("seed", "weather", "perception_mode", "scenario_name", "map_name"):
    register_metric(_name)(_meta_field(_name))


# --- Snow Lion's Table 2 -----------------------------------------------------------------------------
@register_metric("duration_s")
def _duration(sig: RunSignals) -> MetricResult:
    return _ok(sig.duration_s)


@register_metric("distance_m")
def _distance(sig: RunSignals) -> MetricResult:
    return _ok(sig.distance_m)


@register_metric("max_speed_mps")
def _max_speed(sig: RunSignals) -> MetricResult:
    return _ok(float(np.max(sig.speed_mps))) if sig.rows else INVALID


@register_metric("mean_speed_mps")
def _mean_speed(sig: RunSignals) -> MetricResult:
    return _ok(sig.distance_m / sig.duration_s) if sig.duration_s > 0.0 else INVALID


@register_metric("share_time_at_or_above_9kph")
def _share_fast(sig: RunSignals) -> MetricResult:
    if sig.duration_s <= 0.0:
        return INVALID
    return _ok(sig.time_where(sig.speed_mps >= SPEED_9KPH_MPS) / sig.duration_s)


@register_metric("min_accel_mps2")
def _min_accel(sig: RunSignals) -> MetricResult:
    return _ok(float(np.min(sig.accel_mps2))) if sig.rows else INVALID


@register_metric("max_accel_mps2")
def _max_accel(sig: RunSignals) -> MetricResult:
    return _ok(float(np.max(sig.accel_mps2))) if sig.rows else INVALID


@register_metric("min_jerk_mps3")
def _min_jerk(sig: RunSignals) -> MetricResult:
    return _ok(float(np.min(sig.jerk_mps3))) if len(sig.jerk_mps3) else INVALID


@register_metric("max_jerk_mps3")
def _max_jerk(sig: RunSignals) -> MetricResult:
    return _ok(float(np.max(sig.jerk_mps3))) if len(sig.jerk_mps3) else INVALID


@register_metric("hard_braking_events")
def _hard_braking(sig: RunSignals) -> MetricResult:
    return _ok(sig.hard_braking_events)


@register_metric("km_per_hard_braking")
def _km_per_braking(sig: RunSignals) -> MetricResult:
    n = sig.hard_braking_events
    return _ok(sig.distance_m / 1000.0 / n) if n else INVALID


@register_metric("km_per_takeover")
def _km_per_takeover(sig: RunSignals) -> MetricResult:
    n = len(sig.events("takeover"))
    return _ok(sig.distance_m / 1000.0 / n) if n else INVALID


# --- safety ------------------------------------------------------------------------------------------
register_metric("collisions_total")(_count("collision"))


@register_metric("collisions_at_fault")
def _at_fault(sig: RunSignals) -> MetricResult:
    return _ok(sum(1 for e in sig.events("collision") if e.data["at_fault"]))


@register_metric("collisions_not_at_fault")
def _not_at_fault(sig: RunSignals) -> MetricResult:
    return _ok(sum(1 for e in sig.events("collision") if not e.data["at_fault"]))


register_metric("takeovers")(_count("takeover"))


def _takeovers_for(reason: str) -> MetricFn:
    return lambda sig: _ok(sum(1 for e in sig.events("takeover") if e.data["reason"] == reason))


for _reason in run_log.TAKEOVER_REASONS:
    register_metric(f"takeovers_{_reason}")(_takeovers_for(_reason))
register_metric("emergency_stops")(_count("emergency_stop"))


@register_metric("min_ttc_s")
def _min_ttc(sig: RunSignals) -> MetricResult:
    return INVALID if sig.min_ttc_s is None else _ok(sig.min_ttc_s)


# --- rules -------------------------------------------------------------------------------------------
register_metric("rule_violations")(_count("rule_violation"))


def _violations_of(rule: str) -> MetricFn:
    return lambda sig: _ok(len(sig.violations(rule)))


for _rule in run_log.RULES:
    register_metric(f"rule_violations_{_rule}")(_violations_of(_rule))


@register_metric("rule_violations_other")
def _other_violations(sig: RunSignals) -> MetricResult:
    return _ok(sum(1 for e in sig.events("rule_violation") if e.data["rule"] not in run_log.RULES))


register_metric("intersection_entries")(_count("intersection_entry"))


@register_metric("intersection_entries_out_of_order")
def _out_of_order(sig: RunSignals) -> MetricResult:
    return _ok(sum(1 for e in sig.events("intersection_entry") if not e.data["order_ok"]))


@register_metric("time_over_speed_limit_s")
def _time_over_limit(sig: RunSignals) -> MetricResult:
    return _ok(sig.time_where(sig.over_limit_rows))


# --- service -----------------------------------------------------------------------------------------
register_metric("stops_served")(_count("stop_served"))
register_metric("stops_missed")(_count("stop_missed"))
register_metric("passengers_served")(_count("passenger_boarded"))
register_metric("passengers_boarded")(_count("passenger_boarded"))
register_metric("passengers_alighted")(_count("passenger_alighted"))
register_metric("mean_wait_s")(lambda sig: _mean(_field(sig, "passenger_boarded", "wait_s")))
register_metric("max_wait_s")(lambda sig: _max(_field(sig, "passenger_boarded", "wait_s")))
register_metric("mean_ride_s")(lambda sig: _mean(_field(sig, "passenger_alighted", "ride_s")))
register_metric("max_ride_s")(lambda sig: _max(_field(sig, "passenger_alighted", "ride_s")))
register_metric("pullover_curb_gap_mean_m")(lambda sig: _mean(_field(sig, "stop_served", "curb_gap_m")))
register_metric("pullover_curb_gap_max_m")(lambda sig: _max(_field(sig, "stop_served", "curb_gap_m")))
register_metric("pullover_longitudinal_error_mean_m")(
    lambda sig: _mean(_field(sig, "stop_served", "longitudinal_error_m"))
)
register_metric("pullover_longitudinal_error_max_m")(
    lambda sig: _max(_field(sig, "stop_served", "longitudinal_error_m"))
)

# Snow Lion's unscheduled drop-off (seat button): only in runs where a rider asked for one.
_DROP = "drop_off_requested"
register_metric("drop_offs_requested", only_with=_DROP)(_count("drop_off_requested"))
register_metric("drop_offs_served", only_with=_DROP)(_count("drop_off_served"))
register_metric("drop_offs_at_kerb", only_with=_DROP)(
    lambda sig: _ok(sum(1 for e in sig.events("drop_off_served") if not e.data["stop_id"]))
)
register_metric("drop_off_curb_gap_max_m", only_with=_DROP)(
    lambda sig: _max(_field(sig, "drop_off_served", "curb_gap_m"))
)
register_metric("drop_off_wait_min_s", only_with=_DROP)(
    lambda sig: (
        _ok(min(_field(sig, "drop_off_served", "wait_s"))) if sig.events("drop_off_served") else INVALID
    )
)


@register_metric("loops_completed")
def _loops(sig: RunSignals) -> MetricResult:
    return _ok(max((int(e.data["loop"]) for e in sig.events("loop_completed")), default=0))


def _time_share_of(code: int) -> MetricFn:
    def share(sig: RunSignals) -> MetricResult:
        if sig.duration_s <= 0.0:
            return INVALID
        return _ok(sig.time_where(sig.state == code) / sig.duration_s)

    return share


for _code, _state in enumerate(run_log.STATE_NAMES):
    register_metric(f"time_share_{_state}")(_time_share_of(_code))


# --- closed-loop score -------------------------------------------------------------------------------
@register_metric("progress_ratio")
def _progress_ratio(sig: RunSignals) -> MetricResult:
    return _ok(sig.progress_ratio)


@register_metric("ttc_compliant")
def _ttc_compliant(sig: RunSignals) -> MetricResult:
    return _ok(int(sig.min_ttc_s is None or sig.min_ttc_s >= TTC_THRESHOLD_S))


@register_metric("speed_limit_compliance")
def _speed_compliance(sig: RunSignals) -> MetricResult:
    if sig.duration_s <= 0.0:
        return INVALID
    return _ok(1.0 - sig.time_where(sig.over_limit_rows) / sig.duration_s)


@register_metric("comfort_compliant")
def _comfort_compliant(sig: RunSignals) -> MetricResult:
    return _ok(int(sig.comfort_compliant)) if sig.rows else INVALID


@register_metric("comfort_violation")
def _comfort_violation(sig: RunSignals) -> MetricResult:
    """Why ``comfort_compliant`` is 0: each limit broken, its worst value and when (None: compliant)."""
    if not sig.rows:
        return INVALID
    found = sig.comfort_exceedances()
    return _ok("; ".join(e.describe() for e in found) if found else None)


@register_metric("snow_lion_comfort_compliant")
def _snow_lion_compliant(sig: RunSignals) -> MetricResult:
    return _ok(int(not sig.comfort_exceedances(SNOW_LION_COMFORT))) if sig.rows else INVALID


@register_metric("snow_lion_comfort_violation")
def _snow_lion_violation(sig: RunSignals) -> MetricResult:
    if not sig.rows:
        return INVALID
    found = sig.comfort_exceedances(SNOW_LION_COMFORT)
    return _ok("; ".join(e.describe() for e in found) if found else None)


def _extreme(values: np.ndarray, pick: Callable[[np.ndarray], np.floating]) -> MetricResult:
    return _ok(float(pick(values))) if len(values) else INVALID


register_metric("comfort_min_accel_mps2")(lambda sig: _extreme(sig.comfort_accel_mps2[1], np.min))
register_metric("comfort_max_accel_mps2")(lambda sig: _extreme(sig.comfort_accel_mps2[1], np.max))
register_metric("comfort_min_jerk_mps3")(lambda sig: _extreme(sig.comfort_jerk_mps3[1], np.min))
register_metric("comfort_max_jerk_mps3")(lambda sig: _extreme(sig.comfort_jerk_mps3[1], np.max))


@register_metric("closed_loop_score")
def _closed_loop_score(sig: RunSignals) -> MetricResult:
    if sig.duration_s <= 0.0:
        return INVALID
    at_fault = any(e.data["at_fault"] for e in sig.events("collision"))
    off_road = bool(sig.violations("drivable_area"))
    multiplier = 0.0 if (at_fault or off_road) else 1.0
    if sig.progress_ratio < MIN_PROGRESS_RATIO:
        multiplier *= 0.5
    terms = {
        "ttc": float(sig.min_ttc_s is None or sig.min_ttc_s >= TTC_THRESHOLD_S),
        "speed_limit": 1.0 - sig.time_where(sig.over_limit_rows) / sig.duration_s,
        "comfort": float(sig.comfort_compliant),
        "progress": min(1.0, sig.progress_ratio),
    }
    weighted = sum(SCORE_WEIGHTS[k] * v for k, v in terms.items()) / sum(SCORE_WEIGHTS.values())
    return _ok(multiplier * weighted)


def _pose_metric(fn: Callable[[PoseErrors], float | None]) -> MetricFn:
    def metric(sig: RunSignals) -> MetricResult:
        value = fn(sig.pose_errors)
        return INVALID if value is None else _ok(value)

    return metric


for _name, _fn in POSE_METRICS.items():
    register_metric(_name)(_pose_metric(_fn))


def _clean(result: MetricResult, name: str) -> MetricValue:
    if not result.valid or result.value is None:
        return None
    value = result.value
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, bool):
        return int(value)
    if isinstance(value, int | str):
        return value
    if isinstance(value, float):
        # Adding 0.0 turns -0.0 into 0.0, so identical runs print identically.
        return round(value, 6) + 0.0 if math.isfinite(value) else None
    raise MetricsError(f"metric {name}: expected a float, int, str or None, got {type(value).__name__}")


def compute_metrics(log: run_log.RunLog, comfort: ComfortLimits = SHUTTLE_COMFORT) -> dict[str, MetricValue]:
    """Every registered metric of one run, as a flat dict (``None`` where not measurable).

    Each metric is a small function registered by name (:func:`register_metric`) that reads a
    :class:`RunSignals` (the log plus signals derived once) and returns a :class:`MetricResult`
    ``(value, valid)``, as in Waymax. An invalid result (nothing to measure, e.g. a wait time with no
    passengers) becomes ``None``, which ``metrics.json`` writes as ``null``. Metrics depend only on the
    log, never on wall-clock time, so the same seed and configuration give an identical dict.

    Definitions (units in the names):

    - ``duration_s``: span of the ego trace (last minus first ``t_s``); ``distance_m``: length of the
      driven path (sum of the distances between consecutive ego positions); ``mean_speed_mps`` =
      distance / duration.
    - ``share_time_at_or_above_9kph``: time-weighted share of the trace with speed >= 2.5 m/s (each
      sample holds until the next), stops and dwell included, as in Snow Lion's Table 2.
    - ``min_accel_mps2``/``max_accel_mps2``: extremes of the logged longitudinal acceleration.
    - Jerk: the acceleration is first averaged over consecutive 0.1 s windows (10 Hz) and then
      differentiated between adjacent windows. This mirrors an IMU-rate estimate like the logs behind
      Snow Lion's Table 2; differentiating the raw 50 Hz trace would turn every controller step into a
      spike that no passenger feels. ``min_jerk_mps3``/``max_jerk_mps3`` are extremes of that jerk.
    - ``comfort_min_accel_mps2``/``comfort_max_accel_mps2``/``comfort_min_jerk_mps3``/
      ``comfort_max_jerk_mps3``: extremes of the 10 Hz acceleration and jerk outside emergencies (what
      the comfort checks read). ``comfort_violation``: why ``comfort_compliant`` is 0, one clause per
      limit broken (its worst value, the bound, the time, the state and how many 0.1 s samples), None
      when compliant. ``snow_lion_comfort_compliant`` / ``snow_lion_comfort_violation``: the same check
      against Snow Lion's measured envelope (-1.83..1.12 m/s², |jerk| <= 1.84 m/s³).
    - ``hard_braking_events``: entries into episodes where the 10 Hz acceleration is <= -1 m/s² (Snow
      Lion's braking criterion); an episode ends once the acceleration rises above -1 + 0.1 m/s², so a
      signal hovering at the threshold counts once. ``km_per_hard_braking`` and ``km_per_takeover``
      are distance in km divided by the count, and ``None`` when the count is zero (infinity is not
      JSON).
    - ``drop_offs_requested`` / ``drop_offs_served`` / ``drop_offs_at_kerb`` (served away from a stop),
      ``drop_off_curb_gap_max_m`` (door to kerb, the referee's), ``drop_off_wait_min_s`` (the shortest
      standstill at a served drop-off): only in runs with a ``drop_off_requested`` event.
    - ``passengers_served``: passengers picked up (``passenger_boarded`` events);
      ``passengers_alighted`` counts drop-offs. Riders still waiting at the end of the run have no
      wait time in the log, so ``mean_wait_s``/``max_wait_s`` cover boarded riders only.
    - ``localization_*`` and ``cross_track_error_*``: the stack's localization error against the
      true pose and the true cross-track error, from the log's localization table (definitions in
      ``pose_errors.POSE_METRICS``); None for a log without one.
    - ``min_ttc_s``: the smallest time-to-collision logged; ``None`` when it never fell below the
      simulator's 3 s logging threshold.
    - ``closed_loop_score`` (in [0, 1], in the spirit of nuPlan's):
      ``M * (5 * ttc + 4 * speed_limit + 2 * comfort + 5 * progress) / 16``. The multiplier ``M`` is 0
      with any at-fault collision, 0 with any drivable-area violation, else 1, halved when the
      progress ratio is below 0.2; ``ttc`` is 1 when ``min_ttc_s`` is None or >= 0.95 s, else 0;
      ``speed_limit`` is 1 minus the share of time over the limit in episodes the referee flagged;
      ``comfort`` is 1 when the 10 Hz acceleration and jerk stay inside :class:`ComfortLimits` outside
      emergencies, else 0; ``progress`` is ``min(1, distance / expected_distance_m)`` with
      ``expected_distance_m`` from ``meta.config`` (ratio 1 when it is absent).

    Optional ``meta.config`` keys read here: ``expected_distance_m`` (progress), ``speed_limit_mps``
    and ``speed_tolerance_mps`` (default 0.5, the referee's) to measure time over the limit,
    ``speed_hold_s`` (default 1.0, the referee's) for the estimate used when the limit is absent.

    Args:
        log: the run log.
        comfort: comfort limits (the shuttle defaults of :class:`ComfortLimits`).

    Returns:
        Metric name -> value; floats rounded to 6 decimals; depends on nothing but the log.

    Raises:
        ConfigError: an optional ``meta.config`` key the metrics read is not a finite number.
    """
    sig = RunSignals(log, comfort)
    return {
        name: _clean(fn(sig), name)
        for name, fn in _REGISTRY.items()
        if name not in _ONLY_WITH or sig.events(_ONLY_WITH[name])
    }


def _write_json(doc: Mapping[str, Any], path: Path, what: str) -> Path:
    try:
        text = json.dumps(dict(doc), sort_keys=True, indent=2, allow_nan=False)
    except (TypeError, ValueError) as exc:
        raise MetricsError(
            f"{what}: expected JSON-able values (finite numbers, str, None), got {exc}"
        ) from None
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text + "\n", encoding="utf-8")
    os.replace(tmp, path)
    return path


def write_metrics(metrics: Mapping[str, Any], run_dir: str | os.PathLike[str]) -> Path:
    """Write ``metrics.json`` (sorted keys, indent 2) into ``run_dir``; returns its path.

    Besides the metric values it may hold JSON-able tables (the configuration that produced them).
    """
    return _write_json(metrics, Path(run_dir) / METRICS_FILE, "write_metrics")


def write_timing(timing: Mapping[str, Any], run_dir: str | os.PathLike[str]) -> Path:
    """Write the wall-clock ``timing.json`` (sorted keys, indent 2) into ``run_dir``; returns its path."""
    return _write_json(timing, Path(run_dir) / TIMING_FILE, "write_timing")


def load_metrics(run_dir: str | os.PathLike[str]) -> dict[str, MetricValue]:
    """Read ``metrics.json`` back (for sweeps that aggregate many runs).

    Raises:
        MetricsError: naming the file when it is missing or not a JSON object.
    """
    path = Path(run_dir) / METRICS_FILE
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise MetricsError(f"{path}: expected a metrics file, got no such file") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise MetricsError(f"{path}: expected metrics JSON, got unreadable content ({exc})") from None
    if not isinstance(doc, dict):
        raise MetricsError(f"{path}: expected a JSON object, got {type(doc).__name__}")
    return doc
