"""A spinning LiDAR's model and mount: beams, spin and columns, and the ring and firing time they imply.

Real clouds often lack what the pipeline reads per point: KITTI's ``.bin`` files hold only
``x y z reflectance``, many PCD exports drop the ring, and some drivers stamp a whole sweep once.
Given the sensor's model (datasheet beam elevations, rotation rate, column spacing, spin direction,
where a sweep starts), a point's ring is the beam nearest its elevation in the sensor frame (or, for
a model given only by its field of view and channel count, the elevation bin), and its firing time
is its column's: the angle turned since the sweep's first column over the angle a revolution turns,
times the period. The mount (``base_from_sensor``) places the sensor on the vehicle's base frame.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from lastmile.core.errors import ConfigError, MessageError
from lastmile.perception.motion_compensation import se3_matrix

# Datasheet beam elevations (deg), ascending: ring 0 is the lowest beam, as drivers number them.
# Velodyne HDL-64E S2 (KITTI): +2 to -24.8 deg in 64 "approximately 0.4 deg" equal subdivisions.
HDL64E_ELEVATIONS_DEG = tuple(float(e) for e in np.linspace(-24.8, 2.0, 64))
# Velodyne VLP-16: -15 to +15 deg every 2 deg.
VLP16_ELEVATIONS_DEG = tuple(float(e) for e in np.arange(-15.0, 15.1, 2.0))
# Velodyne VLP-32C (User Manual, table of laser elevations): dense around the horizon.
VLP32C_ELEVATIONS_DEG = (
    -25.0, -15.639, -11.31, -8.843, -7.254, -6.148, -5.333, -4.667, -4.0, -3.667, -3.333, -3.0,
    -2.667, -2.333, -2.0, -1.667, -1.333, -1.0, -0.667, -0.333, 0.0, 0.333, 0.667, 1.0, 1.333,
    1.667, 2.333, 3.333, 4.667, 7.0, 10.333, 15.0,
)  # fmt: skip
# Velodyne HDL-32E: -30.67 to +10.67 deg, 1.33 deg apart.
HDL32E_ELEVATIONS_DEG = tuple(float(e) for e in np.linspace(-30.67, 10.67, 32))
# Ouster OS1-64 (uniform beam spacing): 45 deg vertical field of view centred on the horizon.
OS1_64_ELEVATIONS_DEG = tuple(float(e) for e in np.linspace(-22.5, 22.5, 64))

# (beam elevations, horizontal resolution at 10 Hz in deg, clockwise) per built-in model.
BUILTIN_MODELS: dict[str, tuple[tuple[float, ...], float, bool]] = {
    "hdl64e": (HDL64E_ELEVATIONS_DEG, 0.1728, True),  # 2083 columns per turn at 10 Hz
    "hdl32e": (HDL32E_ELEVATIONS_DEG, 0.16, True),
    "vlp16": (VLP16_ELEVATIONS_DEG, 0.2, True),
    "vlp32c": (VLP32C_ELEVATIONS_DEG, 0.2, True),
    "os1_64": (OS1_64_ELEVATIONS_DEG, 360.0 / 1024.0, True),  # 1024 x 10 mode
}


class RingSource(enum.Enum):
    """Where a point's ring comes from."""

    AUTO = "auto"  # the file's ring field when it has one, else from the elevation
    FIELD = "field"  # the file's ring field (an error when absent)
    ELEVATION = "elevation"  # the model's beam nearest the point's elevation (or its elevation bin)
    SCAN_ORDER = "scan_order"  # the file lists its returns beam by beam (KITTI's .bin): a new ring
    # starts where the angle turned since the sweep start wraps around


class TimeSource(enum.Enum):
    """Where a point's firing time comes from."""

    AUTO = "auto"  # the file's per-point time when it has one, else from the azimuth
    FIELD = "field"  # the file's per-point time field (an error when absent)
    AZIMUTH = "azimuth"  # the column's firing time of a spinning sensor
    SWEEP = "sweep"  # one stamp for the whole sweep (offset 0: nothing is de-skewed)


@dataclass(frozen=True, slots=True, kw_only=True)
class LidarMount:
    """The sensor on the base frame (x forward, y left, z up from the road), ZYX Euler angles.

    Attributes:
        x_m, y_m, z_m: sensor origin in the base frame.
        roll_deg, pitch_deg, yaw_deg: sensor axes relative to the base's.
    """

    x_m: float = 0.0
    y_m: float = 0.0
    z_m: float = 0.0
    roll_deg: float = 0.0
    pitch_deg: float = 0.0
    yaw_deg: float = 0.0

    def base_from_sensor(self) -> np.ndarray:
        """(4, 4) float64 homogeneous transform from the sensor frame to the base frame."""
        return se3_matrix(
            self.x_m,
            self.y_m,
            self.z_m,
            math.radians(self.roll_deg),
            math.radians(self.pitch_deg),
            math.radians(self.yaw_deg),
        )


@dataclass(frozen=True, slots=True, kw_only=True)
class LidarModel:
    """A spinning LiDAR: its beams, columns and spin.

    Attributes:
        name: a built-in model (``BUILTIN_MODELS``) whose datasheet values fill the beams and the
            column spacing, or "custom" (then ``beam_elevations_deg`` or ``rings`` is required, and
            ``azimuth_resolution_deg``); given beams or rings replace a built-in model's.
        beam_elevations_deg: the beams' elevations (any order; rings count from the lowest).
        rings: with no beam list, the number of equal elevation bins between ``min_elevation_deg``
            and ``max_elevation_deg`` (a sensor known only by its field of view).
        azimuth_resolution_deg: angle between columns (0: the model's datasheet value).
        rotation_hz: revolutions per second; the sweep lasts one period.
        clockwise: spin seen from above (Velodyne, Ouster and Hesai units spin clockwise).
        sweep_start_azimuth_deg: sensor-frame azimuth (x forward, counter-clockwise) of the first
            column of a sweep (180: the sweep starts and ends behind the sensor, as KITTI's does).
        max_elevation_miss_deg, max_outside_share: a cloud with more than this share of its points
            farther than this beyond the outermost beams (or the bins' field of view) is refused
            (a wrong model, a tilted mount); fewer take the outermost ring (near returns of lasers
            mounted off the spin axis: in KITTI's frames 0-1.4 % of the points, 4-6 m away, lie
            2-2.5 deg above the HDL-64E's top beam; a VLP-16 model on those clouds leaves ~30 %
            outside).
    """

    name: str = "hdl64e"
    beam_elevations_deg: tuple[float, ...] = ()
    rings: int = 0
    min_elevation_deg: float = 0.0
    max_elevation_deg: float = 0.0
    azimuth_resolution_deg: float = 0.0
    rotation_hz: float = 10.0
    clockwise: bool = True
    sweep_start_azimuth_deg: float = 180.0
    max_elevation_miss_deg: float = 2.0
    max_outside_share: float = 0.05

    def __post_init__(self) -> None:
        if self.name != "custom" and self.name not in BUILTIN_MODELS:
            raise ConfigError(
                f"LidarModel.name: expected 'custom' or one of {sorted(BUILTIN_MODELS)}, got {self.name!r}"
            )
        els = self.beam_elevations_deg
        if els and (len(set(els)) != len(els) or not all(math.isfinite(e) and abs(e) < 90 for e in els)):
            raise ConfigError(
                f"LidarModel.beam_elevations_deg: expected distinct angles in (-90, 90), got {els}"
            )
        if self.name == "custom" and not els and self.rings <= 0:
            raise ConfigError(
                "LidarModel: a 'custom' model needs beam_elevations_deg or rings with "
                f"min_elevation_deg < max_elevation_deg, got neither (rings = {self.rings})"
            )
        if self.rings > 0 and not (-90 < self.min_elevation_deg < self.max_elevation_deg < 90):
            raise ConfigError(
                "LidarModel: expected -90 < min_elevation_deg < max_elevation_deg < 90 with rings, got "
                f"{self.min_elevation_deg}, {self.max_elevation_deg}"
            )
        if not (0 < self.rotation_hz <= 100):
            raise ConfigError(f"LidarModel.rotation_hz: expected 0..100 Hz, got {self.rotation_hz}")
        if not (0 <= self.azimuth_resolution_deg < 10):
            raise ConfigError(
                f"LidarModel.azimuth_resolution_deg: expected 0 (datasheet) to 10 deg, "
                f"got {self.azimuth_resolution_deg}"
            )
        if self.name == "custom" and self.azimuth_resolution_deg == 0:
            raise ConfigError("LidarModel.azimuth_resolution_deg: a 'custom' model needs it (> 0), got 0")
        if not (0 <= self.max_outside_share < 1):
            raise ConfigError(
                f"LidarModel.max_outside_share: expected 0 <= share < 1, got {self.max_outside_share}"
            )
        if not (self.max_elevation_miss_deg > 0):
            raise ConfigError(
                f"LidarModel.max_elevation_miss_deg: expected > 0, got {self.max_elevation_miss_deg}"
            )

    @property
    def elevations_deg(self) -> np.ndarray:
        """(R,) float64 ascending beam elevations (empty in the elevation-bin mode)."""
        if self.beam_elevations_deg:
            return np.sort(np.asarray(self.beam_elevations_deg, dtype=np.float64))
        if self.rings > 0:
            return np.empty(0)
        return np.asarray(BUILTIN_MODELS[self.name][0], dtype=np.float64)

    @property
    def column_step_deg(self) -> float:
        """Angle between columns (deg)."""
        if self.azimuth_resolution_deg > 0:
            return self.azimuth_resolution_deg
        # The datasheet's figure is at 10 Hz: the column rate is fixed, so the step scales with spin.
        return BUILTIN_MODELS[self.name][1] * self.rotation_hz / 10.0

    @property
    def period_us(self) -> float:
        """One revolution (us)."""
        return 1e6 / self.rotation_hz


@dataclass(frozen=True, slots=True, kw_only=True)
class LidarSensorConfig:
    """One LiDAR as files deliver it: its id, model, mount and which per-point fields to trust.

    Attributes:
        sensor_id: name of the sensor in the outputs.
        model: beams, columns and spin.
        mount: the sensor on the base frame.
        ring: where rings come from (:class:`RingSource` value).
        time: where firing times come from (:class:`TimeSource` value).
        intensity_scale: factor to the pipeline's 0..255 intensity (KITTI's 0..1 reflectance: 255).
    """

    sensor_id: str = "lidar"
    model: LidarModel = field(default_factory=LidarModel)
    mount: LidarMount = field(default_factory=LidarMount)
    ring: RingSource = RingSource.AUTO
    time: TimeSource = TimeSource.AUTO
    intensity_scale: float = 1.0

    def __post_init__(self) -> None:
        if not self.sensor_id:
            raise ConfigError("LidarSensorConfig.sensor_id: expected a non-empty name, got ''")
        if not (math.isfinite(self.intensity_scale) and self.intensity_scale > 0):
            raise ConfigError(f"LidarSensorConfig.intensity_scale: expected > 0, got {self.intensity_scale}")


def ring_from_elevation(xyz_m: npt.ArrayLike, model: LidarModel, where: str = "cloud") -> np.ndarray:
    """(N,) int64 ring of each point: the beam nearest its elevation (0 = lowest beam).

    Args:
        xyz_m: (N, 3) points in the sensor frame.
        model: the sensor's beams, or its elevation bins.
        where: names the input in errors (a file name).

    Raises:
        MessageError: more than ``max_outside_share`` of the points beyond the outermost beams by
            more than ``max_elevation_miss_deg`` (the model or the frame is wrong: a tilted mount, a
            cloud already in the base frame).
    """
    p = np.asarray(xyz_m, dtype=np.float64).reshape(-1, 3)
    elev = np.degrees(np.arctan2(p[:, 2], np.hypot(p[:, 0], p[:, 1])))
    beams = model.elevations_deg
    if len(beams):
        lo, hi = beams[0], beams[-1]
        mids = 0.5 * (beams[1:] + beams[:-1])
        ring = np.searchsorted(mids, elev)
    else:
        lo, hi = model.min_elevation_deg, model.max_elevation_deg
        width = (hi - lo) / model.rings
        ring = np.clip(np.floor((elev - lo) / width), 0, model.rings - 1).astype(np.int64)
    miss = (elev < lo - model.max_elevation_miss_deg) | (elev > hi + model.max_elevation_miss_deg)
    # A few near returns miss by more (the lasers sit off the spin axis: a 0.1 m offset is 1 deg
    # at 5 m); a wrong model or a tilted cloud puts whole rings outside.
    if miss.mean() > model.max_outside_share:
        i = int(np.argmax(miss))
        raise MessageError(
            f"{where}: expected elevations within {lo:.1f}..{hi:.1f} deg (+-{model.max_elevation_miss_deg} "
            f"deg) of the {model.name} model's beams in the sensor frame, got {int(miss.sum())} of "
            f"{len(elev)} points outside (point {i} at {elev[i]:.1f} deg): wrong model, or a tilted or "
            "moved cloud"
        )
    return ring.astype(np.int64)


def time_from_azimuth(xyz_m: npt.ArrayLike, model: LidarModel) -> np.ndarray:
    """(N,) float64 firing time of each point's column (us after the sweep's first column).

    The angle turned since ``sweep_start_azimuth_deg`` in the spin direction, rounded to the
    nearest column, over 360 deg, times the period: points of one column share its time, as a spinning
    sensor fires a column at once (within a few us).
    """
    p = np.asarray(xyz_m, dtype=np.float64).reshape(-1, 3)
    az = np.degrees(np.arctan2(p[:, 1], p[:, 0]))
    turned = (model.sweep_start_azimuth_deg - az) if model.clockwise else (az - model.sweep_start_azimuth_deg)
    turned = np.mod(turned, 360.0)
    step = model.column_step_deg
    n_columns = math.ceil(360.0 / step - 1e-9)
    # Nearest column: a return lies at its column's azimuth (to the encoder's resolution); past the
    # last column it is still this sweep's.
    column = np.minimum(np.round(turned / step), n_columns - 1)
    return column * (model.period_us / n_columns)


def ring_from_scan_order(xyz_m: npt.ArrayLike, model: LidarModel, where: str = "cloud") -> np.ndarray:
    """(N,) int64 ring of each point of a cloud listed beam by beam, each beam in firing order.

    A beam's returns turn once around from ``sweep_start_azimuth_deg`` in the spin direction; a new
    beam starts where that angle drops by more than 180 deg after the current beam has turned more
    than 180 deg (jitter at the seam does not start one). Beams are numbered by their median
    elevation, 0 the lowest. KITTI's ``.bin`` files list the HDL-64E's 64 lasers this way
    (counter-clockwise from the front: ``clockwise = false``, ``sweep_start_azimuth_deg = 0``).

    Raises:
        MessageError: more beams than the model has (or its ``rings``), or a beam spanning more
            than a quarter of the field of view in elevation: the cloud is not listed beam by
            beam, or the model's spin or start is not the file's.
    """
    p = np.asarray(xyz_m, dtype=np.float64).reshape(-1, 3)
    az = np.degrees(np.arctan2(p[:, 1], p[:, 0]))
    turned = (model.sweep_start_azimuth_deg - az) if model.clockwise else (az - model.sweep_start_azimuth_deg)
    turned = np.mod(turned, 360.0)
    drops = np.flatnonzero(np.diff(turned) < -180.0) + 1
    starts = [0]
    for d in drops:  # at most a few per beam
        if turned[starts[-1] : d].max() - turned[starts[-1] : d].min() > 180.0:
            starts.append(int(d))
    beams = len(model.elevations_deg) or model.rings
    if len(starts) > beams:
        raise MessageError(
            f"{where}: expected at most {beams} beams listed one after another (the {model.name} "
            f"model, {'clockwise' if model.clockwise else 'counter-clockwise'} from "
            f"{model.sweep_start_azimuth_deg} deg), got {len(starts)}: not in scan order, or another spin"
        )
    segment = np.zeros(len(p), dtype=np.int64)
    segment[starts[1:]] = 1
    segment = np.cumsum(segment)
    elev = np.degrees(np.arctan2(p[:, 2], np.hypot(p[:, 0], p[:, 1])))
    bounds = list(zip(starts, [*starts[1:], len(p)], strict=True))
    # A beam keeps to its cone: a "beam" spanning a quarter of the field of view in elevation is
    # several beams (a cloud listed column by column turns once around as one "beam").
    beams_deg = model.elevations_deg
    fov = (
        (beams_deg[-1] - beams_deg[0])
        if len(beams_deg)
        else model.max_elevation_deg - model.min_elevation_deg
    )
    for k, (a, b) in enumerate(bounds):
        lo, hi = np.percentile(elev[a:b], [10, 90])
        if hi - lo > fov / 4:
            raise MessageError(
                f"{where}: expected each beam's returns listed together, got beam {k} (points {a}..{b - 1}) "
                f"spanning {hi - lo:.1f} deg of elevation (10-90 %): not listed beam by beam"
            )
    medians = np.array([np.median(elev[a:b]) for a, b in bounds])
    rank = np.empty(len(starts), dtype=np.int64)
    rank[np.argsort(medians, kind="stable")] = np.arange(len(starts))
    return rank[segment]
