"""Ground segmentation, chosen by name: WATonoBus's HD-map adaptive grid and aUToronto's Himmelsbach.

Both take (N, 3) base-frame points (z up, z = 0 on flat ground under the rear axle) and return an
(N,) bool mask of ground points. Points below the fitted surface (multipath and mirror reflections
under the road) count as ground: they can never be obstacles.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
import numpy.typing as npt

from lastmile.core.errors import ConfigError
from lastmile.perception.ground_kernel import (
    accept_planes,
    classify_ring,
    low_quantile,
    plane_residuals,
    plane_systems,
    ring_points,
    ring_prelude,
    weighted_sums,
)
from lastmile.perception.himmelsbach import HimmelsbachConfig, HimmelsbachGroundSegmenter
from lastmile.perception.himmelsbach_kernel import segment_members
from lastmile.perception.road_region import RoadMask

BoolArray = npt.NDArray[np.bool_]


class GroundSegmenter(Protocol):
    """Splits a base-frame cloud into ground and the rest."""

    def segment(self, xyz_m: npt.ArrayLike, road_mask: RoadMask | None = None) -> BoolArray:
        """(N,) bool, True for ground points of the (N, 3) cloud."""
        ...


@dataclass(frozen=True, slots=True, kw_only=True)
class AdaptiveGridConfig:
    """WATonoBus's adaptive grid ground segmentation.

    Attributes:
        ring_edges_m: radial edges of the grid rings; cells get longer with range, where points
            thin out (strictly increasing, first 0).
        sectors_per_ring: azimuth sectors in each ring (one per ring).
        threshold_near_m: ground tolerance above the fitted surface at range 0 (strict near the bus).
        threshold_per_m: growth of the tolerance per metre of range (lenient far away, where
            beam divergence, pitch noise and range noise grow).
        threshold_max_m: cap of the tolerance.
        seed_window_m: first pass: only points at most this far above the prior surface (the inner
            ring's plane, extrapolated) can be seeds.
        max_below_m: ... and at most this far below it (deeper returns are noise).
        seed_quantile: the seeds' reference height is this quantile of a region's heights.
        seed_band_m: seeds lie within this of that reference.
        max_slope: steepest road-surface slope accepted for a cell's plane (rise over run).
        min_fit_points: fewer points than this keep the prior (inner ring's) plane.
        max_step_m: a cell's plane may depart from its prior by at most this much at the centroid
            of the points it was fitted to; more keeps the prior. A cell the road is hidden in
            (only a car's side seen by a horizontal beam, all at one height) otherwise fits its
            plane through the car and calls the car ground. 0.5 m passes a high kerb or a raised
            verge (0.15-0.35 m) fitted from the road's prior in the first ring.
        prior_weight: regularisation pulling a cell's plane toward its prior (in squared-metre units
            of one point), so sparse cells cannot tilt wildly.
        iterations: refits with the shrinking window.
        smooth_sigmas, smooth_floor_m: where a region's fitted surface is smooth, its tolerance
            shrinks to ``max(smooth_floor_m, smooth_sigmas * rms)`` of the final fit's residuals
            within the tolerance (never above the range-dependent one). The range-dependent
            tolerance allows for the range noise, pitch error and beam divergence of a rough or
            distant surface; on a smooth paved cell (residuals ~1 cm) it let a grazing ring's
            returns off a goose's body 0.10-0.13 m up pass as ground. 4 sigma keeps the road's
            own returns ground; the 0.10 m floor keeps road texture, ruts and a ring grazing a
            bird's feet ground whatever the fit.
        level_change_fallback, fallback: where a region's own plane is rejected while at least
            ``min_fit_points`` of its points lie more than ``max_below_m`` below the plane it
            kept (the road continues below a level change: an underpass, a lower street beyond a
            wall or a ramp), its points take the labels of Himmelsbach's line fit per segment
            (``fallback``), which follows the lower surface; the grid alone would call everything
            below its kept plane ground (a pedestrian standing 1.7 m below it included).
        edge_margin_m: within this of the HD map's road edge (either side), a point that is not
            ground on its own part's plane is ground when it lies within the tolerance of the
            cell's other part (road or off-road). The map's edge and the real one differ by the
            map's error (HD maps are surveyed to about 0.1 m) plus the localization's (the
            vehicle places the map about as well again): a strip of sidewalk the map calls road
            stood 0.15 m out of the road plane, a row of small objects that kept their place
            beside the moving shuttle (tracked as moving at its speed). 0 turns the rule off.
    """

    ring_edges_m: tuple[float, ...] = (0.0, 6.0, 12.0, 20.0, 30.0, 45.0, 65.0, 120.0)
    sectors_per_ring: tuple[int, ...] = (8, 16, 24, 32, 32, 32, 32)
    threshold_near_m: float = 0.12
    threshold_per_m: float = 0.004
    threshold_max_m: float = 0.35
    seed_window_m: float = 1.0
    max_below_m: float = 1.0
    seed_band_m: float = 0.15
    seed_quantile: float = 0.2
    max_slope: float = 0.2
    min_fit_points: int = 8
    max_step_m: float = 0.5
    prior_weight: float = 4.0
    iterations: int = 2
    smooth_sigmas: float = 4.0
    smooth_floor_m: float = 0.10
    level_change_fallback: bool = True
    fallback: HimmelsbachConfig = field(default_factory=HimmelsbachConfig)
    edge_margin_m: float = 0.25

    def __post_init__(self) -> None:
        e = self.ring_edges_m
        if len(e) < 2 or e[0] != 0.0 or any(b <= a for a, b in itertools.pairwise(e)):
            raise ConfigError(
                f"AdaptiveGridConfig.ring_edges_m: expected strictly increasing from 0, got {e}"
            )
        if len(self.sectors_per_ring) != len(e) - 1 or min(self.sectors_per_ring) < 1:
            raise ConfigError(
                f"AdaptiveGridConfig.sectors_per_ring: expected {len(e) - 1} positive counts, "
                f"got {self.sectors_per_ring}"
            )
        positive = (
            "threshold_near_m",
            "threshold_max_m",
            "seed_window_m",
            "max_slope",
            "max_below_m",
            "seed_band_m",
            "max_step_m",
            "smooth_sigmas",
            "smooth_floor_m",
        )
        for name in positive:
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ConfigError(f"AdaptiveGridConfig.{name}: expected a positive number, got {v}")
        if not (math.isfinite(self.edge_margin_m) and 0.0 <= self.edge_margin_m <= 2.0):
            raise ConfigError(f"AdaptiveGridConfig.edge_margin_m: expected 0..2 m, got {self.edge_margin_m}")
        if self.threshold_max_m < self.threshold_near_m or self.threshold_per_m < 0:
            raise ConfigError(
                "AdaptiveGridConfig: expected threshold_per_m >= 0 and threshold_max_m >= threshold_near_m, "
                f"got {self.threshold_per_m}, {self.threshold_max_m} < {self.threshold_near_m}"
            )
        if not 0.0 < self.seed_quantile < 1.0:
            raise ConfigError(
                f"AdaptiveGridConfig.seed_quantile: expected in (0, 1), got {self.seed_quantile}"
            )
        if self.min_fit_points < 3 or self.iterations < 1 or self.prior_weight < 0:
            raise ConfigError(
                "AdaptiveGridConfig: expected min_fit_points >= 3, iterations >= 1, prior_weight >= 0, got "
                f"{self.min_fit_points}, {self.iterations}, {self.prior_weight}"
            )

    def threshold_m(self, range_m: npt.ArrayLike) -> npt.NDArray[np.float64]:
        """Ground tolerance (m) at the given ranges: strict near, lenient far."""
        r = np.asarray(range_m, dtype=np.float64)
        return np.minimum(self.threshold_near_m + self.threshold_per_m * r, self.threshold_max_m)


class AdaptiveGridGroundSegmenter:
    """WATonoBus's adaptive grid: polar cells growing with range, split by HD-map road regions.

    Each ring of cells is fitted after the ring inside it, starting from the inner ring's plane as a
    prior (the flat plane z = 0 for the first ring), so the surface follows slopes outward. In every
    cell the road part and the off-road part (from the HD map's road region) get separate planes
    z = a + b x + c y, fitted by weighted least squares to points near the prior and then near the
    previous fit, with a range-dependent tolerance. A plane steeper than ``max_slope`` or with too
    few points is replaced by its prior. Without a road mask every point is treated as road.
    """

    def __init__(self, config: AdaptiveGridConfig | None = None) -> None:
        self.config = config or AdaptiveGridConfig()
        self._himmelsbach = HimmelsbachGroundSegmenter(self.config.fallback)

    def segment(self, xyz_m: npt.ArrayLike, road_mask: RoadMask | None = None) -> BoolArray:
        cfg = self.config
        fallback_idx: list[np.ndarray] = []
        edge_candidates: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        p = np.asarray(xyz_m, dtype=np.float64).reshape(-1, 3)
        n = len(p)
        ground = np.zeros(n, dtype=bool)
        if n == 0:
            return ground
        # Contiguous columns: every later step is a 1-D operation on them.
        x, y, z = (np.ascontiguousarray(p[:, i]) for i in range(3))
        az = np.arctan2(y, x)
        road = np.ones(n, dtype=bool) if road_mask is None else np.asarray(road_mask(p[:, :2]), dtype=bool)
        # One compiled pass (ground_kernel.ring_prelude): range, tolerance (cfg.threshold_m's
        # arithmetic), ring = number of edges at or below the range minus one, and the points
        # grouped by ring once (a stable counting sort) instead of a scan of the cloud per ring.
        tol, by_ring, ring_start = ring_prelude(
            x,
            y,
            np.asarray(cfg.ring_edges_m, dtype=np.float64),
            cfg.threshold_near_m,
            cfg.threshold_per_m,
            cfg.threshold_max_m,
            len(cfg.sectors_per_ring),
        )
        # Prior planes of the previous ring per sector (a, b, c); the first ring's prior is z = 0.
        prev_planes = np.zeros((1, 2, 3))
        prev_sectors = 1
        for k, n_sec in enumerate(cfg.sectors_per_ring):
            idx = by_ring[ring_start[k] : ring_start[k + 1]]
            sec_centres = (np.arange(n_sec) + 0.5) * (2 * math.pi / n_sec) - math.pi
            inner = (
                np.floor((sec_centres + math.pi) / (2 * math.pi / prev_sectors)).astype(int) % prev_sectors
            )
            prior = prev_planes[inner]  # (n_sec, 2, 3)
            if len(idx) == 0:
                prev_planes, prev_sectors = prior, n_sec
                continue
            px, py, pz, window, region = ring_points(idx, x, y, z, az, tol, road, 2 * math.pi / n_sec, n_sec)
            planes = prior.reshape(-1, 3).copy()
            low = np.zeros(0)
            for it in range(cfg.iterations + 1):
                # Compiled passes (ground_kernel): the same arithmetic as array expressions.
                res = plane_residuals(px, py, pz, region, planes)
                if it == cfg.iterations:
                    break
                if it == 0:
                    # Seeds: points within seed_band_m of the region's low quantile (not its
                    # minimum: the foot of a curb face or one deep noise return would win that).
                    low = low_quantile(
                        res, region, 2 * n_sec, cfg.max_below_m, cfg.seed_window_m, _HIST_BIN_M,
                        cfg.seed_quantile,
                    )  # fmt: skip
                # Weight 1 for the seeds, then Tukey weights: points near the surface count most,
                # snow and object feet least. Only weighted points enter the sums.
                sums = weighted_sums(
                    px, py, pz, res, region, 2 * n_sec, it == 0, low, window,
                    cfg.max_below_m, cfg.seed_window_m, cfg.seed_band_m,
                )  # fmt: skip
                planes, _ = _fit_planes(sums, prior.reshape(-1, 3), cfg)
            # Tolerance per region: the range-dependent one, tightened where the fit is smooth.
            below = classify_ring(
                idx,
                res,
                region,
                window,
                2 * n_sec,
                cfg.smooth_floor_m,
                cfg.smooth_sigmas,
                ground,
                cfg.max_below_m,
            )
            if road_mask is not None and cfg.edge_margin_m > 0.0:
                edge_candidates.append(_edge_candidates(idx, px, py, pz, window, region, planes, ground))
            poor = self._poor_points(below, region) if cfg.level_change_fallback else None
            if poor is not None:
                fallback_idx.append(idx[poor])
            prev_planes, prev_sectors = planes.reshape(n_sec, 2, 3), n_sec
        if edge_candidates:
            assert road_mask is not None
            self._ground_at_road_edge(edge_candidates, road_mask, ground)
        if fallback_idx:
            self._apply_fallback(p, az, np.concatenate(fallback_idx), road_mask, ground)
        return ground

    def _ground_at_road_edge(
        self,
        candidates: list[tuple[np.ndarray, np.ndarray, np.ndarray]],
        road_mask: RoadMask,
        ground: BoolArray,
    ) -> None:
        """Marks as ground the candidates (:func:`_edge_candidates`, every ring's) that lie within
        ``edge_margin_m`` of the map's road edge.

        Args:
            candidates: per ring, (K,) rows in the cloud, (K, 2) their x, y, (K,) whether the map
                calls them road.
            ground: (N,) labels, updated in place.
        """
        rows = np.concatenate([c[0] for c in candidates])
        if len(rows) == 0:
            return
        xy = np.concatenate([c[1] for c in candidates])
        own_road = np.concatenate([c[2] for c in candidates])
        # Eight directions: any side of the point that the map calls the other surface within the
        # margin (an edge at any angle is found to within cos(22.5 deg) of the margin). One mask
        # call for all of them: the exact edge test's cost is mostly per call.
        m = self.config.edge_margin_m
        a = np.arange(8) * (math.pi / 4.0)
        offsets = np.column_stack([m * np.cos(a), m * np.sin(a)])
        shifted = np.asarray(road_mask((xy[None, :, :] + offsets[:, None, :]).reshape(-1, 2)), dtype=bool)
        near_edge = (shifted.reshape(8, -1) != own_road[None, :]).any(axis=0)
        ground[rows[near_edge]] = True

    def _apply_fallback(
        self, p: np.ndarray, az: np.ndarray, points: np.ndarray, road_mask: RoadMask | None, ground: BoolArray
    ) -> None:
        """Himmelsbach's labels for ``points``, from one pass over the points of their segments
        only: a segment's labels depend on its own points alone, so a subset made of whole
        segments gets the labels the whole cloud would."""
        # Himmelsbach's own segment formula on the same arctan2 values, in one compiled pass.
        members = segment_members(az, points, self._himmelsbach.config.n_segments)
        labels = np.zeros(len(p), dtype=bool)
        labels[members] = self._himmelsbach.segment(p[members], road_mask)
        ground[points] = labels[points]

    def _poor_points(self, below: np.ndarray, region: np.ndarray) -> np.ndarray | None:
        """(M,) bool points of the ring in a region whose own plane was rejected while
        ``min_fit_points`` of its points lie more than ``max_below_m`` below the plane it kept (a
        surface the grid cannot reach from its prior: the road beyond a level change); None when
        there is none.

        Args:
            below: (R,) each region's points more than ``max_below_m`` below its plane (counted
                by ``ground_kernel.classify_ring``).
            region: (M,) the ring's points' regions.
        """
        poor_region = below >= self.config.min_fit_points
        return poor_region[region] if poor_region.any() else None


_HIST_BIN_M = 0.05


def _edge_candidates(
    idx: np.ndarray,
    px: np.ndarray,
    py: np.ndarray,
    pz: np.ndarray,
    window: np.ndarray,
    region: np.ndarray,
    planes: np.ndarray,
    ground: BoolArray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A ring's points that are not ground on their own part's plane but lie within the tolerance
    of their cell's other part (road for an off-road point, off-road for a road point): rows in the
    cloud, (K, 2) x y, whether the map calls them road.

    Args:
        idx: (M,) the ring's rows in the cloud; px, py, pz, window, region: (M,) per point.
        planes: (R, 3) the ring's final planes, region ``2 * sector + road``.
        ground: (N,) labels so far.
    """
    # The residual on the other part's plane: plane_residuals with the region's partner
    # (the same expression, compiled, without three (M,) gathers of plane coefficients).
    res_other = plane_residuals(px, py, pz, region ^ 1, planes)
    cand = np.flatnonzero(~ground[idx] & (res_other <= window))
    return idx[cand], np.column_stack([px[cand], py[cand]]), (region[cand] & 1) == 1


def _low_quantile(res: np.ndarray, region: np.ndarray, n_regions: int, cfg: AdaptiveGridConfig) -> np.ndarray:
    """Per-region ``seed_quantile`` of residuals, from a 5 cm histogram (no per-region sort).

    The array form of ``ground_kernel.low_quantile`` (which the segmenter calls), kept as the
    reference the kernel is tested against."""
    n_bins = math.ceil((cfg.max_below_m + cfg.seed_window_m) / _HIST_BIN_M) + 1
    b = np.clip(((res + cfg.max_below_m) / _HIST_BIN_M).astype(np.int64), 0, n_bins - 1)
    hist = np.bincount(region * n_bins + b, minlength=n_regions * n_bins).reshape(n_regions, n_bins)
    cum = np.cumsum(hist, axis=1)
    target = np.maximum(cum[:, -1] * cfg.seed_quantile, 1)
    k = np.argmax(cum >= target[:, None], axis=1)
    return (k + 0.5) * _HIST_BIN_M - cfg.max_below_m


def _fit_planes(
    sums: np.ndarray, prior: np.ndarray, cfg: AdaptiveGridConfig
) -> tuple[np.ndarray, np.ndarray]:
    """Weighted least-squares planes per region from their sums (``ground_kernel.weighted_sums``),
    regularised toward the prior; rejects bad fits. Returns the planes (R, 3) and (R,) whether
    each region kept its own fit.

    The systems are assembled and the fits judged in compiled passes (``ground_kernel``: the same
    arithmetic as :func:`_fit_planes_array_form`, about thirty small array operations per ring and
    iteration otherwise); the solve and the slope stay NumPy's (LAPACK, libm) so that the planes
    are the same to the bit."""
    A, b = plane_systems(sums, prior, cfg.prior_weight)
    sol = np.linalg.solve(A, b[..., None])[..., 0]
    slope = np.hypot(sol[:, 1], sol[:, 2])
    return accept_planes(sol, slope, sums, prior, cfg.min_fit_points, cfg.max_slope, cfg.max_step_m)


def _fit_planes_array_form(
    sums: np.ndarray, prior: np.ndarray, cfg: AdaptiveGridConfig
) -> tuple[np.ndarray, np.ndarray]:
    """The array form of :func:`_fit_planes`, kept as the reference its compiled passes are tested
    against."""
    sw, sx, sy, sz, sxx, sxy, syy, sxz, syz, count = sums.T
    A = np.stack(
        [np.stack([sw, sx, sy], -1), np.stack([sx, sxx, sxy], -1), np.stack([sy, sxy, syy], -1)], axis=1
    )
    b = np.stack([sz, sxz, syz], -1)
    lam = cfg.prior_weight
    A = A + lam * np.eye(3)[None]
    b = b + lam * prior
    sol = np.linalg.solve(A, b[..., None])[..., 0]
    ok = (count >= cfg.min_fit_points) & (np.hypot(sol[:, 1], sol[:, 2]) <= cfg.max_slope)
    ok &= np.isfinite(sol).all(axis=1)
    # The step from the prior, measured where the fitted points are (not at the sensor, where a
    # small tilt of a far cell's plane would read as a large offset).
    with np.errstate(invalid="ignore", divide="ignore"):
        cx, cy = sx / sw, sy / sw
    step = (sol[:, 0] - prior[:, 0]) + (sol[:, 1] - prior[:, 1]) * cx + (sol[:, 2] - prior[:, 2]) * cy
    ok &= np.abs(np.nan_to_num(step, nan=np.inf)) <= cfg.max_step_m
    out = np.where(ok[:, None], sol, prior)
    # An off-road part without its own fit borrows the road plane of its cell (and vice versa)
    # rather than the inner ring's, since the cell's other half is the nearer evidence.
    pair = out.reshape(-1, 2, 3)
    okp = ok.reshape(-1, 2)
    pair[:, 0] = np.where((~okp[:, 0] & okp[:, 1])[:, None], pair[:, 1], pair[:, 0])
    pair[:, 1] = np.where((~okp[:, 1] & okp[:, 0])[:, None], pair[:, 0], pair[:, 1])
    return pair.reshape(-1, 3), ok


GROUND_SEGMENTERS: dict[str, type] = {
    "adaptive_grid": AdaptiveGridGroundSegmenter,
    "himmelsbach": HimmelsbachGroundSegmenter,
}
"""Registry: the name used in configs -> the segmenter class."""


def make_ground_segmenter(
    name: str, config: AdaptiveGridConfig | HimmelsbachConfig | None = None
) -> AdaptiveGridGroundSegmenter | HimmelsbachGroundSegmenter:
    """Build a segmenter by registry name.

    Raises:
        ConfigError: an unknown name, or a config of the other segmenter's type.
    """
    if name not in GROUND_SEGMENTERS:
        raise ConfigError(f"ground segmenter: expected one of {sorted(GROUND_SEGMENTERS)}, got {name!r}")
    if name == "adaptive_grid":
        if config is not None and not isinstance(config, AdaptiveGridConfig):
            raise ConfigError(
                f"ground segmenter 'adaptive_grid': expected AdaptiveGridConfig, got {type(config).__name__}"
            )
        return AdaptiveGridGroundSegmenter(config)
    if config is not None and not isinstance(config, HimmelsbachConfig):
        raise ConfigError(
            f"ground segmenter 'himmelsbach': expected HimmelsbachConfig, got {type(config).__name__}"
        )
    return HimmelsbachGroundSegmenter(config)
