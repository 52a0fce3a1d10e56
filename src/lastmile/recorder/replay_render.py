"""Top-down pictures of a recording: ego, tracks, clouds, planned path, route and map in one fixed frame.

Everything is placed through the recording's own transform tree (``/tf``: map -> base_link -> each
sensor), as Foxglove's 3D panel does, so a LiDAR or radar cloud appears where its sensor saw it. Works
on any MCAP with Foxglove schemas: without a ``map`` frame (``lastmile perceive``'s files are in
``base``), the first frame the data name is the fixed frame.
"""

from __future__ import annotations

import bisect
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from lastmile.core.vehicle_messages import ActuatorCommand, BehaviourDecision, TurnSignal
from lastmile.recorder.foxglove_views import BASE_FRAME, MAP_FRAME
from lastmile.recorder.mcap_codec import RecordingError
from lastmile.recorder.replay import Recording, ViewMessage

_EGO_LENGTH_M, _EGO_WIDTH_M, _EGO_CENTRE_AHEAD_M = 4.6, 2.0, 1.45  # base_link is the rear axle
_NUMERIC = {7: "<f4", 8: "<f8"}  # foxglove.NumericType FLOAT32, FLOAT64
_MAX_DEPTH = 16


@dataclass(frozen=True, slots=True)
class RenderSummary:
    """What one picture holds (so a caller can tell a picture from empty axes)."""

    path: Path
    t_us: int
    fixed_frame: str
    ego: bool
    boxes: int
    cloud_points: int
    lines: int


def _matrix(translation: Any, rotation: Any) -> np.ndarray:
    m = np.eye(4)
    q = (rotation.x, rotation.y, rotation.z, rotation.w)
    if any(q):
        m[:3, :3] = Rotation.from_quat(q).as_matrix()
    m[:3, 3] = (translation.x, translation.y, translation.z)
    return m


def _pose_matrix(pose: Any) -> np.ndarray:
    return _matrix(pose.position, pose.orientation)


@dataclass(slots=True)
class _Scene:
    """The latest state of every view channel at a time: transforms, clouds, scene updates."""

    fixed: str
    parents: dict[str, tuple[str, np.ndarray]] = field(default_factory=dict)
    clouds: dict[str, Any] = field(default_factory=dict)
    scenes: dict[str, Any] = field(default_factory=dict)
    pose: Any = None

    def add(self, view: ViewMessage) -> None:
        m = view.message
        if view.schema == "foxglove.FrameTransforms":
            for tf in m.transforms:
                self.parents[tf.child_frame_id] = (tf.parent_frame_id, _matrix(tf.translation, tf.rotation))
        elif view.schema == "foxglove.FrameTransform":
            self.parents[m.child_frame_id] = (m.parent_frame_id, _matrix(m.translation, m.rotation))
        elif view.schema == "foxglove.PointCloud":
            self.clouds[view.topic] = m
        elif view.schema == "foxglove.SceneUpdate":
            self.scenes[view.topic] = m
        elif view.schema == "foxglove.PoseInFrame":
            self.pose = m

    def resolve(self, frame: str) -> np.ndarray | None:
        """fixed_from_frame, or None when the tree does not (yet) connect them."""
        out = np.eye(4)
        for _ in range(_MAX_DEPTH):
            if frame == self.fixed:
                return out
            link = self.parents.get(frame)
            if link is None:
                return None
            frame, parent_from_child = link[0], link[1]
            out = parent_from_child @ out
        return None


def fixed_frame_of(views: Iterable[ViewMessage]) -> str:
    """``map`` when the transform tree has it, else the frame of the first cloud or scene entity."""
    first = ""
    for v in views:
        m = v.message
        if v.schema == "foxglove.FrameTransforms" and any(
            t.parent_frame_id == MAP_FRAME for t in m.transforms
        ):
            return MAP_FRAME
        if not first and v.schema == "foxglove.PointCloud":
            first = m.frame_id
        if not first and v.schema == "foxglove.SceneUpdate" and len(m.entities):
            first = m.entities[0].frame_id
    return first or MAP_FRAME


def cloud_xyz(cloud: Any) -> np.ndarray:
    """(N, 3) float64 points of a ``PointCloud`` in its frame (its ``pose`` applied)."""
    fields = {f.name: f for f in cloud.fields}
    stride = int(cloud.point_stride)
    if stride <= 0 or not all(k in fields and fields[k].type in _NUMERIC for k in ("x", "y", "z")):
        return np.zeros((0, 3))
    n = len(cloud.data) // stride
    dtype = np.dtype(
        {
            "names": ["x", "y", "z"],
            "formats": [_NUMERIC[fields[k].type] for k in ("x", "y", "z")],
            "offsets": [fields[k].offset for k in ("x", "y", "z")],
            "itemsize": stride,
        }
    )
    rec = np.frombuffer(cloud.data, dtype=dtype, count=n)
    xyz = np.stack([rec["x"], rec["y"], rec["z"]], axis=1).astype(float)
    pose = _pose_matrix(cloud.pose) if cloud.HasField("pose") else np.eye(4)
    return xyz @ pose[:3, :3].T + pose[:3, 3]


def _apply(m: np.ndarray, xyz: np.ndarray) -> np.ndarray:
    return xyz @ m[:3, :3].T + m[:3, 3]


def _box_xy(m: np.ndarray, length: float, width: float, ahead: float = 0.0) -> np.ndarray:
    corners = np.array(
        [[ahead + length / 2, width / 2, 0.0], [ahead - length / 2, width / 2, 0.0],
         [ahead - length / 2, -width / 2, 0.0], [ahead + length / 2, -width / 2, 0.0]]
    )  # fmt: skip
    return _apply(m, corners)[:, :2]


def _rgba(c: Any, default: tuple[float, ...]) -> tuple[float, float, float, float]:
    if c is None or not (c.r or c.g or c.b or c.a):
        return (default[0], default[1], default[2], default[3])
    return (c.r, c.g, c.b, max(c.a, 0.3))


class _Painter:
    """Draws one scene on matplotlib axes and counts what it drew."""

    def __init__(self, ax: Any) -> None:
        self.ax = ax
        self.boxes = 0
        self.points = 0
        self.lines = 0

    def clouds(self, scene: _Scene) -> None:
        for topic, cloud in scene.clouds.items():
            m = scene.resolve(cloud.frame_id)
            if m is None:
                continue
            xy = _apply(m, cloud_xyz(cloud))[:, :2]
            self.points += len(xy)
            if "radar" in topic:
                self.ax.scatter(xy[:, 0], xy[:, 1], s=14, marker="x", c="tab:purple", zorder=3)
            else:
                self.ax.scatter(xy[:, 0], xy[:, 1], s=0.2, c="0.45", alpha=0.5, linewidths=0, zorder=2)

    def scenes(self, scene: _Scene) -> None:
        from matplotlib.patches import Polygon

        for topic, update in scene.scenes.items():
            background = topic in ("/map", "/route")
            for ent in update.entities:
                m = scene.resolve(ent.frame_id)
                if m is None:
                    continue
                for cube in ent.cubes:
                    cm = m @ _pose_matrix(cube.pose)
                    xy = _box_xy(cm, cube.size.x, cube.size.y)
                    self.ax.add_patch(
                        Polygon(xy, closed=True, fc=_rgba(cube.color, (1, 0.5, 0, 0.6)), zorder=4)
                    )
                    self.boxes += 1
                for line in ent.lines:
                    if not len(line.points):
                        continue
                    lm = m @ _pose_matrix(line.pose)
                    pts = np.array([(p.x, p.y, p.z) for p in line.points])
                    xy = _apply(lm, pts)[:, :2]
                    lw = 0.6 if background and topic == "/map" else 2.0
                    self.ax.plot(
                        xy[:, 0], xy[:, 1], "-", lw=lw, c=_rgba(line.color, (0, 0.8, 0.3, 1)), zorder=1
                    )
                    self.lines += 0 if background else 1

    def ego(self, scene: _Scene) -> tuple[float, float] | None:
        from matplotlib.patches import Polygon

        m = scene.resolve(BASE_FRAME)
        if m is None and scene.pose is not None:
            frame_m = scene.resolve(scene.pose.frame_id)
            m = frame_m @ _pose_matrix(scene.pose.pose) if frame_m is not None else None
        if m is None:
            return None
        xy = _box_xy(m, _EGO_LENGTH_M, _EGO_WIDTH_M, _EGO_CENTRE_AHEAD_M)
        self.ax.add_patch(Polygon(xy, closed=True, fc="tab:blue", alpha=0.9, zorder=5))
        return float(m[0, 3]), float(m[1, 3])


class _Titles:
    """The title of a picture at a time: the latest behaviour state and e-brake flag by then."""

    def __init__(self, recording: Recording) -> None:
        self.decisions = [
            (m.log_time_us, m.message) for m in recording.messages if isinstance(m.message, BehaviourDecision)
        ]
        self.commands = [
            (m.log_time_us, m.message) for m in recording.messages if isinstance(m.message, ActuatorCommand)
        ]

    @staticmethod
    def _latest(items: list[tuple[int, Any]], t_us: int) -> Any:
        k = bisect.bisect_right(items, t_us, key=lambda item: item[0])
        return items[k - 1][1] if k else None

    def at(self, t_us: int) -> str:
        return _title(self._latest(self.decisions, t_us), self._latest(self.commands, t_us), t_us)


def _title(decision: BehaviourDecision | None, cmd: ActuatorCommand | None, t_us: int) -> str:
    title = f"t = {t_us / 1e6:.2f} s"
    if decision is not None:
        title += f"  {decision.state.value}"
    if cmd is not None and cmd.emergency_brake:
        title += "  E-BRAKE"
    if cmd is not None and cmd.turn_signal is not TurnSignal.OFF:
        title += f"  indicators {cmd.turn_signal.value}"
    return title


def _frame_times(recording: Recording) -> tuple[int, int]:
    times = [v.log_time_us for v in recording.views] + [m.log_time_us for m in recording.messages]
    if not times:
        raise RecordingError(f"render: expected messages to draw, got none in {recording.path}")
    return min(times), max(times)


def _render(recording: Recording, times: list[int], paths: list[Path], view_m: float) -> list[RenderSummary]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    views = recording.views
    scene = _Scene(fixed=fixed_frame_of(views))
    titles = _Titles(recording)
    out: list[RenderSummary] = []
    i = 0
    fig, ax = plt.subplots(figsize=(7.0, 7.0), dpi=100)
    try:
        for t, path in zip(times, paths, strict=True):
            while i < len(views) and views[i].log_time_us <= t:
                scene.add(views[i])
                i += 1
            ax.clear()
            p = _Painter(ax)
            p.scenes(scene)
            p.clouds(scene)
            centre = p.ego(scene)
            cx, cy = centre if centre is not None else (0.0, 0.0)
            ax.set_xlim(cx - view_m / 2, cx + view_m / 2)
            ax.set_ylim(cy - view_m / 2, cy + view_m / 2)
            ax.set_aspect("equal")
            ax.set_xlabel(f"x [m] ({scene.fixed} frame)")
            ax.set_ylabel("y [m]")
            ax.set_title(titles.at(t), fontsize=9)
            fig.savefig(path)
            out.append(RenderSummary(path, t, scene.fixed, centre is not None, p.boxes, p.points, p.lines))
    finally:
        plt.close(fig)
    return out


def default_render_time(recording: Recording) -> int:
    """The first trigger's time when the recording has one (the incident), else its last message."""
    first, last = _frame_times(recording)
    if recording.events:
        return min(max(int(recording.events[0]["time_us"]), first), last)
    return last


def render_png(
    recording: Recording, out_file: str | Path, *, at_us: int | None = None, view_m: float = 60.0
) -> RenderSummary:
    """One top-down picture at ``at_us`` (default :func:`default_render_time`) into a new PNG file.

    Raises:
        RecordingError: ``out_file`` exists (never overwritten) or the recording holds nothing.
    """
    out = Path(out_file)
    if out.exists():
        raise RecordingError(f"--render: expected a new file, got {out}, which exists (not overwritten)")
    t = default_render_time(recording) if at_us is None else at_us
    out.parent.mkdir(parents=True, exist_ok=True)
    return _render(recording, [t], [out], view_m)[0]


def render_png_sequence(
    recording: Recording,
    out_dir: str | Path,
    *,
    fps: float = 10.0,
    view_m: float = 60.0,
    max_frames: int | None = None,
) -> list[Path]:
    """Top-down frames ``out_dir/frame_00000.png ...`` at ``fps`` of log time.

    Raises:
        RecordingError: ``out_dir`` is a file or already holds frames (never overwritten).
    """
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise RecordingError(f"--render: expected a directory for the frames, got {out}, which is a file")
    if out.is_dir() and any(out.glob("frame_*.png")):
        raise RecordingError(f"--render: expected a directory without frames, got {out}, which has some")
    out.mkdir(parents=True, exist_ok=True)
    t0, t1 = _frame_times(recording)
    step = max(round(1e6 / fps), 1)
    times = list(range(t0, t1 + 1, step))
    if max_frames is not None:
        times = times[:max_frames]
    paths = [out / f"frame_{k:05d}.png" for k in range(len(times))]
    _render(recording, times, paths, view_m)
    return paths
