"""A point-cloud map from recorded LiDAR sweeps placed at the vehicle's own recorded poses.

Snow Lion ("Three-dimensional point cloud mapping and localization") builds the map its scan matcher
localizes against from the vehicle's own drives. Here each LiDAR rig frame (the sweeps of all units
stamped alike) is:

1. de-skewed: every point carried into the base frame at the frame's stamp with the recorded trajectory
   interpolated at its own capture time (a sweep lasts 100 ms, 0.56 m at 20 km/h);
2. placed at the recorded pose ``map -> base_link`` (the vehicle's own localization, never the
   simulator's truth; on RTK it is good to centimetres);
3. refined by scan-to-map registration (small_gicp point-to-plane ICP) against the frames already placed
   near it (the ``submap_frames`` nearest within ``submap_radius_m``: on a second lap those include the
   first, so revisits register to what was mapped before). The correction is applied only when the
   registration converged, paired at least ``min_inlier_share`` of the points, left an RMSE within
   ``max_rmse_m`` and moved the recorded pose by at most ``max_correction_m`` / ``max_correction_rad``
   (the recorded pose's own accuracy: a larger jump is a wrong match, not a better pose). Only the
   planar part (x, y, yaw) is kept, the frame the stack localizes in;
4. voxel-downsampled into the map.

Frames are taken once per ``keyframe_m`` of travel or ``keyframe_rad`` of turn (standing at a stop adds
passers-by, not structure), and only while the recorded pose was held by an absolute source with a
sigma within ``max_pose_std_m`` when the recording says so. No pose graph: with RTK poses the
registration corrections were centimetres (see the sidecar), so a graph's loop closures would have
nothing to close; a recording on dead reckoning is refused frame by frame instead.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from lastmile.core.errors import ConfigError

_SUBMAP_MIN_POINTS = 300


@dataclass(frozen=True, slots=True, kw_only=True)
class MapBuildConfig:
    """Parameters of :class:`PointCloudMapBuilder`.

    Attributes:
        voxel_m: voxel size of the written map, m.
        keyframe_m: a rig frame is placed after this much travel since the last placed one, m.
        keyframe_rad: or after this much turn, rad.
        min_range_m: returns nearer the sensor than this are dropped (the vehicle's own body), m.
        max_range_m: and farther than this (sparse, and the angular error grows with range), m.
        register: refine each placed frame by scan-to-map registration.
        submap_radius_m: frames placed within this of the current pose form the registration target, m.
        submap_frames: at most this many of them (the nearest).
        max_correspondence_m: largest point-to-map distance paired, m.
        max_iterations: Gauss-Newton iterations.
        min_inlier_share: a registration pairing fewer of the frame's points is not applied.
        max_rmse_m: nor one leaving a larger point-to-plane RMSE, m.
        max_correction_m: nor one moving the recorded pose farther than this, m.
        max_correction_rad: or turning it by more than this, rad.
        max_pose_std_m: frames whose recorded pose sigma exceeds this are not placed, m.
    """

    voxel_m: float = 0.2
    keyframe_m: float = 1.0
    keyframe_rad: float = math.radians(10.0)
    min_range_m: float = 2.0
    max_range_m: float = 60.0
    register: bool = True
    submap_radius_m: float = 30.0
    submap_frames: int = 8
    max_correspondence_m: float = 0.5
    max_iterations: int = 20
    min_inlier_share: float = 0.5
    max_rmse_m: float = 0.1
    max_correction_m: float = 0.3
    max_correction_rad: float = math.radians(1.0)
    max_pose_std_m: float = 0.1

    def __post_init__(self) -> None:
        for name in (
            "voxel_m",
            "keyframe_m",
            "keyframe_rad",
            "max_range_m",
            "submap_radius_m",
            "max_correspondence_m",
            "max_rmse_m",
            "max_correction_m",
            "max_correction_rad",
            "max_pose_std_m",
        ):
            value = getattr(self, name)
            if not (value > 0 and math.isfinite(value)):
                raise ConfigError(f"MapBuildConfig.{name}: expected a positive number, got {value!r}")
        if not 0.01 <= self.voxel_m <= 5.0:
            raise ConfigError(f"--voxel: expected a voxel size in [0.01, 5] m, got {self.voxel_m}")
        if not 0.0 <= self.min_range_m < self.max_range_m:
            raise ConfigError(
                f"MapBuildConfig.min_range_m: expected in [0, max_range_m), got {self.min_range_m}"
            )
        if self.submap_frames < 1 or self.max_iterations < 1:
            raise ConfigError(
                "MapBuildConfig: expected submap_frames >= 1 and max_iterations >= 1, "
                f"got {self.submap_frames} and {self.max_iterations}"
            )
        if not 0.0 < self.min_inlier_share <= 1.0:
            raise ConfigError(
                f"MapBuildConfig.min_inlier_share: expected (0, 1], got {self.min_inlier_share}"
            )


@dataclass(frozen=True, slots=True)
class Trajectory:
    """Recorded planar poses ``map -> base_link``: stamps_us (K,) increasing, xy_m (K, 2), yaw_rad (K,)."""

    stamps_us: np.ndarray
    xy_m: np.ndarray
    yaw_rad: np.ndarray

    @staticmethod
    def from_matrices(stamps_us: np.ndarray, map_from_base: np.ndarray) -> Trajectory:
        """From (K,) stamps and (K, 4, 4) poses; duplicate stamps keep the last pose."""
        t = np.asarray(stamps_us, dtype=np.int64)
        keep = np.append(t[1:] != t[:-1], True) if len(t) else np.zeros(0, bool)
        m = np.asarray(map_from_base, dtype=np.float64)[keep]
        yaw = np.unwrap(np.arctan2(m[:, 1, 0], m[:, 0, 0]))
        return Trajectory(t[keep], m[:, :2, 3].copy(), yaw)

    def covers(self, t_us: np.ndarray) -> bool:
        """All of ``t_us`` within the recorded span (interpolation, never extrapolation)."""
        return bool(
            len(self.stamps_us) >= 2 and t_us.min() >= self.stamps_us[0] and t_us.max() <= self.stamps_us[-1]
        )

    def at(self, t_us: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Interpolated (xy (n, 2), yaw (n,)) at ``t_us`` (n,)."""
        t = np.asarray(t_us, dtype=np.float64)
        st = self.stamps_us.astype(np.float64)
        x = np.interp(t, st, self.xy_m[:, 0])
        y = np.interp(t, st, self.xy_m[:, 1])
        return np.column_stack([x, y]), np.interp(t, st, self.yaw_rad)


def deskew_to_base(
    points_sensor: np.ndarray,
    offsets_us: np.ndarray,
    stamp_us: int,
    base_from_sensor: np.ndarray,
    trajectory: Trajectory,
) -> np.ndarray:
    """Points of one sweep, each captured at ``stamp_us + offset``, in the base frame at ``stamp_us``.

    Args:
        points_sensor: (n, 3) in the sensor frame, m.
        offsets_us: (n,) capture time of each point after the sweep's stamp, µs.
        base_from_sensor: (4, 4) the sensor's mount.
        trajectory: the recorded poses (must cover the sweep).
    """
    p = points_sensor @ base_from_sensor[:3, :3].T + base_from_sensor[:3, 3]
    xy_t, yaw_t = trajectory.at(stamp_us + offsets_us)
    c, s = np.cos(yaw_t), np.sin(yaw_t)
    mx = xy_t[:, 0] + c * p[:, 0] - s * p[:, 1]
    my = xy_t[:, 1] + s * p[:, 0] + c * p[:, 1]
    xy0, yaw0 = trajectory.at(np.array([stamp_us]))
    c0, s0 = math.cos(float(yaw0[0])), math.sin(float(yaw0[0]))
    dx, dy = mx - xy0[0, 0], my - xy0[0, 1]
    return np.column_stack([c0 * dx + s0 * dy, -s0 * dx + c0 * dy, p[:, 2]])


def planar_matrix(x_m: float, y_m: float, yaw_rad: float) -> np.ndarray:
    """(4, 4) pose of a planar (x, y, yaw)."""
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    m = np.eye(4)
    m[:2, :2] = [[c, -s], [s, c]]
    m[0, 3], m[1, 3] = x_m, y_m
    return m


@dataclass(slots=True)
class MapBuildStats:
    """What the builder did, for the sidecar."""

    frames_offered: int = 0
    frames_used: int = 0
    frames_registered: int = 0
    frames_rejected_registration: int = 0
    rmse_m: list[float] = field(default_factory=list)
    correction_m: list[float] = field(default_factory=list)


class PointCloudMapBuilder:
    """Accumulates de-skewed rig frames into a map, registering each to what is already mapped."""

    def __init__(self, config: MapBuildConfig | None = None) -> None:
        self.config = config or MapBuildConfig()
        self.stats = MapBuildStats()
        # Each placed frame's points (downsampled) and pose, relative to the first pose's position:
        # small_gicp's voxel keys hold 21 bits per axis (+-200 km at 0.2 m), less than a UTM easting.
        self._origin: tuple[float, float] | None = None
        self._frames: list[np.ndarray] = []
        self._poses: list[tuple[float, float, float]] = []
        self._last: tuple[float, float, float] | None = None

    def wants(self, x_m: float, y_m: float, yaw_rad: float) -> bool:
        """Whether a frame at this pose is a new keyframe (moved or turned enough since the last)."""
        if self._last is None:
            return True
        lx, ly, lyaw = self._last
        c = self.config
        turned = abs(math.remainder(yaw_rad - lyaw, math.tau))
        return math.hypot(x_m - lx, y_m - ly) >= c.keyframe_m or turned >= c.keyframe_rad

    def add(self, points_base: np.ndarray, x_m: float, y_m: float, yaw_rad: float) -> bool:
        """Place one rig frame (base frame at its stamp, de-skewed) recorded at pose (x, y, yaw).

        Returns:
            True if the frame was placed (a keyframe with enough points in range).
        """
        import small_gicp

        c = self.config
        self.stats.frames_offered += 1
        if not self.wants(x_m, y_m, yaw_rad):
            return False
        r2 = np.einsum("ij,ij->i", points_base[:, :2], points_base[:, :2])
        keep = (r2 >= c.min_range_m**2) & (r2 <= c.max_range_m**2) & np.isfinite(points_base).all(axis=1)
        pts = np.ascontiguousarray(points_base[keep], dtype=np.float64)
        if len(pts) < _SUBMAP_MIN_POINTS:
            return False
        self._last = (x_m, y_m, yaw_rad)
        if self._origin is None:
            self._origin = (x_m, y_m)
        ox, oy = self._origin
        pose = planar_matrix(x_m - ox, y_m - oy, yaw_rad)
        if c.register:
            pose = self._refine(small_gicp, pts, pose)
        down = np.asarray(small_gicp.voxelgrid_sampling(pts, c.voxel_m).points())[:, :3]
        placed = down @ pose[:3, :3].T + pose[:3, 3]
        self._frames.append(placed)
        self._poses.append((float(pose[0, 3]), float(pose[1, 3]), math.atan2(pose[1, 0], pose[0, 0])))
        self.stats.frames_used += 1
        return True

    def _submap(self, x_m: float, y_m: float) -> np.ndarray | None:
        c = self.config
        if not self._poses:
            return None
        xy = np.array([(p[0], p[1]) for p in self._poses])
        d = np.hypot(xy[:, 0] - x_m, xy[:, 1] - y_m)
        near = np.flatnonzero(d <= c.submap_radius_m)
        if near.size == 0:
            return None
        near = near[np.argsort(d[near], kind="stable")[: c.submap_frames]]
        pts = np.concatenate([self._frames[i] for i in sorted(near)])
        return pts if len(pts) >= _SUBMAP_MIN_POINTS else None

    def _refine(self, sg: object, pts: np.ndarray, pose: np.ndarray) -> np.ndarray:
        """The recorded pose, or its registration to the submap when that passes every check."""
        c = self.config
        target_pts = self._submap(float(pose[0, 3]), float(pose[1, 3]))
        if target_pts is None:
            return pose
        target, tree = sg.preprocess_points(target_pts, downsampling_resolution=c.voxel_m)  # type: ignore[attr-defined]
        source, _ = sg.preprocess_points(pts, downsampling_resolution=c.voxel_m)  # type: ignore[attr-defined]
        result = sg.align(  # type: ignore[attr-defined]
            target,
            source,
            tree,
            init_T_target_source=pose,
            registration_type="PLANE_ICP",
            max_correspondence_distance=c.max_correspondence_m,
            max_iterations=c.max_iterations,
        )
        inliers = int(result.num_inliers)
        rmse = math.sqrt(2.0 * float(result.error) / max(inliers, 1))
        found = np.asarray(result.T_target_source, dtype=np.float64)
        fx, fy, fyaw = float(found[0, 3]), float(found[1, 3]), math.atan2(found[1, 0], found[0, 0])
        moved = math.hypot(fx - pose[0, 3], fy - pose[1, 3])
        turned = abs(math.remainder(fyaw - math.atan2(pose[1, 0], pose[0, 0]), math.tau))
        ok = (
            bool(result.converged)
            and inliers >= c.min_inlier_share * int(source.size())
            and rmse <= c.max_rmse_m
            and moved <= c.max_correction_m
            and turned <= c.max_correction_rad
        )
        if not ok:
            self.stats.frames_rejected_registration += 1
            return pose
        self.stats.frames_registered += 1
        self.stats.rmse_m.append(rmse)
        self.stats.correction_m.append(moved)
        return planar_matrix(fx, fy, fyaw)

    def points(self) -> np.ndarray:
        """The map: every placed frame, voxel-downsampled together, (N, 3) float64."""
        import small_gicp

        if not self._frames or self._origin is None:
            return np.zeros((0, 3))
        allpts = np.concatenate(self._frames)
        out = np.asarray(small_gicp.voxelgrid_sampling(allpts, self.config.voxel_m).points())[:, :3].copy()
        out[:, 0] += self._origin[0]
        out[:, 1] += self._origin[1]
        return out
