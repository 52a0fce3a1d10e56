"""A point-cloud map from recorded LiDAR sweeps placed at the vehicle's own recorded poses.

Snow Lion ("Three-dimensional point cloud mapping and localization") builds the map its scan matcher
localizes against from the vehicle's own drives. Here each LiDAR rig frame (the sweeps of all units
stamped alike) is:

1. de-skewed: every point carried into the base frame at the frame's stamp with the recorded trajectory
   interpolated at its own capture time (a sweep lasts 100 ms, 0.56 m at 20 km/h);
2. placed at the recorded pose ``map -> base_link`` (the vehicle's own localization, never the
   simulator's truth; on RTK it is good to centimetres);
3. registered (small_gicp point-to-plane ICP, :class:`ScanToMapMatcher`) to the frames already placed
   near it (the ``submap_frames`` nearest within ``submap_radius_m``: on a second lap those include
   the first, so revisits register to what was mapped before). A registration that converged, paired
   at least ``min_inlier_share`` of the points, left an RMSE within ``max_rmse_m`` and, fused with the
   recorded pose by their covariances, moved it by at most ``max_correction_m`` / ``max_correction_rad``
   (a larger jump is a wrong match) becomes an edge of a planar pose graph
   (:mod:`lastmile.localization.pose_graph`) to the nearest submap frame, with the registration's
   covariance (opened up along directions no surface constrains);
4. after the last frame, the pose graph is solved: every recorded pose is an absolute prior with its
   own sigma, every registration a relative edge. Registering frame after frame alone would anchor
   the whole map on the first frame's error (measured: a 5 cm pose noise left the map 10 cm off);
   the graph spreads the absolute information over all frames and keeps the registrations' local
   consistency. Only the planar part (x, y, yaw) is estimated, the frame the stack localizes in;
5. placed at the optimised poses and voxel-downsampled into the map.

Frames are taken once per ``keyframe_m`` of travel or ``keyframe_rad`` of turn (standing at a stop adds
passers-by, not structure), and only while the recorded pose was held by an absolute source with a
sigma within ``max_pose_std_m`` when the recording says so (a recording on dead reckoning is refused
frame by frame). SciPy's sparse least squares solves the graph (GTSAM would too; it is not a
dependency, and a planar graph of a few thousand poses needs nothing more).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from lastmile.core.errors import ConfigError, MessageError
from lastmile.localization.pose_graph import RelativeEdge, optimise, relative
from lastmile.localization.scan_matching import ScanMatchConfig, ScanToMapMatcher

_SUBMAP_MIN_POINTS = 300


@dataclass(frozen=True, slots=True, kw_only=True)
class MapBuildConfig:
    """Parameters of :class:`PointCloudMapBuilder`.

    Attributes:
        voxel_m: voxel size of the written map, m.
        keyframe_m: a rig frame is placed after this much travel since the last placed one, m.
        keyframe_rad: or after this much turn, rad.
        min_range_m: returns nearer the sensor than this are dropped (the vehicle's own body), m.
        max_range_m: and farther than this, m. A point lands off by its range times the recorded
            heading's error: the stack's heading sigma is about 0.12 degree (its EKF on the simulated
            RTK/INS), 5 cm at 25 m, 13 cm at 60 m; with a keyframe every metre or two every place is
            seen from near by some frame, so only near returns go into the map (measured: a map from
            60 m returns put the scan matcher 10-14 cm off laterally, from 25 m within 5 cm).
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
        pose_std_m: the recorded pose's sigma when the recording does not say (RTK: 2 cm), m.
        pose_yaw_std_rad: and its heading sigma (a dual-antenna RTK heading: 0.1 degree), rad.
    """

    voxel_m: float = 0.2
    keyframe_m: float = 1.0
    keyframe_rad: float = math.radians(10.0)
    min_range_m: float = 2.0
    max_range_m: float = 25.0
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
    pose_std_m: float = 0.02
    pose_yaw_std_rad: float = math.radians(0.1)

    def __post_init__(self) -> None:
        if not 0.01 <= self.voxel_m <= 5.0:  # the CLI's --voxel
            raise ConfigError(f"--voxel: expected a voxel size in [0.01, 5] m, got {self.voxel_m}")
        for name in (
            "keyframe_m",
            "keyframe_rad",
            "max_range_m",
            "submap_radius_m",
            "max_correspondence_m",
            "max_rmse_m",
            "max_correction_m",
            "max_correction_rad",
            "max_pose_std_m",
            "pose_std_m",
            "pose_yaw_std_rad",
        ):
            value = getattr(self, name)
            if not (value > 0 and math.isfinite(value)):
                raise ConfigError(f"MapBuildConfig.{name}: expected a positive number, got {value!r}")
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
    """How far the pose graph moved each frame from its recorded pose, m."""


class PointCloudMapBuilder:
    """Accumulates de-skewed rig frames into a map, registering each to what is already mapped."""

    def __init__(self, config: MapBuildConfig | None = None) -> None:
        self.config = config or MapBuildConfig()
        self.stats = MapBuildStats()
        # Poses and points relative to the first pose's position: small_gicp's voxel keys hold 21 bits
        # per axis (+-200 km at 0.2 m), less than a UTM easting.
        self._origin: tuple[float, float] | None = None
        self._local: list[np.ndarray] = []  # each frame's points in its base frame, downsampled
        self._frames: list[np.ndarray] = []  # the same placed at the first-pass pose (the submaps)
        self._poses: list[np.ndarray] = []  # first-pass poses (x, y, yaw)
        self._recorded: list[np.ndarray] = []
        self._prior_covs: list[np.ndarray] = []
        self._edges: list[RelativeEdge] = []
        self._last: tuple[float, float, float] | None = None

    def wants(self, x_m: float, y_m: float, yaw_rad: float) -> bool:
        """Whether a frame at this pose is a new keyframe (moved or turned enough since the last)."""
        if self._last is None:
            return True
        lx, ly, lyaw = self._last
        c = self.config
        turned = abs(math.remainder(yaw_rad - lyaw, math.tau))
        return math.hypot(x_m - lx, y_m - ly) >= c.keyframe_m or turned >= c.keyframe_rad

    def add(
        self,
        points_base: np.ndarray,
        x_m: float,
        y_m: float,
        yaw_rad: float,
        pos_std_m: float | None = None,
        yaw_std_rad: float | None = None,
    ) -> bool:
        """Place one rig frame (base frame at its stamp, de-skewed) recorded at pose (x, y, yaw).

        ``pos_std_m`` and ``yaw_std_rad`` are the recorded pose's sigmas (the recording's estimate;
        None: ``pose_std_m`` / ``pose_yaw_std_rad``); they weigh it against the registrations.

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
        recorded = np.array([x_m - self._origin[0], y_m - self._origin[1], yaw_rad])
        sp = c.pose_std_m if pos_std_m is None else max(pos_std_m, 1e-3)
        sy = c.pose_yaw_std_rad if yaw_std_rad is None else max(yaw_std_rad, 1e-4)
        prior = np.diag([sp**2, sp**2, sy**2])
        pose = self._refine(pts, recorded, prior) if c.register else recorded
        down = np.asarray(small_gicp.voxelgrid_sampling(pts, c.voxel_m).points())[:, :3]
        self._local.append(down)
        self._frames.append(_place(down, pose))
        self._poses.append(pose)
        self._recorded.append(recorded)
        self._prior_covs.append(prior)
        self.stats.frames_used += 1
        return True

    def _near(self, x_m: float, y_m: float) -> np.ndarray:
        """Indices of the placed frames forming the submap at (x, y), nearest first."""
        c = self.config
        if not self._poses:
            return np.zeros(0, np.int64)
        xy = np.array([p[:2] for p in self._poses])
        d = np.hypot(xy[:, 0] - x_m, xy[:, 1] - y_m)
        near = np.flatnonzero(d <= c.submap_radius_m)
        return near[np.argsort(d[near], kind="stable")[: c.submap_frames]]

    def _refine(self, pts: np.ndarray, recorded: np.ndarray, prior: np.ndarray) -> np.ndarray:
        """The first-pass pose of a frame: the recorded pose fused with its registration to the submap
        when that passes every check (else the recorded pose); a passing registration also becomes an
        edge of the pose graph to the nearest submap frame.

        The registration (:class:`ScanToMapMatcher`: point-to-plane ICP with its Gauss-Newton
        covariance, opened up along directions no surface constrains) and the recorded pose are
        weighted by their information: along a street between parallel walls the registration slides,
        and there the recorded pose keeps the frame.
        """
        c = self.config
        near = self._near(float(recorded[0]), float(recorded[1]))
        target_pts = np.concatenate([self._frames[i] for i in sorted(near)]) if near.size else None
        if target_pts is None or len(target_pts) < _SUBMAP_MIN_POINTS:
            return recorded
        matcher = ScanToMapMatcher(
            target_pts,
            ScanMatchConfig(
                map_voxel_m=c.voxel_m,
                scan_voxel_m=c.voxel_m,
                roi_radius_m=c.max_range_m,
                max_correspondence_m=c.max_correspondence_m,
                max_iterations=c.max_iterations,
                min_inlier_share=c.min_inlier_share,
                max_scan_points=0,
            ),
        )
        try:
            match = matcher.match(pts, planar_matrix(*recorded))
        except MessageError:
            self.stats.frames_rejected_registration += 1
            return recorded
        meas = np.array(
            [match.x_m, match.y_m, recorded[2] + math.remainder(match.yaw_rad - recorded[2], math.tau)]
        )
        ok = (
            match.converged
            and match.inlier_share >= c.min_inlier_share
            and match.rmse_m <= c.max_rmse_m
            and np.isfinite(match.covariance).all()
        )
        fused = (
            recorded + prior @ np.linalg.solve(prior + match.covariance, meas - recorded) if ok else recorded
        )
        moved = math.hypot(fused[0] - recorded[0], fused[1] - recorded[1])
        if not ok or moved > c.max_correction_m or abs(fused[2] - recorded[2]) > c.max_correction_rad:
            self.stats.frames_rejected_registration += 1
            return recorded
        self.stats.frames_registered += 1
        self.stats.rmse_m.append(match.rmse_m)
        j = int(near[0])
        rot = np.eye(3)
        cj, sj = math.cos(self._poses[j][2]), math.sin(self._poses[j][2])
        rot[:2, :2] = [[cj, sj], [-sj, cj]]  # map -> frame j
        self._edges.append(
            RelativeEdge(
                i=len(self._poses),
                j=j,
                z=relative(meas, self._poses[j]),
                covariance=rot @ match.covariance @ rot.T,
            )
        )
        return fused

    def optimised_poses(self) -> np.ndarray:
        """(N, 3) poses of the placed frames after the pose graph (first-pass poses without edges)."""
        initial = np.array(self._poses).reshape(-1, 3)
        if not self._edges:
            return initial
        return optimise(initial, np.array(self._recorded), np.array(self._prior_covs), self._edges)

    def points(self) -> np.ndarray:
        """The map: every placed frame at its optimised pose, voxel-downsampled together, (N, 3) float64.
        Fills ``stats.correction_m`` (optimised against recorded poses of the registered frames)."""
        import small_gicp

        if not self._local or self._origin is None:
            return np.zeros((0, 3))
        poses = self.optimised_poses()
        registered = sorted({e.i for e in self._edges})
        rec = np.array(self._recorded)
        self.stats.correction_m = [float(np.hypot(*(poses[i, :2] - rec[i, :2]))) for i in registered]
        allpts = np.concatenate([_place(pts, pose) for pts, pose in zip(self._local, poses, strict=True)])
        out = np.asarray(small_gicp.voxelgrid_sampling(allpts, self.config.voxel_m).points())[:, :3].copy()
        out[:, 0] += self._origin[0]
        out[:, 1] += self._origin[1]
        return out


def _place(points: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """Base-frame points placed at planar pose (x, y, yaw)."""
    c, s = math.cos(pose[2]), math.sin(pose[2])
    out = points.copy()
    out[:, 0] = pose[0] + c * points[:, 0] - s * points[:, 1]
    out[:, 1] = pose[1] + s * points[:, 0] + c * points[:, 1]
    return out
