"""Merge of several LiDAR sweeps into one cloud in the base frame at one reference time.

WATonoBus concatenates its front and two side blind-spot LiDARs before ground segmentation. Each
sweep goes through its extrinsic calibration (``base_from_sensor``) and, when INS poses are given, is
de-skewed to the common reference time (the latest sweep end), so the three clouds line up on a
moving vehicle.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from lastmile.core.arrays import frozen_array
from lastmile.core.errors import MessageError
from lastmile.core.sensor_frames import LIDAR_COLUMNS, LidarSweep
from lastmile.core.stamp import Stamp
from lastmile.perception.deskew_kernel import rigid_transform_into
from lastmile.perception.motion_compensation import (
    PoseTrajectory,
    _apply_bin_transforms,
    _sweep_time_bins,
)

MERGED_COLUMNS = ("x_m", "y_m", "z_m", "intensity", "ring", "sensor_index")
"""Columns of :attr:`MergedCloud.points`."""

_T = LIDAR_COLUMNS.index("t_offset_us")


@dataclass(frozen=True, slots=True, kw_only=True)
class MergedCloud:
    """All LiDAR points of one rig frame in the base frame (x forward, y left, z up from the ground
    under the rear axle) at the reference time ``stamp``.

    Attributes:
        points: (N, 6) float32, columns :data:`MERGED_COLUMNS`; ``sensor_index`` indexes ``sensor_ids``.
        sensor_ids: the sweeps' sensor ids in merge order.
        compensated: whether the points were de-skewed with INS poses.
    """

    stamp: Stamp
    points: np.ndarray
    sensor_ids: tuple[str, ...]
    compensated: bool

    def __post_init__(self) -> None:
        object.__setattr__(
            self, "points", frozen_array(self.points, np.float32, len(MERGED_COLUMNS), "MergedCloud.points")
        )

    def validate(self) -> None:
        frozen_array(self.points, np.float32, len(MERGED_COLUMNS), "MergedCloud.points")
        idx = self.points[:, 5]
        if len(idx) and (idx.min() < 0 or idx.max() >= len(self.sensor_ids)):
            raise MessageError(
                f"MergedCloud.points: expected sensor_index in [0, {len(self.sensor_ids)}), "
                f"got [{idx.min()}, {idx.max()}]"
            )

    @property
    def xyz_m(self) -> np.ndarray:
        """(N, 3) float32 view of the coordinates."""
        return self.points[:, :3]


def sweep_end_us(sweep: LidarSweep) -> int:
    """Capture time of a sweep's last point (its stamp when empty)."""
    if len(sweep.points) == 0:
        return int(sweep.stamp)
    return int(sweep.stamp) + int(sweep.points[:, _T].max())


def merge_sweeps(
    sweeps: Sequence[LidarSweep],
    base_from_sensor: Mapping[str, npt.ArrayLike],
    trajectory: PoseTrajectory | None = None,
    ref_stamp: Stamp | None = None,
    time_bin_us: int = 500,
) -> MergedCloud:
    """Bring every sweep into the base frame and concatenate them (:func:`merged_points` as a
    checked, read-only :class:`MergedCloud`)."""
    stamp, points = merged_points(sweeps, base_from_sensor, trajectory, ref_stamp, time_bin_us)
    ids = tuple(s.sensor_id for s in sweeps)
    return MergedCloud(stamp=stamp, points=points, sensor_ids=ids, compensated=trajectory is not None)


def merged_points(
    sweeps: Sequence[LidarSweep],
    base_from_sensor: Mapping[str, npt.ArrayLike],
    trajectory: PoseTrajectory | None = None,
    ref_stamp: Stamp | None = None,
    time_bin_us: int = 500,
) -> tuple[Stamp, np.ndarray]:
    """The reference stamp and the (N, 6) float32 points (:data:`MERGED_COLUMNS`) of every sweep in
    the base frame, concatenated in the order given (sensor index = position in ``sweeps``).

    The array is the caller's own (not copied, not frozen): the pipeline crops it at once and
    checks only what it keeps (points of validated sweeps through finite extrinsics).

    Args:
        sweeps: one sweep per LiDAR (distinct sensor ids).
        base_from_sensor: (4, 4) extrinsic calibration per sensor id.
        trajectory: INS poses; when given, points are de-skewed to ``ref_stamp``.
        ref_stamp: reference time; defaults to the latest sweep end.
        time_bin_us: de-skew time-bin width (see :func:`deskew_points`).

    Raises:
        MessageError: no sweeps, a repeated sensor id, or a sensor without extrinsics.
    """
    if not sweeps:
        raise MessageError("merge_sweeps: expected at least one LidarSweep, got none")
    ids = tuple(s.sensor_id for s in sweeps)
    if len(set(ids)) != len(ids):
        raise MessageError(f"merge_sweeps: expected distinct sensor ids, got {ids}")
    missing = [i for i in ids if i not in base_from_sensor]
    if missing:
        raise MessageError(
            f"merge_sweeps: expected extrinsics for every sensor, got none for {missing} "
            f"(known: {sorted(base_from_sensor)})"
        )
    ref = int(ref_stamp) if ref_stamp is not None else max(sweep_end_us(s) for s in sweeps)
    total = sum(len(s.points) for s in sweeps)
    out = np.empty((total, len(MERGED_COLUMNS)), dtype=np.float32)
    if trajectory is not None and time_bin_us <= 0:
        raise MessageError(f"merge_sweeps.time_bin_us: expected > 0, got {time_bin_us}")
    extrinsics, binned = [], []
    for sweep in sweeps:
        B = np.asarray(base_from_sensor[sweep.sensor_id], dtype=np.float64)
        if B.shape != (4, 4) or not np.isfinite(B).all():
            raise MessageError(
                f"merge_sweeps: expected a finite (4, 4) extrinsic for {sweep.sensor_id!r}, got {B.shape}"
            )
        extrinsics.append(B)
        if trajectory is not None and len(sweep.points):
            binned.append(_sweep_time_bins(int(sweep.stamp), sweep.points[:, _T], time_bin_us))
    if binned and trajectory is not None:
        # One pose query for every sweep's bins and the reference (the same per-time poses as
        # one query per sweep: the interpolation is element-wise), then per-sweep transforms
        # exactly as deskew_points forms them.
        M = trajectory.matrices_at(np.concatenate([c for _, c in binned] + [np.array([float(ref)])]))
        ref_from_map = np.linalg.inv(M[-1])
    row, b0, j = 0, 0, 0
    for k, sweep in enumerate(sweeps):
        pts = sweep.points
        n = len(pts)
        B = extrinsics[k]
        if trajectory is not None and n:
            bins, centres = binned[j]
            T = ref_from_map @ M[b0 : b0 + len(centres)] @ B  # (n_bins, 4, 4): base(ref) <- sensor(t_bin)
            out[row : row + n, :3] = _apply_bin_transforms(pts[:, :3], bins, T)
            b0, j = b0 + len(centres), j + 1
            out[row : row + n, 3:5] = pts[:, 3:5]
            out[row : row + n, 5] = k
        else:
            # Compiled: the float32 array expressions' arithmetic in one pass over the sweep.
            rigid_transform_into(pts, B.astype(np.float32), out, row, k)
        row += n
    return Stamp(ref), out
