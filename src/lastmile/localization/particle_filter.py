"""NUS AMCL: adaptive Monte Carlo localization on a 2D occupancy map built from the LiDAR.

The NUS golf car (IV-A) localizes against an a-priori laser map with AMCL (Thrun, Burgard and Fox,
Probabilistic Robotics, ch. 8: KLD-sampling MCL with random-particle recovery). As there and in ROS's
``amcl`` (whose documented defaults are used here): the odometry motion model samples each particle's
rotation-translation-rotation with noise ``alpha1..4``; the likelihood-field model scores a scan's
endpoints by their distance to the nearest occupied cell (Gaussian ``sigma_hit`` mixed with a uniform
``z_rand``); resampling is low-variance, only after the vehicle has moved ``update_min_d`` or turned
``update_min_a``; the particle count follows KLD sampling between ``min_particles`` and ``max_particles``;
and when the short-term average likelihood falls below the long-term one (``alpha_fast``, ``alpha_slow``)
random particles are injected, the safeguard that lets a kidnapped or lost vehicle recover. The output
is the weighted mean pose with its covariance, from which the confidence follows.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.ndimage import distance_transform_edt
from scipy.stats import norm

from lastmile.core.errors import ConfigError, MessageError


@dataclass(frozen=True, slots=True, kw_only=True)
class OccupancyGrid:
    """A 2D occupancy map.

    Attributes:
        occupied: (H, W) bool, row i is y = origin_y + (i + 0.5) * resolution, column j likewise in x.
        resolution_m: cell size, m.
        origin_xy: map-frame coordinates of the grid's (0, 0) corner, m.
    """

    occupied: np.ndarray
    resolution_m: float
    origin_xy: tuple[float, float] = (0.0, 0.0)

    def __post_init__(self) -> None:
        occ = np.asarray(self.occupied)
        if occ.ndim != 2 or occ.dtype != bool or occ.size == 0:
            raise MessageError(
                f"OccupancyGrid.occupied: expected a non-empty (H, W) bool array, got {occ.shape}"
            )
        if not (self.resolution_m > 0 and math.isfinite(self.resolution_m)):
            raise MessageError(
                f"OccupancyGrid.resolution_m: expected a positive number, got {self.resolution_m}"
            )

    def distance_field_m(self) -> np.ndarray:
        """(H, W) distance from each cell to the nearest occupied cell, m."""
        return distance_transform_edt(~np.asarray(self.occupied)) * self.resolution_m

    def free_cells_xy(self) -> np.ndarray:
        """(n, 2) centres of the free cells, m."""
        rows, cols = np.nonzero(~np.asarray(self.occupied))
        return np.c_[cols + 0.5, rows + 0.5] * self.resolution_m + np.asarray(self.origin_xy)


@dataclass(frozen=True, slots=True, kw_only=True)
class AmclConfig:
    """AMCL parameters; defaults are ROS amcl's documented ones (and Probabilistic Robotics, table 8.x).

    Attributes:
        min_particles, max_particles: KLD sampling bounds.
        kld_err, kld_z: KLD sampling: the error bound and the upper standard-normal quantile.
        kld_bin_m, kld_bin_rad: histogram bins of KLD sampling.
        alpha1..alpha4: odometry noise: rotation from rotation, rotation from translation, translation
            from translation, translation from rotation.
        z_hit, z_rand: likelihood-field mixture weights.
        sigma_hit_m: sigma of a scan endpoint's distance to the nearest obstacle, m.
        max_range_m: returns at or beyond this are no-hits, m.
        beams: beams used per scan (evenly subsampled).
        update_min_d_m, update_min_a_rad: filter updates need this much motion.
        alpha_slow, alpha_fast: the long- and short-term likelihood averages' rates (recovery).
        max_pos_std_m: the estimate is confident while its position sigma (worst axis) is within this.
    """

    min_particles: int = 100
    max_particles: int = 5000
    kld_err: float = 0.01
    kld_z: float = 0.99
    kld_bin_m: float = 0.5
    kld_bin_rad: float = math.radians(10.0)
    alpha1: float = 0.2
    alpha2: float = 0.2
    alpha3: float = 0.2
    alpha4: float = 0.2
    z_hit: float = 0.95
    z_rand: float = 0.05
    sigma_hit_m: float = 0.2
    max_range_m: float = 30.0
    beams: int = 60
    update_min_d_m: float = 0.2
    update_min_a_rad: float = math.pi / 6.0
    alpha_slow: float = 0.001
    alpha_fast: float = 0.1
    max_pos_std_m: float = 0.3

    def __post_init__(self) -> None:
        if not 1 <= self.min_particles <= self.max_particles:
            raise ConfigError(
                f"AmclConfig: expected 1 <= min_particles <= max_particles, got {self.min_particles}, "
                f"{self.max_particles}"
            )
        if not (0.0 < self.alpha_slow < self.alpha_fast <= 1.0):
            raise ConfigError(
                "AmclConfig: expected 0 < alpha_slow < alpha_fast <= 1, "
                f"got {self.alpha_slow}, {self.alpha_fast}"
            )
        for name in ("sigma_hit_m", "max_range_m", "kld_err", "kld_bin_m", "kld_bin_rad", "max_pos_std_m"):
            value = getattr(self, name)
            if not (value > 0 and math.isfinite(value)):
                raise ConfigError(f"AmclConfig.{name}: expected a positive number, got {value!r}")
        if self.beams < 1 or not math.isclose(self.z_hit + self.z_rand, 1.0):
            raise ConfigError(
                f"AmclConfig: expected beams >= 1 and z_hit + z_rand = 1, got {self.beams}, "
                f"{self.z_hit} + {self.z_rand}"
            )


@dataclass(frozen=True, slots=True, kw_only=True)
class AmclEstimate:
    """Weighted mean pose (x_m, y_m, yaw_rad), its (3, 3) covariance, particle count and confidence."""

    x_m: float
    y_m: float
    yaw_rad: float
    covariance: np.ndarray
    pos_std_m: float
    particles: int
    random_injection: float
    confident: bool


class AmclLocalizer:
    """Particles (x, y, yaw) with weights; ``initialise``, then ``motion`` and ``scan`` as data arrive."""

    def __init__(self, grid: OccupancyGrid, config: AmclConfig | None, rng: np.random.Generator) -> None:
        self.config = c = config or AmclConfig()
        self._grid = grid
        self._field = grid.distance_field_m()
        self._free = grid.free_cells_xy()
        self._rng = rng
        self._particles = np.zeros((c.min_particles, 3))
        self._weights = np.full(c.min_particles, 1.0 / c.min_particles)
        self._w_slow = self._w_fast = 0.0
        self._moved = np.zeros(2)  # distance and rotation since the last update
        self._z_rand_density = c.z_rand / c.max_range_m

    def initialise(self, pose: tuple[float, float, float], std: tuple[float, float, float]) -> None:
        """Particles from a Gaussian around ``pose`` (x_m, y_m, yaw_rad) with per-axis ``std``."""
        n = self.config.max_particles // 2
        self._particles = self._rng.normal(pose, std, (n, 3))
        self._weights = np.full(n, 1.0 / n)

    def motion(self, delta: tuple[float, float, float]) -> None:
        """Odometry motion since the last call: (dx_m, dy_m, dyaw_rad) in the previous base frame."""
        c, rng = self.config, self._rng
        dx, dy, dyaw = delta
        trans = math.hypot(dx, dy)
        rot1 = math.atan2(dy, dx) if trans > 1e-3 else 0.0
        rot2 = dyaw - rot1
        n = self._particles.shape[0]
        # Thrun's sample_motion_model_odometry; small rotations are folded to avoid the reverse-motion
        # singularity (ROS amcl does the same).
        r1 = min(abs(rot1), abs(math.pi - abs(rot1)))
        r2 = min(abs(rot2), abs(math.pi - abs(rot2)))
        s_rot1 = math.sqrt(c.alpha1 * r1**2 + c.alpha2 * trans**2)
        s_trans = math.sqrt(c.alpha3 * trans**2 + c.alpha4 * (r1**2 + r2**2))
        s_rot2 = math.sqrt(c.alpha1 * r2**2 + c.alpha2 * trans**2)
        h1 = rot1 - rng.normal(0.0, s_rot1 + 1e-12, n)
        ht = trans - rng.normal(0.0, s_trans + 1e-12, n)
        h2 = rot2 - rng.normal(0.0, s_rot2 + 1e-12, n)
        p = self._particles
        p[:, 0] += ht * np.cos(p[:, 2] + h1)
        p[:, 1] += ht * np.sin(p[:, 2] + h1)
        p[:, 2] = np.remainder(p[:, 2] + h1 + h2 + math.pi, 2 * math.pi) - math.pi
        self._moved += (trans, abs(dyaw))

    def scan(
        self, ranges_m: np.ndarray, angles_rad: np.ndarray, sensor_xy_base: tuple[float, float] = (0.0, 0.0)
    ) -> bool:
        """Weigh the particles by a planar scan and resample; False when the vehicle has not moved enough.

        Args:
            ranges_m: (B,) ranges; NaN, inf or >= max_range_m are no-hits.
            angles_rad: (B,) beam angles in the base frame.
            sensor_xy_base: the scanner's position in the base frame, m.
        """
        c = self.config
        ranges = np.asarray(ranges_m, dtype=float)
        angles = np.asarray(angles_rad, dtype=float)
        if ranges.shape != angles.shape or ranges.ndim != 1:
            raise MessageError(
                "AmclLocalizer.scan: expected equal (B,) ranges and angles, "
                f"got {ranges.shape}, {angles.shape}"
            )
        if self._moved[0] < c.update_min_d_m and self._moved[1] < c.update_min_a_rad:
            return False
        self._moved[:] = 0.0
        hit = np.isfinite(ranges) & (ranges < c.max_range_m)
        idx = np.flatnonzero(hit)
        if idx.size > c.beams:
            idx = idx[np.linspace(0, idx.size - 1, c.beams).round().astype(int)]
        if idx.size == 0:
            return False
        likelihood, mean_likelihood = self._likelihood(ranges[idx], angles[idx], sensor_xy_base)
        w = self._weights * likelihood
        total = float(w.sum())
        self._w_slow += c.alpha_slow * (mean_likelihood - self._w_slow) if self._w_slow else mean_likelihood
        self._w_fast += c.alpha_fast * (mean_likelihood - self._w_fast) if self._w_fast else mean_likelihood
        self._weights = w / total if total > 0 else np.full(w.size, 1.0 / w.size)
        self._resample()
        return True

    def _likelihood(
        self, ranges: np.ndarray, angles: np.ndarray, sensor_xy: tuple[float, float]
    ) -> tuple[np.ndarray, float]:
        """Per particle, the product over beams of z_hit N(dist; 0, sigma_hit) + z_rand / max_range.

        Returns:
            The products scaled so the best particle has 1 (they underflow otherwise), and the mean
            over particles of the per-beam geometric mean: a likelihood comparable from scan to scan
            for the recovery averages.
        """
        c, grid = self.config, self._grid
        p = self._particles
        cs, sn = np.cos(p[:, 2:3]), np.sin(p[:, 2:3])
        lx = sensor_xy[0] + ranges * np.cos(angles)
        ly = sensor_xy[1] + ranges * np.sin(angles)
        ex = p[:, 0:1] + cs * lx - sn * ly
        ey = p[:, 1:2] + sn * lx + cs * ly
        col = np.floor((ex - grid.origin_xy[0]) / grid.resolution_m).astype(int)
        row = np.floor((ey - grid.origin_xy[1]) / grid.resolution_m).astype(int)
        h, w = self._field.shape
        inside = (row >= 0) & (row < h) & (col >= 0) & (col < w)
        dist = np.full(ex.shape, c.max_range_m)
        dist[inside] = self._field[row[inside], col[inside]]
        per_beam = c.z_hit * norm.pdf(dist, scale=c.sigma_hit_m) + self._z_rand_density
        # Log-sum for the product, shifted so the largest particle's likelihood is 1 (scale-free).
        log_l = np.log(per_beam).sum(axis=1)
        return np.exp(log_l - log_l.max()), float(np.mean(np.exp(log_l / ranges.size)))

    @property
    def random_injection(self) -> float:
        """Share of particles replaced by random ones at the next resampling: max(0, 1 - w_fast / w_slow)."""
        return max(0.0, 1.0 - self._w_fast / self._w_slow) if self._w_slow > 0 else 0.0

    def _resample(self) -> None:
        rng = self._rng
        # KLD sampling counts the histogram bins the resampled set occupies, then draws that many.
        n = self._kld_count(self._particles[self._low_variance(self._weights.size)])
        particles = self._particles[self._low_variance(n)].copy()
        inject = rng.random(n) < self.random_injection
        if inject.any() and self._free.size:
            cells = self._free[rng.integers(0, self._free.shape[0], int(inject.sum()))]
            jitter = rng.uniform(-0.5, 0.5, cells.shape) * self._grid.resolution_m
            particles[inject, :2] = cells + jitter
            particles[inject, 2] = rng.uniform(-math.pi, math.pi, int(inject.sum()))
        self._particles = particles
        self._weights = np.full(n, 1.0 / n)

    def _low_variance(self, n: int) -> np.ndarray:
        """Indices of ``n`` particles drawn by low-variance (systematic) resampling of the weights."""
        positions = (self._rng.random() + np.arange(n)) / n
        return np.minimum(np.searchsorted(np.cumsum(self._weights), positions), self._weights.size - 1)

    def _kld_count(self, p: np.ndarray) -> int:
        """KLD sampling: particles needed for the histogram bins the set ``p`` occupies (Fox 2003)."""
        c = self.config
        bins = np.c_[
            np.floor(p[:, 0] / c.kld_bin_m),
            np.floor(p[:, 1] / c.kld_bin_m),
            np.floor(p[:, 2] / c.kld_bin_rad),
        ]
        k = np.unique(bins, axis=0).shape[0]
        if k <= 1:
            return c.min_particles
        z = float(norm.ppf(c.kld_z))
        a = 2.0 / (9.0 * (k - 1))
        n = (k - 1) / (2.0 * c.kld_err) * (1.0 - a + math.sqrt(a) * z) ** 3
        return int(min(max(math.ceil(n), c.min_particles), c.max_particles))

    def estimate(self) -> AmclEstimate:
        """Weighted mean (circular for yaw) and covariance of the particles."""
        p, w = self._particles, self._weights
        mean_xy = w @ p[:, :2]
        yaw = math.atan2(float(w @ np.sin(p[:, 2])), float(w @ np.cos(p[:, 2])))
        d = np.c_[p[:, :2] - mean_xy, np.remainder(p[:, 2] - yaw + math.pi, 2 * math.pi) - math.pi]
        cov = (d * w[:, None]).T @ d
        pos_std = math.sqrt(max(float(np.linalg.eigvalsh(cov[:2, :2])[-1]), 0.0))
        return AmclEstimate(
            x_m=float(mean_xy[0]),
            y_m=float(mean_xy[1]),
            yaw_rad=yaw,
            covariance=cov,
            pos_std_m=pos_std,
            particles=int(p.shape[0]),
            random_injection=self.random_injection,
            confident=pos_std <= self.config.max_pos_std_m,
        )
