"""The run log's localization table: the stack's own pose estimate and the true pose's cross-track errors.

One row per planning cycle on which the stack reported a localization estimate (its public
``StackOutput.diagnostics.estimate``, 10 Hz with the default 100 ms planning period) beside the true
pose at the same instant. ``table`` is an (M, 12) float64 array with the columns of
:data:`LOCALIZATION_COLUMNS`:

================ ====================================================================================
t_s              simulated time of the tick the estimate came with, strictly increasing
est_x_m, est_y_m the estimate's rear-axle position in the map frame (as the stack reported it)
est_yaw_rad      the estimate's heading
pos_std_m        the estimate's position sigma (largest horizontal axis), m
yaw_std_rad      the estimate's heading sigma
source_code      index into :data:`POSITION_SOURCES` of what held the position; -1 when the estimate
                 was flagged invalid (its pose is then not to be trusted; the five columns before
                 may then be NaN, where the stack's values were not finite)
true_x_m,        the simulator's true rear-axle pose at the estimate's instant (the start of the tick,
true_y_m,        before the command is applied: the ego trace's rows hold the state after it)
true_yaw_rad
route_d_m        the TRUE rear axle's signed lateral offset from the service route's centre line
                 (left positive), from the simulator; NaN when unknown
path_d_m         the TRUE rear axle's signed lateral offset from the stack's latest planned path
                 (left positive); NaN before the first plan
================ ====================================================================================

The true pose and the last two columns are ground truth the runner writes for the report: the stack
never sees them.
"""

from __future__ import annotations

import numpy as np

from lastmile.core.errors import LastmileError

LOCALIZATION_COLUMNS = (
    "t_s",
    "est_x_m",
    "est_y_m",
    "est_yaw_rad",
    "pos_std_m",
    "yaw_std_rad",
    "source_code",
    "true_x_m",
    "true_y_m",
    "true_yaw_rad",
    "route_d_m",
    "path_d_m",
)
"""Column names of :attr:`RunLocalization.table`, in order."""

LOCALIZATION_INDEX = {name: i for i, name in enumerate(LOCALIZATION_COLUMNS)}

POSITION_SOURCES = ("gnss", "landmarks", "dead_reckoning", "scan_matching", "amcl")
"""``source_code`` values: the ``core.vehicle_messages.PositionSource`` values, in order."""

INVALID_SOURCE = -1

_NULLABLE = ("route_d_m", "path_d_m")
_NULL_WHEN_INVALID = ("est_x_m", "est_y_m", "est_yaw_rad", "pos_std_m", "yaw_std_rad")


class RunLocalizationError(LastmileError):
    """A localization table is malformed (shape, NaN where a value is required, time going back)."""


class RunLocalization:
    """The localization table of a run (read-only; see the module docstring for the columns).

    Args:
        table: (M, 12) float64 rows; M may be 0.
        where: names the caller in errors.

    Raises:
        RunLocalizationError: naming the column and row that is wrong and what arrived.
    """

    __slots__ = ("table",)

    def __init__(self, table: np.ndarray, where: str = "RunLocalization") -> None:
        arr = np.array(table, dtype=np.float64)
        if arr.size == 0:
            arr = arr.reshape(0, len(LOCALIZATION_COLUMNS))
        if arr.ndim != 2 or arr.shape[1] != len(LOCALIZATION_COLUMNS):
            raise RunLocalizationError(
                f"{where}: expected an (M, {len(LOCALIZATION_COLUMNS)}) localization table, got shape "
                f"{arr.shape}"
            )
        invalid = arr[:, LOCALIZATION_INDEX["source_code"]] == INVALID_SOURCE
        for i, name in enumerate(LOCALIZATION_COLUMNS):
            bad = np.isinf(arr[:, i]) if name in _NULLABLE else ~np.isfinite(arr[:, i])
            if name in _NULL_WHEN_INVALID:
                bad &= ~(invalid & np.isnan(arr[:, i]))
            if np.any(bad):
                row = int(np.argmax(bad))
                raise RunLocalizationError(f"{where}: expected finite {name}, got {arr[row, i]} in row {row}")
        codes = arr[:, LOCALIZATION_INDEX["source_code"]]
        bad = (codes != np.round(codes)) | (codes < INVALID_SOURCE) | (codes >= len(POSITION_SOURCES))
        if np.any(bad):
            row = int(np.argmax(bad))
            raise RunLocalizationError(
                f"{where}: expected source_code an integer in [-1, {len(POSITION_SOURCES) - 1}], got "
                f"{codes[row]} in row {row}"
            )
        if len(arr) > 1 and not np.all(np.diff(arr[:, 0]) > 0.0):
            row = int(np.argmax(np.diff(arr[:, 0]) <= 0.0)) + 1
            raise RunLocalizationError(
                f"{where}: expected strictly increasing t_s, got {arr[row, 0]} after {arr[row - 1, 0]} "
                f"in row {row}"
            )
        arr.setflags(write=False)
        self.table = arr

    @classmethod
    def empty(cls) -> RunLocalization:
        return cls(np.zeros((0, len(LOCALIZATION_COLUMNS))))

    def __len__(self) -> int:
        return len(self.table)

    def column(self, name: str) -> np.ndarray:
        """(M,) read-only view of one column, by its name in :data:`LOCALIZATION_COLUMNS`."""
        if name not in LOCALIZATION_INDEX:
            raise RunLocalizationError(
                f"RunLocalization.column: expected one of {list(LOCALIZATION_COLUMNS)}, got {name!r}"
            )
        return self.table[:, LOCALIZATION_INDEX[name]]

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, RunLocalization):
            return NotImplemented
        return np.array_equal(self.table, other.table, equal_nan=True)

    __hash__ = None  # type: ignore[assignment]
