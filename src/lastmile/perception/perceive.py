"""``lastmile perceive``: the LiDAR pipeline on a user's own point-cloud files, frame by frame.

Each file's sweeps (one per ``.bin`` / ``.pcd``, one per ``PointCloud2`` message of a bag) become
:class:`LidarSweep` s through the sensor's configured model and mount (rings and firing times derived
where the file lacks them), run through :class:`LidarPipeline` (no INS: nothing is de-skewed; no
map: no road mask, no curb stage), and the objects are written as KITTI object labels and a
Foxglove MCAP, with the per-stage time of every frame.

Configuration (TOML, unknown keys rejected)::

    topic = "/points"            # bags: the PointCloud2 topic (default: the only one)
    [sensor]
    sensor_id = "velodyne"
    ring = "auto"                # auto | field | elevation | scan_order
    time = "auto"                # auto | field | azimuth | sweep
    intensity_scale = 1.0
    [sensor.model]
    name = "hdl64e"              # hdl64e hdl32e vlp16 vlp32c os1_64 | custom (beam_elevations_deg or rings)
    rotation_hz = 10.0
    [sensor.mount]
    z_m = 1.73                   # the sensor above the road: ground at z = 0 in the base frame
    [pipeline]                   # any LidarPipelineConfig field, e.g. ground = "himmelsbach"
    [detector]                   # a learned LiDAR detector (ONNX; LidarDetectorConfig), or --detector
    model = "pointpillars.onnx"
    [detector.grid]              # the BEV raster the model takes
    cell_m = 0.16
"""

from __future__ import annotations

import dataclasses
import json
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from lastmile.core.config import from_mapping, load_toml
from lastmile.core.errors import ConfigError
from lastmile.perception.cloud_files import RawCloud, SweepProvenance, read_clouds, sweep_from_cloud
from lastmile.perception.lidar_detector import LidarDetectorConfig, OnnxLidarDetector, frame_objects
from lastmile.perception.lidar_model import LidarModel, LidarMount, LidarSensorConfig
from lastmile.perception.perceive_outputs import FoxgloveFrameWriter, kitti_label_lines
from lastmile.perception.pipeline import LidarPipeline, LidarPipelineConfig

# KITTI's HDL-64E: the default sensor, mounted 1.73 m above the road (KITTI's setup paper).
_DEFAULT_SENSOR = LidarSensorConfig(
    sensor_id="velodyne", model=LidarModel(name="hdl64e"), mount=LidarMount(z_m=1.73)
)
# Files without stamps are laid out at this period in the MCAP so a viewer plays them in order.
_UNSTAMPED_PERIOD_US = 100_000


@dataclass(frozen=True, slots=True, kw_only=True)
class PerceiveConfig:
    """Attributes:
    sensor: the LiDAR the files come from (model, mount, which fields to trust).
    pipeline: the pipeline's configuration.
    topic: the ``PointCloud2`` topic read from bags (None: the bag's only one).
    detector: a learned LiDAR detector whose boxes join the clusters (None: clusters only).
    """

    sensor: LidarSensorConfig = field(default_factory=lambda: _DEFAULT_SENSOR)
    pipeline: LidarPipelineConfig = field(default_factory=LidarPipelineConfig)
    topic: str | None = None
    detector: LidarDetectorConfig | None = None


def load_perceive_config(path: Path | None, detector_model: Path | None = None) -> PerceiveConfig:
    """The configuration in a TOML file (None: the defaults, KITTI's HDL-64E at 1.73 m).

    A ``[sensor]`` table starts from :class:`LidarSensorConfig`'s defaults (an HDL-64E at the base
    origin): give its ``[sensor.mount]``. ``detector_model`` (``--detector``) sets the learned
    detector's model file, with the file's ``[detector]`` settings or the defaults.
    """
    config = PerceiveConfig() if path is None else from_mapping(PerceiveConfig, load_toml(path), str(path))
    if detector_model is None:
        return config
    base = config.detector or LidarDetectorConfig(model=str(detector_model))
    return dataclasses.replace(config, detector=dataclasses.replace(base, model=str(detector_model)))


@dataclass(frozen=True, slots=True, kw_only=True)
class PerceivedFrame:
    """One processed sweep: where it came from, what was derived, objects, and the time per stage."""

    index: int
    source: str
    stamp_us: int
    points: int
    objects: int
    provenance: SweepProvenance
    stage_ms: dict[str, float]
    read_ms: float


def iter_sweeps(paths: Sequence[Path], config: PerceiveConfig) -> Iterator[RawCloud]:
    """Every sweep of the files, in the order given."""
    for path in paths:
        yield from read_clouds(path, config.topic)


def perceive_files(
    paths: Sequence[Path], config: PerceiveConfig, out_dir: Path, pipeline: LidarPipeline | None = None
) -> list[PerceivedFrame]:
    """Runs the pipeline on every sweep of ``paths`` and writes the outputs into ``out_dir``.

    Writes ``labels/<index>.txt`` (KITTI object format, :mod:`perceive_outputs`), ``objects.mcap``
    (Foxglove: ``/lidar/points`` and ``/perception/objects``) and ``timing.json`` (per frame: the
    source, what was derived, the point and object counts, the read time and each stage's ms).

    Raises:
        MessageError: a file is unreadable or does not fit the sensor's model (names the file).
        ConfigError: no file was given.
    """
    if not paths:
        raise ConfigError("perceive: expected at least one point-cloud file, got none")
    pipe = pipeline or LidarPipeline(config.pipeline)
    detector = OnnxLidarDetector(config.detector) if config.detector is not None else None
    ext = {config.sensor.sensor_id: config.sensor.mount.base_from_sensor()}
    labels_dir = out_dir / "labels"
    labels_dir.mkdir(parents=True, exist_ok=True)
    writer = FoxgloveFrameWriter(out_dir / "objects.mcap")
    frames: list[PerceivedFrame] = []
    try:
        clouds = iter_sweeps(paths, config)
        while True:
            t0 = time.perf_counter()
            cloud = next(clouds, None)
            if cloud is None:
                break
            sweep, provenance = sweep_from_cloud(cloud, config.sensor)
            read_ms = (time.perf_counter() - t0) * 1e3
            result = pipe.process([sweep], ext)
            t1 = time.perf_counter()
            objects, _ = frame_objects(result, detector)
            stage_ms = dict(result.stage_ms)
            if detector is not None:
                stage_ms["detector"] = (time.perf_counter() - t1) * 1e3
            k = len(frames)
            (labels_dir / f"{k:06d}.txt").write_text(
                "".join(f"{line}\n" for line in kitti_label_lines(objects))
            )
            writer.write(result, objects, _log_time_ns(cloud.stamp_us, k))
            frames.append(_frame(k, cloud, provenance, len(objects.clusters), stage_ms, read_ms))
    finally:
        writer.close()
    (out_dir / "timing.json").write_text(json.dumps([_as_json(f) for f in frames], indent=1))
    return frames


def _frame(
    k: int,
    cloud: RawCloud,
    provenance: SweepProvenance,
    objects: int,
    stage_ms: dict[str, float],
    read_ms: float,
) -> PerceivedFrame:
    return PerceivedFrame(
        index=k,
        source=cloud.name,
        stamp_us=cloud.stamp_us,
        points=len(cloud.xyz_m),
        objects=objects,
        provenance=provenance,
        stage_ms=stage_ms,
        read_ms=read_ms,
    )


def _log_time_ns(stamp_us: int, index: int) -> int:
    return (stamp_us if stamp_us > 0 else index * _UNSTAMPED_PERIOD_US) * 1000


def _as_json(f: PerceivedFrame) -> dict[str, object]:
    return {
        "index": f.index,
        "source": f.source,
        "stamp_us": f.stamp_us,
        "points": f.points,
        "objects": f.objects,
        "ring_from": f.provenance.ring,
        "time_from": f.provenance.time,
        "intensity_from": f.provenance.intensity,
        "read_ms": round(f.read_ms, 3),
        "stage_ms": {k: round(v, 3) for k, v in f.stage_ms.items()},
    }


def summary_lines(frames: Sequence[PerceivedFrame]) -> list[str]:
    """A few lines for the terminal: frames, objects, what was derived, median ms per stage."""
    if not frames:
        return ["no frames"]
    import statistics

    derived = sorted({(f.provenance.ring, f.provenance.time, f.provenance.intensity) for f in frames})
    stages = list(frames[0].stage_ms)
    medians = {s: statistics.median(f.stage_ms.get(s, 0.0) for f in frames) for s in stages}
    lines = [
        f"{len(frames)} frames, {sum(f.objects for f in frames)} objects, "
        f"median {statistics.median(f.points for f in frames):.0f} points per frame",
        *(f"ring from {r}, time from {t}, intensity {i}" for r, t, i in derived),
        "median ms per frame: "
        + ", ".join(f"{s} {medians[s]:.1f}" for s in stages)
        + f", read {statistics.median(f.read_ms for f in frames):.1f}",
    ]
    return lines
