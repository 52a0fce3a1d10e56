"""lastmile: an autonomy stack, simulator and service tooling for low-speed autonomous shuttles.

The Python API (:mod:`lastmile.api`) is reachable from here: ``lastmile.run``, ``lastmile.load_scenario``,
``lastmile.RunConfig``, ``lastmile.evaluate``. It is imported on first use, so that importing one
subpackage (``lastmile.core``...) does not load the whole simulator.
"""

from __future__ import annotations

from typing import Any

__version__ = "0.1.0"

_API_NAMES = ("RunConfig", "RunResult", "Scenario", "evaluate", "load_run_config", "load_scenario", "run")


def __getattr__(name: str) -> Any:
    if name in _API_NAMES:
        from lastmile import api

        return getattr(api, name)
    raise AttributeError(f"module 'lastmile' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted([*globals(), *_API_NAMES])
