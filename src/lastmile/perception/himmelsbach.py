"""aUToronto's ground removal: Himmelsbach et al. (2010) line fitting in polar segments.

The plane around the vehicle is cut into angular segments and each segment into range bins. Each
bin's prototype is its lowest point, as (range, z). Walking outward, prototypes are added to the
current line while the least-squares fit stays flat enough (|m| <= max_slope), stays low when it is
nearly flat (|m| <= small_slope requires |b| <= max_intercept_m, which rejects car roofs and
walls' tops) and fits well (RMSE <= max_rmse_m); otherwise the line is closed and a new one starts.
A closed line is ground only if it also starts within ``max_step_m`` of the previous ground line
of its segment (T_d_prev), so a roof seen alone in its segment is not ground.
A point is ground when it lies no more than ``ground_distance_m`` above its bin's line. All segments
advance in lockstep, so the Python loop runs once per bin, not once per bin and segment.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from lastmile.core.errors import ConfigError
from lastmile.perception.road_region import RoadMask


@dataclass(frozen=True, slots=True, kw_only=True)
class HimmelsbachConfig:
    """Parameters (Himmelsbach et al.'s T_m, T_m_small, T_b, T_RMSE, T_d_ground), metres and rise/run.

    Attributes:
        n_segments: angular segments over 360 degrees.
        bin_m: radial bin length.
        max_range_m: points beyond are left to the outermost bin's line.
        max_slope: T_m, steepest line accepted.
        small_slope: T_m_small, lines flatter than this must start low.
        max_intercept_m: T_b, height at range 0 allowed for nearly flat lines.
        max_rmse_m: T_RMSE, worst fit accepted.
        ground_distance_m: T_d_ground, tolerance above the line.
        max_step_m: T_d_prev, largest height jump between a line's start and the previous ground
            line, plus max_slope per metre of unseen ground between them (lines starting higher
            are object surfaces: roofs, wall tops).
        max_gap_m: a prototype farther than this from the line's last one starts a new line.
    """

    n_segments: int = 180
    bin_m: float = 0.5
    max_range_m: float = 100.0
    max_slope: float = 0.15
    small_slope: float = 0.03
    max_intercept_m: float = 0.3
    max_rmse_m: float = 0.08
    ground_distance_m: float = 0.2
    max_step_m: float = 0.3
    max_gap_m: float = 4.0

    def __post_init__(self) -> None:
        if self.n_segments < 4:
            raise ConfigError(f"HimmelsbachConfig.n_segments: expected >= 4, got {self.n_segments}")
        for name in (
            "bin_m",
            "max_range_m",
            "max_slope",
            "max_intercept_m",
            "max_rmse_m",
            "ground_distance_m",
        ):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ConfigError(f"HimmelsbachConfig.{name}: expected a positive number, got {v}")
        if not (0 <= self.small_slope <= self.max_slope):
            raise ConfigError(
                f"HimmelsbachConfig.small_slope: expected in [0, max_slope={self.max_slope}], "
                f"got {self.small_slope}"
            )
        if self.max_range_m < 2 * self.bin_m:
            raise ConfigError(f"HimmelsbachConfig.max_range_m: expected >= 2 bins, got {self.max_range_m}")


class HimmelsbachGroundSegmenter:
    """Line-fit ground segmentation in polar segments (the road mask is not used)."""

    def __init__(self, config: HimmelsbachConfig | None = None) -> None:
        self.config = config or HimmelsbachConfig()

    def segment(self, xyz_m: npt.ArrayLike, road_mask: RoadMask | None = None) -> npt.NDArray[np.bool_]:
        cfg = self.config
        p = np.asarray(xyz_m, dtype=np.float64).reshape(-1, 3)
        n = len(p)
        if n == 0:
            return np.zeros(0, dtype=bool)
        S = cfg.n_segments
        B = math.ceil(cfg.max_range_m / cfg.bin_m)
        r = np.hypot(p[:, 0], p[:, 1])
        z = p[:, 2]
        seg = (np.floor((np.arctan2(p[:, 1], p[:, 0]) + math.pi) / (2 * math.pi) * S).astype(np.int64)) % S
        b = np.minimum((r / cfg.bin_m).astype(np.int64), B - 1)
        cell = seg * B + b
        # Prototype of each (segment, bin): its lowest point.
        proto_z = np.full(S * B, np.inf)
        np.minimum.at(proto_z, cell, z)
        proto_r = (np.arange(B) + 0.5) * cfg.bin_m
        has = np.isfinite(proto_z).reshape(S, B)
        pz = np.where(has, proto_z.reshape(S, B), 0.0)

        # Running least-squares sums of the current line per segment.
        cnt = np.zeros(S)
        sr = np.zeros(S)
        sz = np.zeros(S)
        srr = np.zeros(S)
        srz = np.zeros(S)
        szz = np.zeros(S)
        r_first = np.zeros(S)  # range of the current line's first prototype
        r_last = np.zeros(S)
        z_first = np.zeros(S)
        line_id = np.zeros(S, dtype=np.int64)
        bin_line = np.full((S, B), -1, dtype=np.int64)
        line_m = np.zeros((S, B + 1))
        line_b = np.zeros((S, B + 1))
        valid = np.zeros((S, B + 1), dtype=bool)
        # The last ground line of each segment; the road under the bus (z = 0) before any.
        prev_m = np.zeros(S)
        prev_b = np.zeros(S)
        prev_end = np.zeros(S)  # range where the last ground line ended
        rows = np.arange(S)

        def fit(
            c: np.ndarray, a_r: np.ndarray, a_z: np.ndarray, a_rr: np.ndarray, a_rz: np.ndarray
        ) -> tuple[np.ndarray, np.ndarray]:
            den = c * a_rr - a_r * a_r
            m = np.where(den > 1e-12, (c * a_rz - a_r * a_z) / np.where(den > 1e-12, den, 1.0), 0.0)
            return m, (a_z - m * a_r) / np.maximum(c, 1.0)

        def close(seg_rows: np.ndarray) -> None:
            """Record the current lines of ``seg_rows`` and judge whether they are ground."""
            m, b = fit(cnt[seg_rows], sr[seg_rows], sz[seg_rows], srr[seg_rows], srz[seg_rows])
            one = cnt[seg_rows] == 1
            # A one-point line continues the previous ground line's slope through its point.
            m = np.where(one, prev_m[seg_rows], m)
            b = np.where(one, z_first[seg_rows] - m * r_first[seg_rows], b)
            flat_ok = (np.abs(m) > cfg.small_slope) | (np.abs(b) <= cfg.max_intercept_m) | one
            # Continuity (Himmelsbach's T_d_prev): a line must start where the last ground line
            # would be; a roof or a wall top seen alone in its segment does not.
            r0 = r_first[seg_rows]
            step = np.abs((m * r0 + b) - (prev_m[seg_rows] * r0 + prev_b[seg_rows]))
            # Across unseen ground (the blind zone, an occluded stretch) the terrain may have turned
            # by up to max_slope per metre.
            allowed = cfg.max_step_m + cfg.max_slope * np.maximum(r0 - prev_end[seg_rows], 0.0)
            ok = (np.abs(m) <= cfg.max_slope) & flat_ok & (step <= allowed) & (cnt[seg_rows] > 0)
            line_m[seg_rows, line_id[seg_rows]] = m
            line_b[seg_rows, line_id[seg_rows]] = b
            valid[seg_rows, line_id[seg_rows]] = ok
            prev_m[seg_rows] = np.where(ok, m, prev_m[seg_rows])
            prev_b[seg_rows] = np.where(ok, b, prev_b[seg_rows])
            prev_end[seg_rows] = np.where(ok, r_last[seg_rows], prev_end[seg_rows])

        for j in range(B):
            act = has[:, j]
            if not act.any():
                continue
            rj, zj = proto_r[j], pz[:, j]
            c2, r2, z2 = cnt + 1, sr + rj, sz + zj
            rr2, rz2, zz2 = srr + rj * rj, srz + rj * zj, szz + zj * zj
            m2, b2 = fit(c2, r2, z2, rr2, rz2)
            sse = zz2 - 2 * m2 * rz2 - 2 * b2 * z2 + m2 * m2 * rr2 + 2 * m2 * b2 * r2 + c2 * b2 * b2
            rmse = np.sqrt(np.maximum(sse, 0.0) / c2)
            good = (np.abs(m2) <= cfg.max_slope) & (rmse <= cfg.max_rmse_m)
            good &= (np.abs(m2) > cfg.small_slope) | (np.abs(b2) <= cfg.max_intercept_m)
            good &= rj - r_last <= cfg.max_gap_m
            accept = act & ((cnt == 0) | good)
            restart = act & ~accept
            if restart.any():
                rs = rows[restart]
                close(rs)
                line_id[rs] += 1
                cnt[rs], sr[rs], sz[rs], srr[rs], srz[rs], szz[rs] = 0, 0, 0, 0, 0, 0
            new = act & (cnt == 0)
            r_first[new] = rj
            z_first[new] = zj[new]
            r_last[act] = rj
            cnt[act] += 1
            sr[act] += rj
            sz[act] += zj[act]
            srr[act] += rj * rj
            srz[act] += rj * zj[act]
            szz[act] += zj[act] * zj[act]
            bin_line[act, j] = line_id[act]
        close(rows)

        # Bins without a prototype use the nearest line before them in range (after them at the start).
        filled = _fill_forward(bin_line)
        seg_b = filled[seg, b]
        mm = line_m[seg, np.maximum(seg_b, 0)]
        bb = line_b[seg, np.maximum(seg_b, 0)]
        ok = (seg_b >= 0) & valid[seg, np.maximum(seg_b, 0)]
        height = z - (mm * r + bb)
        return ok & (height <= cfg.ground_distance_m)


def _fill_forward(ids: np.ndarray) -> np.ndarray:
    """Replace -1 entries by the last non-negative entry to their left (or the first to their right)."""
    S, B = ids.shape
    pos = np.where(ids >= 0, np.arange(B)[None, :], -1)
    last = np.maximum.accumulate(pos, axis=1)
    out = np.where(last >= 0, np.take_along_axis(ids, np.maximum(last, 0), axis=1), -1)
    first = np.where((ids >= 0).any(axis=1), np.argmax(ids >= 0, axis=1), 0)
    lead = out < 0
    return np.where(lead, ids[np.arange(S), first][:, None], out)
