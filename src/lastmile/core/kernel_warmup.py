"""What a kernel warm-up did, and its one-line summary: shared by the perception's and the simulator's
warm-ups (``lastmile warmup``, ``scripts/bootstrap.sh``)."""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from lastmile.core.user_cache import kernel_cache_dir


@dataclass(frozen=True, slots=True, kw_only=True)
class WarmupReport:
    """What a warm-up did.

    Attributes:
        cache_dir: where the compiled kernels are cached.
        seconds: wall time of the warm-up (compilation, or loading from the cache).
        kernels: kernel functions found.
        not_compiled: names of kernel functions that hold no compiled signature afterwards.
    """

    cache_dir: str
    seconds: float
    kernels: int
    not_compiled: tuple[str, ...]


def warmup_report(kernels: Mapping[str, Any], started_s: float) -> WarmupReport:
    """The report once every path has run: which of ``kernels`` (Numba dispatchers) hold no signature."""
    missing = tuple(sorted(name for name, fn in kernels.items() if not fn.signatures))
    return WarmupReport(
        cache_dir=str(kernel_cache_dir()),
        seconds=time.perf_counter() - started_s,
        kernels=len(kernels),
        not_compiled=missing,
    )


def print_report(what: str, report: WarmupReport) -> int:
    """Print the summary line (and what was not compiled); the exit code: 1 if anything was not."""
    print(
        f"{what} kernels: {report.kernels - len(report.not_compiled)} of {report.kernels} compiled "
        f"in {report.seconds:.1f} s, cached in {report.cache_dir}"
    )
    if report.not_compiled:
        print(f"not compiled (compiled at their first call instead): {', '.join(report.not_compiled)}")
        return 1
    return 0
