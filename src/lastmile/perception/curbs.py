"""Curb and drivable-boundary detection with a lateral residual model (WATonoBus, section III-A).

Inputs are the base-frame cloud and the HD map's curb (right road edge) as a polyline in the base
frame, ordered in the driving direction with the road on its left. Steps:

1. HD-map partition: points within ``band_m`` of the map curb are expressed in the curb's Frenet
   frame (s along, d left of it) and cut into slices of ``slice_m`` in s.
2. Weighted road-surface fit: z = a + b s + c d over road points (``band_m`` to ``band_m +
   road_fit_width_m`` left of the map curb, plus the band), by iteratively reweighted least squares.
   Points above the surface get Tukey weights that vanish at ``snow_reject_m`` and points near the
   map curb count less, so snow invading the road edge cannot lift the surface.
3. Boundary per slice: lateral bins of ``bin_m``; a bin is raised when its lowest point stands at
   least ``step_min_m`` above the road surface (snow banks and curb tops alike). Starting from the
   outermost occupied bin, raised bins are chained toward the road while the gaps stay below
   ``max_gap_m``; the road-side end of the chain is the drivable boundary of that slice. An object
   standing apart on the road (a goose) is not chained to the curb, so it cannot pull the boundary in.
4. Lateral residual model: the boundary's offset from the map curb, r(s), is fitted as a polynomial
   (degree ``residual_degree``) with Huber reweighting; the map carries the curb's shape, the model
   only the misalignment (positioning error, snow). Offsets are limited to ``band_m``.
5. Points in the band left of the fitted boundary by more than ``obstacle_margin_m`` and higher
   than ``obstacle_height_m`` above the road are reassigned as obstacles.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from lastmile.core.errors import ConfigError, MessageError
from lastmile.perception.curbs_kernel import frenet_nearest, scatter_max, scatter_min

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True, slots=True, kw_only=True)
class CurbConfig:
    """Parameters in metres.

    Attributes:
        band_m: half-width of the search band around the map curb: map error up to 0.5 m, a snow
            bank spilling up to 0.5 m onto the road, plus margin.
        slice_m: length of the map partition slices along the curb.
        s_min_m, s_max_m: stations along the map curb considered (relative to its first vertex).
        bin_m: lateral bin width inside a slice.
        step_min_m: height above the road surface that makes a bin raised (a curb is 0.1-0.2 m).
        max_gap_m: largest empty lateral gap inside the chain of raised bins (sparse rings leave
            wide empty stretches on a sidewalk; the Huber fit over slices absorbs the odd slice
            where an object's shadow bridges a gap).
        road_fit_width_m: width of the road strip, beyond the band, used for the surface fit.
        snow_reject_m: points this far above the surface get zero weight in the fit.
        residual_degree: degree of the lateral residual polynomial r(s) (0 to 2).
        min_slices: fewer detected slices leave the estimate invalid.
        obstacle_margin_m: clearance left of the boundary before a raised point counts as an obstacle.
        obstacle_height_m: height above the road for such a point.
        below_road_m: points deeper than this under the fitted road are ignored as noise.
        toe_m: a snow bank slopes down to the road over half a metre or more: past the raised
            chain the boundary follows the ramp's bins while their lowest point stays above this
            height and extends the ramp's line to the road, so it lands where the bare road
            starts (a curb's vertical step has no ramp).
        max_toe_m: the ramp is followed at most this far.
        max_unseen_m: a slice whose raised chain (or ramp) ends more than this short of the first
            road-level return beyond it is ambiguous (the edge lies in the unseen stretch); the
            residual model uses ambiguous slices only when fewer than ``min_slices`` others exist.
        surface_max_m: band points on the curb side of the boundary up to this height above the
            road are the curb, sidewalk or snow bank itself (reported in ``surface_idx``), not
            objects; a goose or a person there still stands out above it.
    """

    band_m: float = 1.5
    slice_m: float = 1.0
    s_min_m: float = 0.0
    s_max_m: float = 30.0
    bin_m: float = 0.1
    step_min_m: float = 0.06
    max_gap_m: float = 2.0
    road_fit_width_m: float = 2.5
    snow_reject_m: float = 0.08
    residual_degree: int = 1
    min_slices: int = 3
    obstacle_margin_m: float = 0.15
    obstacle_height_m: float = 0.1
    below_road_m: float = 0.2
    toe_m: float = 0.03
    max_toe_m: float = 1.0
    max_unseen_m: float = 0.3
    surface_max_m: float = 0.3

    def __post_init__(self) -> None:
        for name in (
            "band_m",
            "slice_m",
            "bin_m",
            "step_min_m",
            "max_gap_m",
            "road_fit_width_m",
            "snow_reject_m",
            "toe_m",
            "max_toe_m",
            "max_unseen_m",
            "surface_max_m",
        ):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ConfigError(f"CurbConfig.{name}: expected a positive number, got {v}")
        if not self.s_max_m > self.s_min_m:
            raise ConfigError(f"CurbConfig: expected s_max_m > s_min_m, got {self.s_min_m}..{self.s_max_m}")
        if self.residual_degree not in (0, 1, 2):
            raise ConfigError(f"CurbConfig.residual_degree: expected 0, 1 or 2, got {self.residual_degree}")
        if self.min_slices < self.residual_degree + 1:
            raise ConfigError(
                f"CurbConfig.min_slices: expected >= residual_degree + 1 = {self.residual_degree + 1}, "
                f"got {self.min_slices}"
            )


@dataclass(frozen=True, slots=True, kw_only=True)
class CurbEstimate:
    """The drivable boundary along the map curb.

    Attributes:
        valid: False when too few slices showed a boundary (the caller decides what to trust then).
        s_m: (K,) stations of the slice centres along the map curb.
        offset_m: (K,) fitted boundary offset from the map curb, left (road side) positive.
        boundary_xy_m: (K, 2) the boundary in the base frame.
        detected_offset_m: (K,) per-slice measured offset (NaN where the slice showed no boundary).
        residual_coeffs: polynomial coefficients of r(s), highest power first (np.polyval order).
        road_plane: (a, b, c) of the road surface z = a + b s + c d.
        obstacle_idx: (M,) int64 indices (into the input cloud) reassigned as obstacles.
        surface_idx: (S,) int64 indices of low band points on the curb side of the boundary (curb,
            sidewalk edge, snow bank): boundary, not objects. Empty when the estimate is invalid.
    """

    valid: bool
    s_m: FloatArray
    offset_m: FloatArray
    boundary_xy_m: FloatArray
    detected_offset_m: FloatArray
    residual_coeffs: FloatArray
    road_plane: FloatArray
    obstacle_idx: npt.NDArray[np.int64]
    surface_idx: npt.NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, dtype=np.int64))


def frenet_of_points(polyline_xy: FloatArray, xy: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Station s (along) and offset d (left positive) of (N, 2) points on an (M, 2) polyline.

    Each point takes its nearest segment; points beyond the ends extend the end segments.
    """
    P = np.asarray(polyline_xy, dtype=np.float64)
    if P.ndim != 2 or P.shape[1] != 2 or len(P) < 2:
        raise MessageError(f"frenet_of_points: expected an (M >= 2, 2) polyline, got {P.shape}")
    a, b = P[:-1], P[1:]
    seg = b - a
    seg_len = np.hypot(seg[:, 0], seg[:, 1])
    if np.any(seg_len <= 0):
        raise MessageError("frenet_of_points: expected a polyline without repeated vertices")
    s0 = np.concatenate([[0.0], np.cumsum(seg_len)[:-1]])
    t_dir = seg / seg_len[:, None]
    lo = np.where(np.arange(len(seg)) == 0, -np.inf, 0.0)
    hi = np.where(np.arange(len(seg)) == len(seg) - 1, np.inf, seg_len)
    # One compiled pass keeping each point's running nearest segment (curbs_kernel): the same
    # arithmetic as the (N, M-1) array form, without building those arrays every frame.
    p = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    s, d = frenet_nearest(
        np.ascontiguousarray(p[:, 0]),
        np.ascontiguousarray(p[:, 1]),
        np.ascontiguousarray(a[:, 0]),
        np.ascontiguousarray(a[:, 1]),
        np.ascontiguousarray(t_dir[:, 0]),
        np.ascontiguousarray(t_dir[:, 1]),
        lo,
        hi,
        s0,
    )
    return s, d


def points_at(polyline_xy: FloatArray, s: FloatArray, d: FloatArray) -> FloatArray:
    """(K, 2) base-frame points at stations s and left offsets d of the polyline."""
    P = np.asarray(polyline_xy, dtype=np.float64)
    seg = np.diff(P, axis=0)
    seg_len = np.hypot(seg[:, 0], seg[:, 1])
    cum = np.concatenate([[0.0], np.cumsum(seg_len)])
    k = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(seg) - 1)
    t_dir = seg[k] / seg_len[k, None]
    base = P[k] + (s - cum[k])[:, None] * t_dir
    return base + d[:, None] * np.stack([-t_dir[:, 1], t_dir[:, 0]], axis=1)


def _irls_plane(
    s: FloatArray, d: FloatArray, z: FloatArray, prior_w: FloatArray, reject_m: float, clear_of_m: float
) -> FloatArray:
    A = np.stack([np.ones_like(s), s, d], axis=1)
    w = prior_w.copy()
    # Start from the low quantile of the road beyond the band, not the median of all: snow lying
    # on the lane edge can be most of the points next to the bus (which hides the lane under it),
    # and a start on the snow would hold the fit there.
    clear = d > clear_of_m
    coef = np.array([np.quantile(z[clear] if clear.sum() >= 10 else z, 0.2), 0.0, 0.0])
    # The weights are taken from the start before the first solve: an unweighted first solve let a
    # car parked in a bay (its whole side within the road strip) lift the plane onto its body, after
    # which the road itself fell outside the weights (measured: a plane 1.08 m up, sloping 0.36).
    for _ in range(4):
        res = z - A @ coef
        # Asymmetric: only points above the surface (snow, objects) lose weight; low outliers
        # (mirror returns) are bounded by a symmetric cap at three times the reject height.
        up = np.clip(res / reject_m, 0.0, 1.0)
        down = np.clip(-res / (3 * reject_m), 0.0, 1.0)
        w = prior_w * (1 - up**2) ** 2 * (1 - down**2) ** 2
        if w.sum() < 3:
            raise MessageError("detect_curb: expected road points for the surface fit, got too few inliers")
        sw = np.sqrt(w)
        coef = np.linalg.lstsq(A * sw[:, None], z * sw, rcond=None)[0]
    return coef


def detect_curb(
    xyz_m: npt.ArrayLike, map_curb_xy_m: npt.ArrayLike, config: CurbConfig | None = None
) -> CurbEstimate:
    """Drivable boundary along the map's right curb, with obstacles reassigned near it.

    Args:
        xyz_m: (N, 3) base-frame points (ground and non-ground alike: a curb top may be either).
        map_curb_xy_m: (M, 2) the HD map's curb in the base frame, M >= 2, road on its left.
        config: parameters.

    Raises:
        MessageError: a malformed curb polyline, or no road points to fit the surface to.
    """
    cfg = config or CurbConfig()
    p = np.asarray(xyz_m, dtype=np.float64).reshape(-1, 3)
    curb = np.asarray(map_curb_xy_m, dtype=np.float64)
    if curb.ndim != 2 or curb.shape[1] != 2 or len(curb) < 2 or not np.isfinite(curb).all():
        raise MessageError(
            f"detect_curb.map_curb_xy_m: expected a finite (M >= 2, 2) polyline, got {curb.shape}"
        )
    reach = cfg.band_m + cfg.road_fit_width_m
    lo_xy, hi_xy = curb.min(axis=0) - reach, curb.max(axis=0) + reach
    near = np.flatnonzero(
        (p[:, 0] >= lo_xy[0]) & (p[:, 0] <= hi_xy[0]) & (p[:, 1] >= lo_xy[1]) & (p[:, 1] <= hi_xy[1])
    )
    s, d = frenet_of_points(curb, p[near, :2])
    z = p[near, 2]
    in_s = (s >= cfg.s_min_m) & (s < cfg.s_max_m)
    band = in_s & (np.abs(d) <= cfg.band_m)
    road = in_s & (d > -0.0) & (d <= reach)
    if road.sum() < 3:
        raise MessageError(f"detect_curb: expected road points left of the map curb, got {int(road.sum())}")
    # Trust grows with distance from the map curb: the band is where snow piles up and the map
    # may be off, so its points only count where the road beyond it is not seen.
    lat_w = np.where(d[road] > cfg.band_m, 1.0, 0.02 + 0.08 * d[road] / cfg.band_m)
    plane = _irls_plane(s[road], d[road], z[road], lat_w, cfg.snow_reject_m, cfg.band_m)
    h = z - (plane[0] + plane[1] * s + plane[2] * d)
    band &= h >= -cfg.below_road_m  # returns under the road (multipath, noise) cannot be a curb

    n_slices = math.ceil((cfg.s_max_m - cfg.s_min_m) / cfg.slice_m)
    centres: FloatArray = cfg.s_min_m + (np.arange(n_slices, dtype=np.float64) + 0.5) * cfg.slice_m
    detected = np.full(n_slices, np.nan)
    n_bins = round(2 * cfg.band_m / cfg.bin_m)
    bi = np.clip(((d[band] + cfg.band_m) / cfg.bin_m).astype(np.int64), 0, n_bins - 1)
    si = np.clip(((s[band] - cfg.s_min_m) / cfg.slice_m).astype(np.int64), 0, n_slices - 1)
    # Lowest point per (slice, bin): the surface there, not whatever stands on it. (The scatters
    # are np.minimum.at / np.maximum.at in compiled passes: ufunc.at costs ~10x per element.)
    flat = si * n_bins + bi
    low_flat = np.full(n_slices * n_bins, np.inf)
    scatter_min(low_flat, flat, h[band])
    low = low_flat.reshape(n_slices, n_bins)
    far_flat = np.full(n_slices * n_bins, -np.inf)
    scatter_max(far_flat, flat, d[band])
    far_d = far_flat.reshape(n_slices, n_bins)
    # Farthest raised point per bin: the bin where the step is crossed holds both levels.
    up = h[band] >= cfg.step_min_m
    up_flat = np.full(n_slices * n_bins, -np.inf)
    scatter_max(up_flat, flat[up], d[band][up])
    far_up = up_flat.reshape(n_slices, n_bins)
    max_gap_bins = max(1, round(cfg.max_gap_m / cfg.bin_m))
    max_toe_bins = max(1, round(cfg.max_toe_m / cfg.bin_m))
    ambiguous = np.zeros(n_slices, dtype=bool)
    # The slice loop reads single bins: Python lists of the same float64 values (a list index is
    # several times cheaper than a NumPy scalar look-up; every comparison is the same).
    low_rows, far_rows, up_rows = low.tolist(), far_d.tolist(), far_up.tolist()
    for k in range(n_slices):
        lk, fk = low_rows[k], far_rows[k]
        occ = [j for j, v in enumerate(lk) if math.isfinite(v)]
        if len(occ) == 0:
            continue
        raised = [lk[j] >= cfg.step_min_m for j in occ]
        if not raised[0]:
            continue  # the outermost occupied bin is road level: no curb in this slice's view
        # Chain raised bins from the outer side toward the road; a road-level bin or an empty gap
        # wider than max_gap_m ends the chain.
        end = 0
        for j in range(1, len(occ)):
            if not raised[j] or occ[j] - occ[end] > max_gap_bins:
                break
            end = j
        detected[k] = fk[occ[end]]
        nxt = occ[end] + 1
        if nxt < n_bins and math.isfinite(up_rows[k][nxt]):
            detected[k] = up_rows[k][nxt]
        # A snow bank's ramp: bins below the raised height but still above the road, falling.
        # Its line, extended to the road surface, is where the bare road starts; a curb's vertical
        # step has no ramp (its next bin is road) and keeps the boundary found above.
        start = occ[end]
        prev_h = lk[start]
        # The ramp may begin inside the raised chain: its upper part stands above step_min_m.
        # Chain bins at the road-side end lower than the chain's top by more than toe_m are on
        # the slope (a curb's face bin alone is one such bin: too few for a ramp line).
        top = max(lk[j] for j in occ[: end + 1])
        tail = end
        while tail > 0 and lk[occ[tail - 1]] < top - cfg.toe_m and lk[occ[tail - 1]] >= lk[occ[tail]]:
            tail -= 1
        ramp = occ[tail : end + 1] if lk[start] < top - cfg.toe_m else [start]
        cap = fk[start] + cfg.max_toe_m
        road_from = math.inf  # the near edge of the first road-level bin beyond the chain
        for j in range(start + 1, min(n_bins, start + 1 + max_toe_bins)):
            if not math.isfinite(lk[j]):
                continue
            if lk[j] <= cfg.toe_m:
                cap = fk[j]  # the road is seen here: the toe is no farther
                road_from = j * cfg.bin_m - cfg.band_m
                break
            if lk[j] > prev_h + cfg.toe_m:
                break
            prev_h = lk[j]
            ramp.append(j)
            detected[k] = max(detected[k], fk[j])
        if len(ramp) >= 3:
            x, y = far_d[k, ramp], low[k, ramp]
            slope = np.polyfit(x, y, 1)[0]
            if slope < -cfg.toe_m / cfg.max_toe_m:
                # A bin called road level may still be up to toe_m above the road: on this slope
                # the bare road can start up to toe_m / |slope| beyond it.
                if math.isfinite(road_from):
                    cap += cfg.toe_m / -slope
                detected[k] = float(np.clip(x[-1] - y[-1] / slope, detected[k], max(cap, detected[k])))
        # Raised surface, nothing, then road: the edge lies somewhere in the unseen stretch (a
        # curb's face or a snow ramp a sparse ring skipped); such a slice votes only if too few
        # others see the edge itself.
        ambiguous[k] = road_from - detected[k] > cfg.max_unseen_m
    ok = np.isfinite(detected)
    if int((ok & ~ambiguous).sum()) >= cfg.min_slices:
        ok &= ~ambiguous
    valid = int(ok.sum()) >= cfg.min_slices
    coeffs = np.zeros(cfg.residual_degree + 1)
    if valid:
        coeffs = _huber_polyfit(centres[ok], detected[ok], cfg.residual_degree)
    offset = np.clip(np.polyval(coeffs, centres), -cfg.band_m, cfg.band_m)
    boundary = points_at(curb, centres, offset)
    # Reassignment: raised points on the road side of the fitted boundary are obstacles, inside
    # the band only. The road-fit strip beyond it (out to ``reach``) may cross the far edge of a
    # narrow road: on a 3.5 m lane the far sidewalk, 0.15 m above the road plane, was reassigned
    # as a row of obstacles that kept their place beside the moving shuttle.
    off_at = np.clip(np.polyval(coeffs, s), -cfg.band_m, cfg.band_m)
    obst = band & (d > off_at + cfg.obstacle_margin_m) & (h >= cfg.obstacle_height_m)
    obstacle_idx = near[obst] if valid else np.zeros(0, dtype=np.int64)
    surface = band & (d <= off_at + cfg.obstacle_margin_m) & (h <= cfg.surface_max_m)
    surface_idx = near[surface] if valid else np.zeros(0, dtype=np.int64)
    return CurbEstimate(
        valid=valid,
        s_m=centres,
        offset_m=offset,
        boundary_xy_m=boundary,
        detected_offset_m=detected,
        residual_coeffs=coeffs,
        road_plane=plane,
        obstacle_idx=obstacle_idx.astype(np.int64),
        surface_idx=surface_idx.astype(np.int64),
    )


def _huber_polyfit(x: FloatArray, y: FloatArray, degree: int, delta_m: float = 0.1) -> FloatArray:
    """Polynomial fit with Huber reweighting (a slice fooled by a parked object loses its pull)."""
    deg = min(degree, len(x) - 1)
    # Start from the median offset, not a least-squares fit a few wild slices could tilt.
    r0 = np.abs(y - np.median(y))
    w = np.where(r0 <= delta_m, 1.0, delta_m / np.maximum(r0, 1e-12))
    for _ in range(8):
        coef = np.polyfit(x, y, deg, w=np.sqrt(w))
        r = np.abs(y - np.polyval(coef, x))
        w = np.where(r <= delta_m, 1.0, delta_m / np.maximum(r, 1e-12))
    if deg < degree:
        coef = np.concatenate([np.zeros(degree - deg), coef])
    return coef
