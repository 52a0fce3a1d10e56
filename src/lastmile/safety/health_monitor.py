"""aUToronto's process-health monitor: per-module heartbeats, watchdog timers and aggregate system health."""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass

from lastmile.core.errors import ConfigError
from lastmile.core.safety_messages import (
    FailSafeLevel,
    MalfunctionKind,
    MalfunctionSignal,
    ModuleHealth,
    SystemHealth,
)
from lastmile.core.stamp import Stamp
from lastmile.core.vehicle_messages import Heartbeat


@dataclass(frozen=True, slots=True, kw_only=True)
class ModuleSpec:
    """One watched module.

    Attributes:
        name: module name as it appears in its heartbeats.
        period_us: how often the module is expected to pulse, > 0.
        failure_level: fail-safe level asked for while the module is unhealthy or silent.
    """

    name: str
    period_us: int
    failure_level: FailSafeLevel = FailSafeLevel.MINIMAL_RISK_MANOEUVRE

    def __post_init__(self) -> None:
        if not self.name:
            raise ConfigError("ModuleSpec.name: expected a non-empty module name, got ''")
        if self.period_us <= 0:
            raise ConfigError(f"ModuleSpec.period_us: expected a positive period, got {self.period_us}")


@dataclass(frozen=True, slots=True, kw_only=True)
class HealthMonitorConfig:
    """Watchdog timing.

    A module is silent when ``now - last_beat > timeout_factor * period_us + timeout_margin_us``. With
    the defaults (1.0, 50 ms) and a monitor checked every base tick (10 ms), a module that freezes right
    after a pulse is reported within one period + 60 ms: inside the issue's "one period + 100 ms".

    Attributes:
        timeout_factor: k in the timeout, >= 1 (a smaller k would flag a punctual module).
        timeout_margin_us: slack for scheduling jitter, >= 0.
        startup_grace_us: time from the first check before a module never heard from counts as silent.
    """

    timeout_factor: float = 1.0
    timeout_margin_us: int = 50_000
    startup_grace_us: int = 1_000_000

    def __post_init__(self) -> None:
        if not self.timeout_factor >= 1.0:
            raise ConfigError(
                f"HealthMonitorConfig.timeout_factor: expected >= 1.0, got {self.timeout_factor}"
            )
        if self.timeout_margin_us < 0 or self.startup_grace_us < 0:
            raise ConfigError(
                "HealthMonitorConfig: expected timeout_margin_us and startup_grace_us >= 0, got "
                f"{self.timeout_margin_us}, {self.startup_grace_us}"
            )


class _Module:
    __slots__ = ("exception", "healthy", "last_beat_us", "reason", "spec", "timeout_us")

    def __init__(self, spec: ModuleSpec, timeout_us: int) -> None:
        self.spec = spec
        self.timeout_us = timeout_us
        self.last_beat_us = -1
        self.healthy = False
        self.reason = "no heartbeat yet"
        self.exception = False


class HealthMonitor:
    """Aggregates heartbeats into :class:`SystemHealth` and turns failures into malfunction signals.

    A module is healthy while its latest pulse said healthy and its watchdog has not expired. An
    unhealthy pulse or an expired watchdog keeps it unhealthy until it pulses healthy again. Heartbeats
    from modules not in the specs raise :class:`ConfigError` (a typo would otherwise go unwatched).
    """

    def __init__(self, modules: Sequence[ModuleSpec], config: HealthMonitorConfig | None = None) -> None:
        self.config = config or HealthMonitorConfig()
        names = [m.name for m in modules]
        if len(set(names)) != len(names):
            raise ConfigError(f"HealthMonitor: expected unique module names, got {names}")
        c = self.config
        self._modules = {
            m.name: _Module(m, round(c.timeout_factor * m.period_us) + c.timeout_margin_us) for m in modules
        }
        self._started_us: int | None = None

    @property
    def module_names(self) -> tuple[str, ...]:
        return tuple(self._modules)

    def timeout_us(self, module: str) -> int:
        """The watchdog timeout of ``module``."""
        return self._get(module).timeout_us

    def _get(self, module: str) -> _Module:
        try:
            return self._modules[module]
        except KeyError:
            raise ConfigError(
                f"HealthMonitor: expected a heartbeat from one of {sorted(self._modules)}, got {module!r}"
            ) from None

    def pulse(self, beat: Heartbeat) -> None:
        """Record one heartbeat (the latest pulse of a module decides its healthy flag)."""
        m = self._get(beat.module)
        if beat.stamp < m.last_beat_us:
            return  # a late pulse must not overwrite a newer verdict
        m.last_beat_us = int(beat.stamp)
        m.healthy = beat.healthy
        m.reason = beat.reason if not beat.healthy else ""
        m.exception = beat.exception and not beat.healthy

    def pulse_all(self, beats: Iterable[Heartbeat]) -> None:
        for beat in beats:
            self.pulse(beat)

    def check(self, now_us: int) -> SystemHealth:
        """Run the watchdogs at ``now_us`` and return the aggregate health."""
        if self._started_us is None:
            self._started_us = int(now_us)
        out = []
        for name, m in self._modules.items():
            silent = self._silent(m, now_us)
            healthy = m.healthy and not silent
            if silent:
                reason = (
                    f"no heartbeat for {(now_us - m.last_beat_us) / 1e3:.0f} ms "
                    f"(timeout {m.timeout_us / 1e3:.0f} ms)"
                    if m.last_beat_us >= 0
                    else "never sent a heartbeat"
                )
            else:
                reason = m.reason
            out.append(
                ModuleHealth(
                    module=name, healthy=healthy, reason=reason, last_beat_us=m.last_beat_us, silent=silent
                )
            )
        return SystemHealth(stamp=Stamp(int(now_us)), healthy=all(h.healthy for h in out), modules=tuple(out))

    def _silent(self, m: _Module, now_us: int) -> bool:
        if m.last_beat_us < 0:
            assert self._started_us is not None
            return now_us - self._started_us > self.config.startup_grace_us
        return now_us - m.last_beat_us > m.timeout_us

    def signals(self, health: SystemHealth) -> tuple[MalfunctionSignal, ...]:
        """One malfunction signal per unhealthy module, at the module's ``failure_level``."""
        out = []
        for h in health.modules:
            if h.healthy or (h.last_beat_us < 0 and not h.silent):
                continue  # healthy, or still within the startup grace (not ready is not a fault)
            m = self._modules[h.module]
            if h.silent:
                kind = MalfunctionKind.MODULE_SILENT
            elif m.exception:
                kind = MalfunctionKind.MODULE_EXCEPTION
            else:
                kind = MalfunctionKind.MODULE_UNHEALTHY
            out.append(
                MalfunctionSignal(
                    stamp=health.stamp,
                    source=f"module:{h.module}",
                    kind=kind,
                    level=m.spec.failure_level,
                    reason=f"{h.module}: {h.reason or 'unhealthy'}",
                )
            )
        return tuple(out)
