"""Simulated spinning LiDARs as WATonoBus mounts them: raw sweeps with per-point time and ego-motion skew.

Each sensor fires columns of channels while it turns once per period (10 Hz). The ray of every column
starts from the sensor pose *at that column's time* (interpolated from the ego track the caller
passes), so a moving shuttle skews its own sweep as on the real vehicle; road users move during the
sweep too. Returns come from :mod:`lastmile.sim.lidar_raycast` (prisms) and the ground model of
:mod:`lastmile.sim.lidar_ground`; range noise, intensity and weather are applied here.

The stack receives only :class:`lastmile.core.sensor_frames.LidarSweep`; the per-point ground truth
(:class:`LidarTruth`) stays on the simulator side for benchmarks.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from lastmile.core.errors import ConfigError
from lastmile.core.object_class import ObjectClass
from lastmile.core.rng import component_rng
from lastmile.core.sensor_frames import LidarSweep
from lastmile.core.stamp import Stamp
from lastmile.core.vehicle import VehicleGeometry
from lastmile.sim import lidar_kernel
from lastmile.sim.lidar_ground import RESOLUTION_M, bank_height_m
from lastmile.sim.lidar_raycast import (
    Columns,
    Hits,
    box_pairs,
    cast,
    cylinder_pairs,
    segment_pairs,
)
from lastmile.sim.lidar_rig import EgoTrack, LidarSpec
from lastmile.sim.lidar_scene import (
    NO_OBJECT,
    REFLECTIVITY,
    Cylinders,
    DynamicObjects,
    PointLabel,
    Segments,
    StaticLidarScene,
)
from lastmile.sim.lidar_weather import LidarWeather

# Detection threshold: a 10 % diffuse target at normal incidence is just seen at ``max_range_m``.
REFERENCE_REFLECTIVITY = 0.10


@dataclass(frozen=True, slots=True, kw_only=True)
class LidarTruth:
    """Ground truth of one sweep, point for point with the sweep's rows (simulator side only).

    Attributes:
        label: (N,) int8 :class:`PointLabel`.
        object_id: (N,) int64 agent id for ``OBJECT`` points, else -1.
        object_class: (N,) int8 :class:`ObjectClass` for ``OBJECT`` points, else 0.
        xyz_map_m: (N, 3) float64 the true (noise-free) hit point in the map frame.
    """

    label: np.ndarray
    object_id: np.ndarray
    object_class: np.ndarray
    xyz_map_m: np.ndarray = field(repr=False)


class LidarSimulator:
    """Casts every sensor of a rig against a static scene and the road users of the moment.

    Args:
        scene: the campus as primitives (:func:`lastmile.sim.lidar_scene.static_scene`).
        specs: the rig (:func:`default_lidar_rig`).
        weather: LiDAR weather terms (:func:`lastmile.sim.lidar_weather.lidar_weather`).
        seed: the run seed; every sensor draws from its own stream ``sensor.lidar.<id>``.
        geometry: the shuttle, whose body blocks the rays that point at it.
        body_height_m: height of the shuttle's body box.
    """

    def __init__(
        self,
        scene: StaticLidarScene,
        specs: tuple[LidarSpec, ...],
        weather: LidarWeather,
        seed: int,
        geometry: VehicleGeometry,
        body_height_m: float = 2.6,
    ) -> None:
        if not isinstance(weather, LidarWeather):
            raise ConfigError(
                f"LidarSimulator.weather: expected a LidarWeather, got {type(weather).__name__}"
            )
        ids = [s.sensor_id for s in specs]
        if not ids or len(set(ids)) != len(ids):
            raise ConfigError(f"LidarSimulator.specs: expected distinct sensor ids, got {ids}")
        if weather.snow_on_road and scene.ground is None:
            raise ConfigError("LidarSimulator: snow on the road needs a scene with a ground raster, got none")
        lidar_kernel.preload()
        self.scene = scene
        self.specs = {s.sensor_id: s for s in specs}
        self.weather = weather
        self.geometry = geometry
        self._rng = {s.sensor_id: component_rng(seed, f"sensor.lidar.{s.sensor_id}") for s in specs}
        self._self_block = {s.sensor_id: _self_blocked(s, geometry, body_height_m) for s in specs}
        seg = scene.segments
        self._seg_mid = 0.5 * (seg.p0 + seg.p1)
        self._seg_half = 0.5 * np.hypot(*(seg.p1 - seg.p0).T)
        self._threshold = {s.sensor_id: REFERENCE_REFLECTIVITY / s.max_range_m**2 for s in specs}
        self._ground_refl = _ground_reflectivity(weather.wet_surface_factor)
        # Per sensor, fixed: beam trigonometry by ascending elevation and the rays that may hit ground.
        self._beams: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
        self._ground_rays: dict[str, np.ndarray] = {}
        for s in specs:
            el = np.radians(np.sort(np.asarray(s.elevations_deg, dtype=np.float64)))
            self._beams[s.sensor_id] = (np.tan(el), np.cos(el), np.sin(el))
            down = np.broadcast_to(el < 0.0, (s.n_columns, len(el)))
            self._ground_rays[s.sensor_id] = (~self._self_block[s.sensor_id] & down).reshape(-1)

    def sweep(
        self, sensor_id: str, stamp: Stamp, ego: EgoTrack, objects: DynamicObjects, objects_t_us: int
    ) -> LidarSweep:
        """The sweep of ``sensor_id`` starting at ``stamp``; road users as they were at ``objects_t_us``."""
        return self._sweep(sensor_id, stamp, ego, objects, objects_t_us, with_truth=False)[0]

    def sweep_with_truth(
        self, sensor_id: str, stamp: Stamp, ego: EgoTrack, objects: DynamicObjects, objects_t_us: int
    ) -> tuple[LidarSweep, LidarTruth]:
        """As :meth:`sweep`, with the per-point ground truth for benchmarks."""
        sweep, truth = self._sweep(sensor_id, stamp, ego, objects, objects_t_us, with_truth=True)
        assert truth is not None  # asked for
        return sweep, truth

    def _sweep(
        self,
        sensor_id: str,
        stamp: Stamp,
        ego: EgoTrack,
        objects: DynamicObjects,
        objects_t_us: int,
        with_truth: bool,
    ) -> tuple[LidarSweep, LidarTruth | None]:
        spec = self.specs.get(sensor_id)
        if spec is None:
            raise ConfigError(
                f"LidarSimulator: expected a sensor id in {list(self.specs)}, got {sensor_id!r}"
            )
        rng = self._rng[sensor_id]
        weather = self.weather
        tan_el, cos_el, sin_el = self._beams[sensor_id]
        n_col, n_ch = spec.n_columns, len(tan_el)
        cols, az = self.columns(spec, int(stamp), ego, objects_t_us)

        table, pairs = self.primitives(spec, cols, objects)
        hits = cast(cols, tan_el, (table["z_min"], table["z_max"]), pairs, spec.max_range_m)
        # From here on only rays that can return matter: not into the body, not into the sky.
        blocked = self._self_block[sensor_id].reshape(-1)
        hit_r = hits.range_h_m.reshape(-1)
        cand = np.flatnonzero(self._ground_rays[sensor_id] | (np.isfinite(hit_r) & ~blocked))
        ground_r, ground_label = self._ground(spec, cols, tan_el, cand, n_ch)
        alpha = weather.extinction_per_m
        loss = np.zeros(0)  # clear air: no loss (exactly 1)
        if alpha != 0.0:
            r_h = np.where(ground_r < hit_r[cand], ground_r, hit_r[cand])
            loss = np.asarray(_two_way_loss(alpha, r_h / cos_el[cand % n_ch]), dtype=np.float64)
        idx, true_range, cos_inc, refl, retro, label_i, prim_i = lidar_kernel.returns(
            cand,
            n_ch,
            ground_r,
            ground_label,
            hit_r,
            hits.prim.reshape(-1),
            hits.cos_incidence.reshape(-1),
            cos_el,
            sin_el,
            table["label"],
            table["refl"],
            table["retro"],
            self._ground_refl,
            loss,
            float(self._threshold[sensor_id]),
            float(spec.min_range_m),
            float(spec.max_range_m),
        )
        if weather.dropout_prob > 0.0:
            kept = rng.random(len(idx)) >= weather.dropout_prob
            idx, true_range, cos_inc, refl, retro, label_i, prim_i = (
                a[kept] for a in (idx, true_range, cos_inc, refl, retro, label_i, prim_i)
            )
        noisy = true_range + rng.normal(0.0, spec.range_noise_std_m * weather.range_noise_factor, len(idx))
        intensity = _intensity(true_range, cos_inc, refl, retro, alpha, rng)
        obj_id = table["obj_id"][prim_i]
        obj_cls = table["cls"][prim_i]

        # Precipitation echoes: single points near the window; a drop in front hides what is behind.
        if weather.echoes_per_kray > 0.0:
            n_echo = int(rng.poisson(weather.echoes_per_kray * n_col * n_ch / 1000.0))
            ray = rng.integers(0, n_col * n_ch, n_echo)
            e_rng = spec.min_range_m + rng.exponential(weather.echo_mean_range_m, n_echo)
            e_int = rng.uniform(0.0, 12.0, n_echo)
            ok = (e_rng <= min(weather.echo_max_range_m, spec.max_range_m)) & ~self._self_block[
                sensor_id
            ].reshape(-1)[ray]
            ray, e_rng, e_int = ray[ok], e_rng[ok], e_int[ok]
            ray, first = np.unique(ray, return_index=True)
            e_rng, e_int = e_rng[first], e_int[first]
            pos = np.searchsorted(idx, ray)
            # A sweep with no returns (a blinded or sky-facing unit) still gets its echoes: every ray is new.
            last = np.minimum(pos, max(len(idx) - 1, 0))
            if len(idx):
                exists = (pos < len(idx)) & (idx[last] == ray)
                nearer = ~exists | (e_rng < noisy[last])
            else:
                exists = np.zeros(len(ray), dtype=bool)
                nearer = np.ones(len(ray), dtype=bool)
            ray, e_rng, e_int, pos, exists = (
                ray[nearer],
                e_rng[nearer],
                e_int[nearer],
                pos[nearer],
                exists[nearer],
            )
            # Replace the hidden returns, then add echoes on rays that had none.
            rp = pos[exists]
            noisy[rp], true_range[rp], intensity[rp] = e_rng[exists], e_rng[exists], e_int[exists]
            label_i[rp], obj_id[rp], obj_cls[rp] = PointLabel.WEATHER_NOISE, NO_OBJECT, 0
            new = ray[~exists]
            all_idx = np.concatenate([idx, new])
            sort = np.argsort(all_idx, kind="stable")
            idx = all_idx[sort]
            noisy = np.concatenate([noisy, e_rng[~exists]])[sort]
            true_range = np.concatenate([true_range, e_rng[~exists]])[sort]
            intensity = np.concatenate([intensity, e_int[~exists]])[sort]
            label_i = np.concatenate([label_i, np.full(len(new), PointLabel.WEATHER_NOISE, np.int8)])[sort]
            obj_id = np.concatenate([obj_id, np.full(len(new), NO_OBJECT)])[sort]
            obj_cls = np.concatenate([obj_cls, np.zeros(len(new), np.int8)])[sort]

        points = np.empty((len(idx), 6), dtype=np.float32)
        lidar_kernel.sweep_points(
            idx, n_ch, n_col, spec.period_us, noisy, intensity, cos_el, sin_el, np.cos(az), np.sin(az), points
        )
        points.setflags(write=False)  # handed over to the sweep (no copy of it)
        sweep = LidarSweep(stamp=stamp, sensor_id=sensor_id, points=points)
        if not with_truth:
            return sweep, None
        col_i, ch_i = idx // n_ch, idx % n_ch
        ce, se = cos_el[ch_i], sin_el[ch_i]
        horiz = (true_range * ce)[:, None]
        xyz = np.column_stack(
            [cols.origin[col_i] + horiz * cols.direction[col_i], cols.z_m + true_range * se]
        )
        truth = LidarTruth(
            label=label_i, object_id=obj_id.astype(np.int64), object_class=obj_cls, xyz_map_m=xyz
        )
        return sweep, truth

    # --- pieces --------------------------------------------------------------------------------
    def columns(
        self, spec: LidarSpec, stamp_us: int, ego: EgoTrack, objects_t_us: int
    ) -> tuple[Columns, np.ndarray]:
        """The sweep's firing columns in the map frame and their (C,) sensor-frame azimuths."""
        n_col = spec.n_columns
        k = np.arange(n_col)
        t_us = stamp_us + (k * spec.period_us) // n_col
        x, y, yaw = ego.at(t_us)
        c, s = np.cos(yaw), np.sin(yaw)
        origin = np.column_stack([x + c * spec.x_m - s * spec.y_m, y + s * spec.x_m + c * spec.y_m])
        sign = -1.0 if spec.clockwise else 1.0
        az = spec.start_azimuth_rad + sign * np.radians(spec.azimuth_res_deg) * k
        theta = yaw + spec.yaw_rad + az
        spin = np.maximum.accumulate(sign * (theta - theta[0]))
        cols = Columns(
            origin=origin,
            direction=np.column_stack([np.cos(theta), np.sin(theta)]),
            t_s=(t_us - objects_t_us) * 1e-6,
            spin=spin,
            theta0_rad=float(theta[0]),
            sign=sign,
            z_m=spec.z_m,
        )
        return cols, az

    def primitives(
        self, spec: LidarSpec, cols: Columns, objects: DynamicObjects
    ) -> tuple[dict[str, np.ndarray], tuple[np.ndarray, ...]]:
        """One table of every primitive in reach and the (column, primitive) pairs against it.

        The table's columns are (P + 1,) arrays (the last row is a sentinel for "nothing hit"); the
        pairs are (prim, col, r_in, r_out, cos_2d) as :func:`lastmile.sim.lidar_raycast.cast` takes them.
        """
        reach = spec.max_range_m + float(np.hypot(*(cols.origin[-1] - cols.origin[0])))
        centre = 0.5 * (cols.origin[0] + cols.origin[-1])
        seg = self.scene.segments
        near = np.hypot(*(self._seg_mid - centre).T) - self._seg_half <= reach
        if self.weather.snow_on_road:
            near &= seg.label != PointLabel.CURB  # the snow bank buries the curb face
        near_seg = np.flatnonzero(near)
        seg = Segments(**{f: getattr(seg, f)[near_seg] for f in Segments.__dataclass_fields__})
        cyl_s = self.scene.cylinders
        near_cyl = np.flatnonzero(np.hypot(*(cyl_s.centre - centre).T) <= reach)
        cyl = _concat_cylinders(
            Cylinders(**{f: getattr(cyl_s, f)[near_cyl] for f in Cylinders.__dataclass_fields__}),
            objects.cylinders,
        )
        box = objects.boxes
        n_seg, n_cyl = len(seg), len(cyl)
        # The last row is a sentinel that index -1 ("no primitive") reads.
        table = {
            "z_min": np.concatenate([seg.z_min_m, cyl.z_min_m, box.z_min_m, [0.0]]),
            "z_max": np.concatenate([seg.z_max_m, cyl.z_max_m, box.z_max_m, [0.0]]),
            "label": np.concatenate([seg.label, cyl.label, box.label, [PointLabel.ROAD]]).astype(np.int8),
            "obj_id": np.concatenate([np.full(n_seg, NO_OBJECT), cyl.object_id, box.object_id, [NO_OBJECT]]),
            "cls": np.concatenate([np.zeros(n_seg, np.int8), cyl.object_class, box.object_class, [0]]).astype(
                np.int8
            ),
            "refl": np.concatenate([seg.reflectivity, cyl.reflectivity, box.reflectivity, [0.0]]),
            "retro": np.concatenate([seg.retro, cyl.retro, np.zeros(len(box), bool), [False]]),
        }
        parts = [segment_pairs(cols, seg), cylinder_pairs(cols, cyl), box_pairs(cols, box)]
        offsets = (0, n_seg, n_seg + n_cyl)
        pairs = tuple(
            np.concatenate([p[i] + (off if i == 0 else 0) for p, off in zip(parts, offsets, strict=True)])
            for i in range(5)
        )
        return table, pairs

    def _ground(
        self, spec: LidarSpec, cols: Columns, tan_el: np.ndarray, cand: np.ndarray, n_ch: int
    ) -> tuple[np.ndarray, np.ndarray]:
        """Horizontal distance to the ground and its label for the rays ``cand`` (flat column * K +
        channel; inf: not downward). Without snow on a ground raster, one compiled pass
        (:func:`lidar_kernel.ground_ranges`); otherwise :meth:`_ground_arrays`."""
        ground = self.scene.ground
        if ground is None or self.weather.snow_on_road:
            return self._ground_arrays(spec, cols, tan_el, cand // n_ch, cand % n_ch)
        f8 = np.ascontiguousarray
        return lidar_kernel.ground_ranges(
            cand,
            n_ch,
            tan_el,
            f8(cols.origin[:, 0]),
            f8(cols.origin[:, 1]),
            f8(cols.direction[:, 0]),
            f8(cols.direction[:, 1]),
            float(cols.z_m),
            float(self.scene.curb_height_m),
            float(spec.max_range_m),
            ground.road.reshape(-1),
            ground.x0_m,
            ground.y0_m,
            ground.width,
            ground.height,
            RESOLUTION_M,
            int(PointLabel.ROAD),
            int(PointLabel.SIDEWALK),
        )

    def _ground_arrays(
        self, spec: LidarSpec, cols: Columns, tan_el: np.ndarray, col: np.ndarray, ch: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """As :meth:`_ground`, for the rays (col, ch), in NumPy: with the snow banks, or without a
        ground raster (the road plane everywhere)."""
        n = len(col)
        r = np.full(n, np.inf)
        label = np.full(n, PointLabel.ROAD, dtype=np.int8)
        down = np.flatnonzero(tan_el[ch] < 0.0)
        if len(down) == 0:
            return r, label
        oz = cols.z_m
        t = tan_el[ch[down]]
        r0 = -oz / t
        ground = self.scene.ground
        if ground is None:
            r[down] = r0
            return r, label
        col_down = col.take(down)
        # 1-D takes from contiguous columns: the values of the (N, 2) row gathers, several times cheaper.
        ox, oy, dx, dy = (np.ascontiguousarray(a).take(col_down) for a in (*cols.origin.T, *cols.direction.T))

        def xy_at(rr: np.ndarray, sel: np.ndarray | slice) -> tuple[np.ndarray, np.ndarray]:
            return ox[sel] + rr * dx[sel], oy[sel] + rr * dy[sel]

        everywhere = slice(None)  # every downward ray: a view, not a gather of all of them
        road0 = ground.is_road(*xy_at(r0, everywhere)) | (r0 > spec.max_range_m)
        hc = self.scene.curb_height_m
        rs = (hc - oz) / t if oz > hc else r0
        # Road where the z=0 plane is met on road; sidewalk where the raised plane is met off road; a
        # ray that passes over road and dips below sidewalk level met the curb face (cast elsewhere),
        # except where no curb is mapped (road ends), where it is kept on the road plane.
        off = np.flatnonzero(~road0)
        road_s = np.zeros(len(down), dtype=bool)
        road_s[off] = ground.is_road(*xy_at(rs[off], off))
        side = ~road0 & ~road_s
        rr = np.where(side, rs, r0)
        lab = np.where(side, PointLabel.SIDEWALK, PointLabel.ROAD).astype(np.int8)
        w = self.weather
        if w.snow_on_road:
            rr = np.where(~road0 & road_s, rs, rr)
            on = np.flatnonzero(~side)
            r_on, t_on = rr[on], t[on]
            # Two fixed-point steps onto the snow surface: the bank slopes gently, so they converge.
            h = np.zeros(len(on))
            for _ in range(2):
                dist = ground.curb_distance_m(*xy_at(r_on, on))
                h = bank_height_m(dist, hc, w.snow_bank_width_m, w.snow_cover_lane_m)
                r_on = (np.minimum(h, oz - 1e-3) - oz) / t_on
            rr[on] = r_on
            lab[on[h > 0.005]] = PointLabel.SNOW
        r[down] = rr
        label[down] = lab
        return r, label


def _ground_reflectivity(wet_factor: float) -> np.ndarray:
    """Diffuse reflectivity of ground hits by label; a wet road and sidewalk mirror the beam away."""
    table = np.zeros(int(max(PointLabel)) + 1)
    for lab, value in REFLECTIVITY.items():
        table[int(lab)] = value
    table[int(PointLabel.ROAD)] *= wet_factor
    table[int(PointLabel.SIDEWALK)] *= wet_factor
    return table


def _two_way_loss(alpha: float, range_m: np.ndarray) -> np.ndarray | float:
    """``exp(-2 alpha r)``, the atmosphere's two-way loss; in clear air (alpha 0) exactly 1.0, as the
    exponential of -0.0 is for every finite range, without an exponential per point. (A ray of
    infinite range never returns: its power test fails either way.)"""
    if alpha == 0.0:
        return 1.0
    return np.exp(-2.0 * alpha * range_m)


def _intensity(
    range_m: np.ndarray,
    cos_inc: np.ndarray,
    refl: np.ndarray,
    retro: np.ndarray,
    alpha: float,
    rng: np.random.Generator,
) -> np.ndarray:
    """0..255 intensity: reflectivity x incidence x atmospheric loss x a mild range fall-off, with noise.

    Retro-reflective sheeting returns most of the beam whatever the incidence (~200-250); diffuse
    surfaces follow Lambert (with a floor: real surfaces are not perfectly diffuse). The noise is one
    standard normal draw per return, scaled by ``1.5 + 3 %`` of the value
    (:func:`lidar_kernel.intensity`).
    """
    loss = np.zeros(0) if alpha == 0.0 else np.asarray(_two_way_loss(alpha, range_m), dtype=np.float64)
    noise = rng.normal(0.0, 1.0, len(range_m))
    return lidar_kernel.intensity(range_m, cos_inc, refl, retro, loss, noise)


def _concat_cylinders(a: Cylinders, b: Cylinders) -> Cylinders:
    return Cylinders(
        **{f: np.concatenate([getattr(a, f), getattr(b, f)]) for f in Cylinders.__dataclass_fields__}
    )


def _self_blocked(spec: LidarSpec, geometry: VehicleGeometry, body_height_m: float) -> np.ndarray:
    """(C, K) rays (channels by ascending elevation) that hit the shuttle's own body.

    Sensor and body are rigid, so this is fixed per sensor; the driver crops these returns, as a
    real LiDAR driver crops its vehicle's box.
    """
    order = np.argsort(spec.elevations_deg)
    tan_el = np.tan(np.radians(np.asarray(spec.elevations_deg, dtype=np.float64)[order]))
    n_col = spec.n_columns
    k = np.arange(n_col)
    sign = -1.0 if spec.clockwise else 1.0
    theta = spec.yaw_rad + spec.start_azimuth_rad + sign * np.radians(spec.azimuth_res_deg) * k
    cols = Columns(
        origin=np.tile([spec.x_m, spec.y_m], (n_col, 1)),
        direction=np.column_stack([np.cos(theta), np.sin(theta)]),
        t_s=np.zeros(n_col),
        spin=np.maximum.accumulate(sign * (theta - theta[0])),
        theta0_rad=float(theta[0]),
        sign=sign,
        z_m=spec.z_m,
    )
    body = (
        DynamicObjects.empty()
        .with_box(
            x_m=geometry.length_m / 2.0 - geometry.rear_overhang_m,
            y_m=0.0,
            yaw_rad=0.0,
            length_m=geometry.length_m,
            width_m=geometry.width_m,
            height_m=body_height_m,
            label=PointLabel.EGO,
            object_class=ObjectClass.UNKNOWN,
        )
        .boxes
    )
    hits: Hits = cast(cols, tan_el, (body.z_min_m, body.z_max_m), box_pairs(cols, body), spec.max_range_m)
    blocked = np.isfinite(hits.range_h_m)
    blocked.setflags(write=False)
    return blocked
