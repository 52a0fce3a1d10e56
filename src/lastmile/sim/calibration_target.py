"""A simulated LiDAR-camera calibration session: a checkerboard's image and a spinning LiDAR's sweep of it.

Frames: the LiDAR frame is x forward, y left, z up (the LiDAR's origin); the camera frame is the optical
one (x right, y down, z along the axis). ``camera_from_lidar`` maps LiDAR points into the camera frame;
``lidar_from_board`` places the board: its x axis along a row of squares, y along a column, z out of the
printed face, the origin at the first inner corner (OpenCV's object-point convention).

The image is rendered per pixel (each ray back-projected onto the board plane, the square's parity),
supersampled, blurred and noised; the sweep is the rings of a spinning sensor hitting the board, the
ground and a wall behind, with Gaussian range noise. Everything random comes from the given generator.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from lastmile.core.errors import ConfigError
from lastmile.sim.lidar_rig import VLP32C_ELEVATIONS_DEG


@dataclass(frozen=True, slots=True, kw_only=True)
class BoardSpec:
    """A printed checkerboard.

    Attributes:
        cols, rows: inner corners along a row (board x) and along a column (board y).
        square_m: side of one square, m.
        border_m: white border around the squares, m (the detector needs a quiet zone).
    """

    cols: int = 7
    rows: int = 5
    square_m: float = 0.1
    border_m: float = 0.06

    def __post_init__(self) -> None:
        if self.cols < 2 or self.rows < 2 or not self.square_m > 0 or not self.border_m >= 0:
            raise ConfigError(
                "BoardSpec: expected at least 2x2 inner corners, a positive square and a non-negative "
                f"border, got {self.cols}x{self.rows}, {self.square_m} m, {self.border_m} m"
            )

    def extent_m(self) -> tuple[float, float, float, float]:
        """The physical board (x_min, x_max, y_min, y_max) in the board frame, border included, m."""
        s, b = self.square_m, self.border_m
        return (-s - b, self.cols * s + b, -s - b, self.rows * s + b)


@dataclass(frozen=True, slots=True, kw_only=True)
class ImagerSpec:
    """A pinhole camera for rendering: K, the image size (pixels) and Brown-Conrady distortion
    (OpenCV's k1 k2 p1 p2 k3; zeros: none)."""

    fx_px: float
    fy_px: float
    cx_px: float
    cy_px: float
    width_px: int
    height_px: int
    distortion: tuple[float, float, float, float, float] = (0.0, 0.0, 0.0, 0.0, 0.0)

    def distorted(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Normalised image coordinates through the lens model (OpenCV's order of terms)."""
        k1, k2, p1, p2, k3 = self.distortion
        r2 = x * x + y * y
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        return (
            x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
            y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y,
        )

    def undistorted(self, xd: np.ndarray, yd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The inverse of :meth:`distorted` by fixed-point iteration (as OpenCV's undistortPoints)."""
        x, y = xd.copy(), yd.copy()
        for _ in range(20):
            dx, dy = self.distorted(x, y)
            x, y = x + (xd - dx), y + (yd - dy)
        return x, y

    def matrix(self) -> np.ndarray:
        """(3, 3) K."""
        return np.array([[self.fx_px, 0.0, self.cx_px], [0.0, self.fy_px, self.cy_px], [0.0, 0.0, 1.0]])


@dataclass(frozen=True, slots=True, kw_only=True)
class SpinningLidarSpec:
    """A ring LiDAR: beam elevations, a fixed azimuth step, Gaussian range noise.

    Defaults: the Velodyne VLP-32C of the simulator's front unit (``lidar_rig.VLP32C_ELEVATIONS_DEG``,
    0.2 degrees at 10 Hz), its datasheet's 3 cm range accuracy taken as 2 cm one sigma.
    """

    elevations_deg: tuple[float, ...] = VLP32C_ELEVATIONS_DEG
    azimuth_step_rad: float = math.radians(0.2)
    range_noise_m: float = 0.02
    max_range_m: float = 60.0


def render_board_image(
    imager: ImagerSpec,
    board: BoardSpec,
    camera_from_board: np.ndarray,
    rng: np.random.Generator,
    supersample: int = 3,
    noise_dn: float = 2.0,
) -> np.ndarray:
    """A grey (height, width) uint8 image of the board (black squares on white) over a grey background.

    Args:
        imager: intrinsics and size.
        board: the board.
        camera_from_board: (4, 4) the board's pose in the camera's optical frame.
        rng: noise source.
        supersample: rays per pixel along each axis (anti-aliasing).
        noise_dn: Gaussian pixel noise, digital numbers.
    """
    h, w = imager.height_px, imager.width_px
    n = supersample
    offsets = (np.arange(n) + 0.5) / n - 0.5
    rot, t = camera_from_board[:3, :3], camera_from_board[:3, 3]
    normal = rot[:, 2]
    x0, x1, y0, y1 = board.extent_m()
    out = np.full((h, w), 110.0)
    # Only the board's projected box is traced (the rest is background).
    outline = np.array([[x, y, 0.0] for x in (x0, x1) for y in (y0, y1)]) @ rot.T + t
    if (outline[:, 2] > 0.05).all():
        xd, yd = imager.distorted(outline[:, 0] / outline[:, 2], outline[:, 1] / outline[:, 2])
        uv = np.column_stack([imager.fx_px * xd + imager.cx_px, imager.fy_px * yd + imager.cy_px])
        # Distortion bends the board's edges between its corners: a margin of 2 % of the image.
        pad = 2 + (int(0.02 * max(w, h)) if any(imager.distortion) else 0)
        u_lo, v_lo = np.clip(np.floor(uv.min(axis=0)).astype(int) - pad, 0, (w, h))
        u_hi, v_hi = np.clip(np.ceil(uv.max(axis=0)).astype(int) + pad, 0, (w, h))
    else:
        u_lo, v_lo, u_hi, v_hi = 0, 0, w, h
    if u_hi <= u_lo or v_hi <= v_lo:
        return _noised(out, rng, noise_dn)
    v, u = np.mgrid[v_lo:v_hi, u_lo:u_hi].astype(np.float64)
    img = np.zeros(u.shape)
    for du in offsets:
        for dv in offsets:
            # OpenCV's pixel (u, v) is centred on (u, v): its samples lie within half a pixel of it.
            xn, yn = (u + du - imager.cx_px) / imager.fx_px, (v + dv - imager.cy_px) / imager.fy_px
            if any(imager.distortion):
                xn, yn = imager.undistorted(xn, yn)
            rays = np.stack([xn, yn, np.ones_like(u)], axis=-1)
            # Ray s * r meets the plane normal . (x - t) = 0 at s = normal . t / normal . r.
            denom = rays @ normal
            with np.errstate(divide="ignore", invalid="ignore"):
                s = (normal @ t) / denom
            hit = rays * s[..., None] - t
            local = hit @ rot  # board coordinates (x, y, ~0)
            bx, by = local[..., 0], local[..., 1]
            on_board = (s > 0) & (bx >= x0) & (bx <= x1) & (by >= y0) & (by <= y1)
            sq = board.square_m
            inner = (bx >= -sq) & (bx <= board.cols * sq) & (by >= -sq) & (by <= board.rows * sq)
            parity = (np.floor(bx / sq) + np.floor(by / sq)).astype(np.int64) % 2 == 0
            sample = np.where(on_board, np.where(inner & parity, 20.0, 235.0), 110.0)
            img += sample
    out[v_lo:v_hi, u_lo:u_hi] = img / (n * n)
    return _noised(out, rng, noise_dn)


def _noised(img: np.ndarray, rng: np.random.Generator, noise_dn: float) -> np.ndarray:
    noisy = img + rng.normal(0.0, noise_dn, img.shape)
    return np.clip(np.rint(noisy), 0, 255).astype(np.uint8)


def sweep_board(
    lidar: SpinningLidarSpec,
    board: BoardSpec,
    lidar_from_board: np.ndarray,
    rng: np.random.Generator,
    ground_z_m: float = -1.8,
    wall_x_m: float = 15.0,
    azimuth_window_rad: float = math.radians(100.0),
) -> tuple[np.ndarray, np.ndarray]:
    """One sweep: (N, 3) points in the LiDAR frame, and (N,) True where the point is on the board.

    Rays within ``azimuth_window_rad`` of the x axis each hit the nearest of the board, the ground
    (z = ``ground_z_m``) and a wall (x = ``wall_x_m``); the range is noised along the ray.
    """
    elev = np.radians(np.array(lidar.elevations_deg))
    half = azimuth_window_rad / 2.0
    azim = np.arange(-half, half, lidar.azimuth_step_rad)
    e, a = np.meshgrid(elev, azim, indexing="ij")
    rays = np.stack([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)], axis=-1).reshape(-1, 3)
    rng_m = np.full(len(rays), np.inf)
    on_board = np.zeros(len(rays), dtype=bool)
    rot, t = lidar_from_board[:3, :3], lidar_from_board[:3, 3]
    normal = rot[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        s_board = (normal @ t) / (rays @ normal)
        s_ground = ground_z_m / rays[:, 2]
        s_wall = wall_x_m / rays[:, 0]
    local = (rays * s_board[:, None] - t) @ rot
    x0, x1, y0, y1 = board.extent_m()
    hits_board = (
        (s_board > 0) & (local[:, 0] >= x0) & (local[:, 0] <= x1) & (local[:, 1] >= y0) & (local[:, 1] <= y1)
    )
    for s, is_board in ((s_ground, False), (s_wall, False), (s_board, True)):
        valid = (s > 0) & (s < rng_m) & (s < lidar.max_range_m)
        if is_board:
            valid &= hits_board
        rng_m = np.where(valid, s, rng_m)
        on_board = np.where(valid, is_board, on_board)
    keep = np.isfinite(rng_m)
    noisy = rng_m[keep] + rng.normal(0.0, lidar.range_noise_m, int(keep.sum()))
    return rays[keep] * noisy[:, None], on_board[keep]


def board_poses(
    rng: np.random.Generator,
    n: int,
    board: BoardSpec,
    distance_m: tuple[float, float] = (3.0, 6.0),
    lateral_m: float = 1.2,
    height_m: tuple[float, float] = (-0.5, 0.3),
    tilt_rad: tuple[float, float, float] = (math.radians(35.0), math.radians(25.0), math.radians(20.0)),
) -> list[np.ndarray]:
    """``n`` boards held in front of the LiDAR, as a calibration session's operator moves them.

    Each is (4, 4) ``lidar_from_board``: its centre ``distance_m`` ahead, up to ``lateral_m`` aside and
    ``height_m`` above the LiDAR, facing it, turned about the LiDAR's z, y and x axes through its centre
    by uniform angles up to ``tilt_rad`` (yaw, pitch, roll).
    """
    # Facing the sensor: board x to the viewer's right (-y), board y up (+z), out of the face (-x).
    facing = np.array([[0.0, 0.0, -1.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    centre_board = np.array(
        [(board.cols - 1) * board.square_m / 2.0, (board.rows - 1) * board.square_m / 2.0, 0.0]
    )
    out = []
    for _ in range(n):
        yaw, pitch, roll = (rng.uniform(-a, a) for a in tilt_rad)
        cz, sz, cy, sy, cx, sx = (
            math.cos(yaw),
            math.sin(yaw),
            math.cos(pitch),
            math.sin(pitch),
            math.cos(roll),
            math.sin(roll),
        )
        rz = np.array([[cz, -sz, 0.0], [sz, cz, 0.0], [0.0, 0.0, 1.0]])
        ry = np.array([[cy, 0.0, sy], [0.0, 1.0, 0.0], [-sy, 0.0, cy]])
        rx = np.array([[1.0, 0.0, 0.0], [0.0, cx, -sx], [0.0, sx, cx]])
        rot = rz @ ry @ rx @ facing
        centre = np.array(
            [rng.uniform(*distance_m), rng.uniform(-lateral_m, lateral_m), rng.uniform(*height_m)]
        )
        pose = np.eye(4)
        pose[:3, :3] = rot
        pose[:3, 3] = centre - rot @ centre_board
        out.append(pose)
    return out


PROJECT_CAMERA = ImagerSpec(
    fx_px=1462.4, fy_px=1462.4, cx_px=1024.0, cy_px=768.0, width_px=2048, height_px=1536
)
"""The simulator's 2048 x 1536, 70-degree cameras (``sim.camera.default_cameras``), undistorted."""


def simulate_session(
    rng: np.random.Generator,
    lidar_from_boards: list[np.ndarray],
    camera_from_lidar: np.ndarray,
    board: BoardSpec,
    imager: ImagerSpec = PROJECT_CAMERA,
    lidar: SpinningLidarSpec | None = None,
    sweeps_per_view: int = 1,
) -> list[tuple[np.ndarray, np.ndarray]]:
    """Each board pose's (image (H, W) uint8, cloud (N, 3) float64 in the LiDAR frame, ``sweeps_per_view``
    sweeps of the board held still, stacked)."""
    spec = lidar or SpinningLidarSpec()
    out = []
    for lidar_from_board in lidar_from_boards:
        image = render_board_image(imager, board, camera_from_lidar @ lidar_from_board, rng, supersample=2)
        sweeps = [sweep_board(spec, board, lidar_from_board, rng)[0] for _ in range(sweeps_per_view)]
        out.append((image, np.concatenate(sweeps)))
    return out
