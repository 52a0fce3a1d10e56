"""Polylines with arc length, interpolation and Frenet projection (s along, d left of the line)."""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass, field

import numpy as np

from lastmile.core.errors import MessageError
from lastmile.core.geometry import FloatArray


@dataclass(frozen=True, slots=True)
class FrenetPoint:
    """A point in the Frenet frame of a polyline: ``s_m`` along it, ``d_m`` to its left."""

    s_m: float
    d_m: float
    segment: int


_VECTOR_FROM_SEGMENTS = 24
"""Projections over more segments than this run vectorised; fewer, as a scalar loop (cheaper there)."""


@dataclass(frozen=True, eq=False)
class Polyline:
    """An open (or closed) 2D polyline.

    Attributes:
        xy_m: (N, 2) float64 vertices, N >= 2, read-only; consecutive duplicates are removed.
        closed: when True the line wraps (a loop); s is taken modulo the length.
    """

    xy_m: FloatArray
    closed: bool = False
    s_m: FloatArray = field(init=False, repr=False)
    _seg_dir: FloatArray = field(init=False, repr=False)
    _seg_len: FloatArray = field(init=False, repr=False)
    _heading: FloatArray = field(init=False, repr=False)
    _xs: list[float] = field(init=False, repr=False)
    _ys: list[float] = field(init=False, repr=False)
    _ss: list[float] = field(init=False, repr=False)
    _dxs: list[float] = field(init=False, repr=False)
    _dys: list[float] = field(init=False, repr=False)
    _headings: list[float] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        xy = np.asarray(self.xy_m, dtype=np.float64)
        if xy.ndim != 2 or xy.shape[1] != 2 or xy.shape[0] < 2:
            raise MessageError(f"Polyline: expected an (N>=2, 2) array, got shape {xy.shape}")
        if not np.all(np.isfinite(xy)):
            raise MessageError("Polyline: expected finite vertices, got NaN or inf")
        if self.closed and np.hypot(*(xy[0] - xy[-1])) > 1e-9:
            xy = np.vstack([xy, xy[:1]])
        keep = np.ones(len(xy), dtype=bool)
        keep[1:] = np.hypot(*(np.diff(xy, axis=0).T)) > 1e-9
        xy = xy[keep]
        if xy.shape[0] < 2:
            raise MessageError("Polyline: expected at least two distinct vertices")
        seg = np.diff(xy, axis=0)
        seg_len = np.hypot(seg[:, 0], seg[:, 1])
        s = np.concatenate([[0.0], np.cumsum(seg_len)])
        for name, value in (
            ("xy_m", xy),
            ("s_m", s),
            ("_seg_dir", seg / seg_len[:, None]),
            ("_seg_len", seg_len),
            ("_heading", np.arctan2(seg[:, 1], seg[:, 0])),
        ):
            value.setflags(write=False)
            object.__setattr__(self, name, value)
        # Python lists for the scalar hot path: indexing a list is ~10x cheaper than a NumPy scalar.
        object.__setattr__(self, "_xs", xy[:, 0].tolist())
        object.__setattr__(self, "_ys", xy[:, 1].tolist())
        object.__setattr__(self, "_ss", s.tolist())
        object.__setattr__(self, "_dxs", (seg[:, 0] / seg_len).tolist())
        object.__setattr__(self, "_dys", (seg[:, 1] / seg_len).tolist())
        object.__setattr__(self, "_headings", self._heading.tolist())

    @property
    def length_m(self) -> float:
        return float(self.s_m[-1])

    def ds_m(self, from_s_m: float, to_s_m: float) -> float:
        """Arc length from ``from_s_m`` to ``to_s_m``: their difference on an open line; on a closed one
        the shorter way round, in [-length / 2, length / 2) (ahead is positive)."""
        if not self.closed:
            return to_s_m - from_s_m
        length = self.length_m
        return (to_s_m - from_s_m + length / 2.0) % length - length / 2.0

    def _wrap_s(self, s_m: float) -> float:
        if self.closed:
            return s_m % self.length_m
        return min(max(s_m, 0.0), self.length_m)

    def _segment_at(self, s_m: float) -> int:
        # bisect on the Python list: same answer as searchsorted(side="right"), without NumPy's
        # per-call overhead on this scalar hot path.
        i = bisect.bisect_right(self._ss, s_m) - 1
        return min(max(i, 0), len(self._ss) - 2)

    def point_at(self, s_m: float) -> tuple[float, float, float]:
        """(x_m, y_m, heading_rad) at arc length ``s_m`` (clamped, or wrapped when closed)."""
        s = self._wrap_s(s_m)
        i = self._segment_at(s)
        t = s - self._ss[i]
        return self._xs[i] + t * self._dxs[i], self._ys[i] + t * self._dys[i], self._headings[i]

    def points_at(self, s_m: FloatArray) -> FloatArray:
        """(M, 2) points at the arc lengths ``s_m`` (M,)."""
        s = np.asarray(s_m, dtype=np.float64)
        s = s % self.length_m if self.closed else np.clip(s, 0.0, self.length_m)
        i = np.clip(np.searchsorted(self.s_m, s, side="right") - 1, 0, len(self._seg_len) - 1)
        t = s - self.s_m[i]
        return self.xy_m[i] + t[:, None] * self._seg_dir[i]

    def heading_at(self, s_m: float) -> float:
        """Heading of the segment under ``s_m``, in rad."""
        return self._headings[self._segment_at(self._wrap_s(s_m))]

    def curvature_at(self, s_m: float, window_m: float = 2.0) -> float:
        """Signed curvature (1/m, left positive): the circle through the points at s - w, s, s + w.

        Three points rather than segment headings, because headings are constant along a segment and
        would quantise the estimate to the vertex spacing.
        """
        ax, ay, _ = self.point_at(s_m - window_m)
        bx, by, _ = self.point_at(s_m)
        cx, cy, _ = self.point_at(s_m + window_m)
        cross = (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)
        denom = math.hypot(bx - ax, by - ay) * math.hypot(cx - bx, cy - by) * math.hypot(cx - ax, cy - ay)
        return 0.0 if denom < 1e-12 else 2.0 * cross / denom

    def project(
        self, x_m: float, y_m: float, hint_s_m: float | None = None, window_m: float = 15.0
    ) -> FrenetPoint:
        """Frenet coordinates of a point: the nearest point on the line, searched near ``hint_s_m`` if given.

        The hint keeps a tracked vehicle on the right branch where a loop passes near itself, and it
        makes the search local (a handful of segments) on the per-tick hot path.
        """
        if not (math.isfinite(x_m) and math.isfinite(y_m)):
            raise MessageError(f"Polyline.project: expected a finite point, got ({x_m}, {y_m})")
        n = len(self._seg_len)
        idx: range | list[int]
        if hint_s_m is None:
            return self._project_range(x_m, y_m, range(n))
        s0 = self._wrap_s(hint_s_m)
        i0 = self._segment_at(s0)
        lo_s, hi_s = s0 - window_m, s0 + window_m
        if self.closed:
            lo = (
                self._segment_at(lo_s % self.length_m)
                if lo_s >= 0
                else self._segment_at(lo_s + self.length_m)
            )
            hi = self._segment_at(hi_s % self.length_m)
            # A window that straddles s = 0 on a loop is two ranges.
            idx = range(lo, hi + 1) if lo <= i0 <= hi else [*range(lo, n), *range(0, hi + 1)]
        else:
            lo = self._segment_at(max(lo_s, 0.0))
            hi = self._segment_at(min(hi_s, self.length_m))
            idx = range(lo, hi + 1)
        return self._project_range(x_m, y_m, idx)

    def _project_range(self, x_m: float, y_m: float, idx: range | list[int]) -> FrenetPoint:
        if isinstance(idx, range) and len(idx) > _VECTOR_FROM_SEGMENTS:
            return self._project_slice(x_m, y_m, idx.start, idx.stop)
        xs, ys, ss = self._xs, self._ys, self._ss
        seg_len = self._seg_len
        best_d2 = math.inf
        best = (0.0, 0.0, 0)
        last = len(seg_len) - 1
        for i in idx:
            ax, ay = xs[i], ys[i]
            bx, by = xs[i + 1], ys[i + 1]
            vx, vy = bx - ax, by - ay
            length = ss[i + 1] - ss[i]
            t = ((x_m - ax) * vx + (y_m - ay) * vy) / (length * length)
            # Open lines extend their end segments so points beyond the ends get s < 0 or s > length.
            if self.closed or (0 < i < last):
                t = min(max(t, 0.0), 1.0)
            elif i == 0 and last > 0:
                t = min(t, 1.0)
            elif i == last and last > 0:
                t = max(t, 0.0)
            dx, dy = x_m - (ax + t * vx), y_m - (ay + t * vy)
            # dx * dx, never dx ** 2: Python's float ** 2 is the C library's pow(), which misses the
            # correctly rounded product by an ulp for some inputs, while NumPy squares by multiplying.
            d2 = dx * dx + dy * dy
            if d2 < best_d2:
                cross = vx * (y_m - ay) - vy * (x_m - ax)
                best_d2 = d2
                best = (ss[i] + t * length, math.copysign(math.sqrt(d2), cross), i)
        return FrenetPoint(s_m=best[0], d_m=best[1], segment=best[2])

    def _project_slice(self, x_m: float, y_m: float, lo: int, hi: int) -> FrenetPoint:
        # The loop of _project_range over segments lo..hi-1 in NumPy, with the same float operations
        # in the same order, so both give bit-identical answers (ties: the first segment wins).
        xy, s = self.xy_m, self.s_m
        ax, ay = xy[lo:hi, 0], xy[lo:hi, 1]
        vx, vy = xy[lo + 1 : hi + 1, 0] - ax, xy[lo + 1 : hi + 1, 1] - ay
        length = s[lo + 1 : hi + 1] - s[lo:hi]
        t = ((x_m - ax) * vx + (y_m - ay) * vy) / (length * length)
        last = len(self._ss) - 2
        if self.closed:
            t = np.clip(t, 0.0, 1.0)
        elif last > 0:
            i = np.arange(lo, hi)
            t = np.where(i > 0, np.maximum(t, 0.0), t)
            t = np.where(i < last, np.minimum(t, 1.0), t)
        dx, dy = x_m - (ax + t * vx), y_m - (ay + t * vy)
        d2 = dx * dx + dy * dy  # as the loop computes it (see there)
        k = int(np.argmin(d2))
        cross = float(vx[k]) * (y_m - float(ay[k])) - float(vy[k]) * (x_m - float(ax[k]))
        return FrenetPoint(
            s_m=float(s[lo + k]) + float(t[k]) * float(length[k]),
            d_m=math.copysign(math.sqrt(float(d2[k])), cross),
            segment=lo + k,
        )

    def offset(self, d_m: float) -> Polyline:
        """A parallel line ``d_m`` to the left (negative: right), using vertex normals."""
        n = _vertex_normals(self.xy_m, self.closed)
        return Polyline(self.xy_m + d_m * n, closed=self.closed)

    def resampled(self, step_m: float) -> Polyline:
        """The same line with vertices every ``step_m`` (the last one at the end)."""
        count = max(2, math.ceil(self.length_m / step_m) + 1)
        s = np.linspace(0.0, self.length_m, count)
        return Polyline(self.points_at(s), closed=False)

    def sub(self, s0_m: float, s1_m: float, step_m: float = 0.5) -> FloatArray:
        """(M, 2) points from ``s0_m`` to ``s1_m`` (may exceed the length when closed: it wraps)."""
        count = max(2, math.ceil(abs(s1_m - s0_m) / step_m) + 1)
        return self.points_at(np.linspace(s0_m, s1_m, count))


def _vertex_normals(xy: FloatArray, closed: bool) -> FloatArray:
    seg = np.diff(xy, axis=0)
    seg /= np.hypot(seg[:, 0], seg[:, 1])[:, None]
    tang = np.empty_like(xy)
    tang[1:-1] = seg[:-1] + seg[1:]
    if closed:
        tang[0] = tang[-1] = seg[0] + seg[-1]
    else:
        tang[0], tang[-1] = seg[0], seg[-1]
    tang /= np.hypot(tang[:, 0], tang[:, 1])[:, None]
    # Keep the offset distance true at corners: scale by 1/cos(half the turning angle).
    seg_prev = np.vstack([seg[-1:] if closed else seg[:1], seg])
    cos_half = np.clip(np.einsum("ij,ij->i", tang, seg_prev[: len(tang)]), 0.3, 1.0)
    normals = np.stack([-tang[:, 1], tang[:, 0]], axis=1)
    return normals / cos_half[:, None]
