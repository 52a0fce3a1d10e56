"""``lastmile calibrate camera``: LiDAR-to-camera calibration from a folder of image + cloud pairs.

The folder holds one image (``.png``, ``.jpg``, ``.jpeg``) and one LiDAR cloud (``.pcd`` or KITTI
``.bin``, read by ``perception/cloud_files.py``) per view, paired by file stem (``view03.png`` with
``view03.pcd``); a cloud may stack several sweeps of the board held still. The intrinsics are a small
TOML or YAML file (``fx fy cx cy width height`` and optionally ``k1 k2 p1 p2 k3``), or a ROS
``camera_info`` YAML (``camera_calibration``'s ``camera_matrix``/``distortion_coefficients``, or the
message's ``k``/``d``). Each view's board is found (``localization/checkerboard_detection.py``), and the
mount is solved (``localization/camera_lidar_calibration.py``).

Like ``lidar_calibration_replay.py``, this feeds files to one module alone: no vehicle, no loop.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from lastmile.core.config import load_toml
from lastmile.core.errors import CalibrationError, ConfigError, MessageError
from lastmile.localization.camera_lidar_calibration import (
    CameraLidarCalibration,
    CameraLidarConfig,
    SkippedView,
    calibrate_camera_lidar,
)
from lastmile.localization.camera_mount_file import (
    CameraMountRow,
    MountPose,
    body_pose,
    camera_from_parent,
    degrees_text,
)
from lastmile.localization.checkerboard_detection import (
    BoardView,
    CameraIntrinsics,
    Checkerboard,
    detect_board,
    opencv,
)
from lastmile.perception.cloud_files import read_clouds

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")
CLOUD_SUFFIXES = (".pcd", ".bin")
_PLAIN_KEYS = ("fx", "fy", "cx", "cy", "width", "height")
_DISTORTION_KEYS = ("k1", "k2", "p1", "p2", "k3")


def parse_board(text: str, square_m: float) -> Checkerboard:
    """``--board COLSxROWS`` (inner corners) and ``--square`` (m)."""
    parts = text.lower().split("x")
    if len(parts) != 2 or not all(p.strip().isdigit() for p in parts):
        raise ConfigError(f"--board: expected COLSxROWS inner corners such as 7x5, got {text!r}")
    return Checkerboard(cols=int(parts[0]), rows=int(parts[1]), square_m=square_m)


def parse_mount(text: str, option: str) -> MountPose:
    """``x,y,z,roll,pitch,yaw`` (m and degrees) as a pose."""
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        values = []
    if len(values) != 6 or not all(math.isfinite(v) for v in values):
        raise ConfigError(f"{option}: expected x,y,z,roll,pitch,yaw (m, m, m, deg, deg, deg), got {text!r}")
    x, y, z, roll, pitch, yaw = values
    return MountPose(
        x_m=x, y_m=y, z_m=z, roll_rad=math.radians(roll), pitch_rad=math.radians(pitch),
        yaw_rad=math.radians(yaw),
    )  # fmt: skip


def read_intrinsics(path: Path) -> CameraIntrinsics:
    """A camera's intrinsics from TOML or YAML (plain keys or ROS ``camera_info``).

    Raises:
        ConfigError: unreadable file, unknown layout, a missing or non-numeric key, a distortion model
            other than plumb_bob / rational with more than five coefficients used.
    """
    data = _mapping(path)
    if "camera_matrix" in data or "k" in data or "K" in data:
        return _camera_info(path, data)
    unknown = sorted(set(data) - set(_PLAIN_KEYS) - set(_DISTORTION_KEYS))
    if unknown:
        raise ConfigError(
            f"{path}: unknown key {unknown[0]!r}; expected {', '.join(_PLAIN_KEYS + _DISTORTION_KEYS)} "
            "or a ROS camera_info YAML"
        )
    missing = [k for k in _PLAIN_KEYS if k not in data]
    if missing:
        raise ConfigError(f"{path}: missing required key {missing[0]!r} (expected {', '.join(_PLAIN_KEYS)})")
    fx, fy, cx, cy = (_number(path, k, data[k]) for k in _PLAIN_KEYS[:4])
    width, height = (_integer(path, k, data[k]) for k in _PLAIN_KEYS[4:])
    k1, k2, p1, p2, k3 = (_number(path, k, data.get(k, 0.0)) for k in _DISTORTION_KEYS)
    return CameraIntrinsics(
        fx_px=fx, fy_px=fy, cx_px=cx, cy_px=cy, width_px=width, height_px=height,
        distortion=(k1, k2, p1, p2, k3),
    )  # fmt: skip


def _camera_info(path: Path, data: dict[str, Any]) -> CameraIntrinsics:
    if "camera_matrix" in data:  # camera_calibration's ost.yaml
        k = _matrix_data(path, "camera_matrix", data["camera_matrix"], 9)
        d_raw = data.get("distortion_coefficients", {"data": []})
        d = _matrix_data(path, "distortion_coefficients", d_raw, None)
        width, height = data.get("image_width"), data.get("image_height")
        size_keys = ("image_width", "image_height")
    else:  # a sensor_msgs/CameraInfo message as YAML
        key_k = "k" if "k" in data else "K"
        key_d = "d" if "d" in data else "D"
        k = _list(path, key_k, data[key_k], 9)
        d = _list(path, key_d, data.get(key_d, []), None)
        width, height = data.get("width"), data.get("height")
        size_keys = ("width", "height")
    model = str(data.get("distortion_model", "plumb_bob"))
    if model not in ("plumb_bob", "rational_polynomial"):
        raise ConfigError(
            f"{path}: distortion_model: expected plumb_bob or rational_polynomial, got {model!r}"
        )
    if len(d) > 5 and any(v != 0.0 for v in d[5:]):
        raise ConfigError(
            f"{path}: distortion: expected at most k1 k2 p1 p2 k3 (plumb_bob), got {len(d)} coefficients "
            "with the rational terms set"
        )
    coeffs = (list(d) + [0.0] * 5)[:5]
    if width is None or height is None:
        raise ConfigError(
            f"{path}: missing required key {size_keys[0]!r} or {size_keys[1]!r} (the image size)"
        )
    return CameraIntrinsics(
        fx_px=k[0], fy_px=k[4], cx_px=k[2], cy_px=k[5],
        width_px=_integer(path, size_keys[0], width), height_px=_integer(path, size_keys[1], height),
        distortion=(coeffs[0], coeffs[1], coeffs[2], coeffs[3], coeffs[4]),
    )  # fmt: skip


def read_views(
    folder: Path, intrinsics: CameraIntrinsics, board: Checkerboard
) -> tuple[list[tuple[BoardView, np.ndarray]], list[SkippedView]]:
    """Every image + cloud pair of ``folder``: the views whose board was found, and the others.

    Raises:
        ConfigError: not a folder, no pairs, or files without their pair (one line naming them).
        MessageError: an unreadable image or cloud.
    """
    if not folder.is_dir():
        raise ConfigError(f"{folder}: expected a folder of image + cloud pairs, got no such folder")
    images = _by_stem(folder, IMAGE_SUFFIXES, "image")
    clouds = _by_stem(folder, CLOUD_SUFFIXES, "cloud")
    lonely_images = sorted(set(images) - set(clouds))
    lonely_clouds = sorted(set(clouds) - set(images))
    if lonely_images or lonely_clouds:
        what = (
            f"image(s) without a cloud: {', '.join(lonely_images[:5])}"
            if lonely_images
            else f"cloud(s) without an image: {', '.join(lonely_clouds[:5])}"
        )
        raise ConfigError(f"{folder}: expected each image paired with a cloud of the same name, got {what}")
    if not images:
        raise ConfigError(
            f"{folder}: expected image + cloud pairs ({'/'.join(IMAGE_SUFFIXES)} with "
            f"{'/'.join(CLOUD_SUFFIXES)} of the same name), got none"
        )
    cv2 = opencv()
    views: list[tuple[BoardView, np.ndarray]] = []
    skipped: list[SkippedView] = []
    for stem in sorted(images):
        image = cv2.imread(str(images[stem]), cv2.IMREAD_GRAYSCALE)
        if image is None:
            raise MessageError(f"{images[stem]}: expected a PNG or JPEG image, got a file OpenCV cannot read")
        cloud = np.concatenate([c.xyz_m for c in read_clouds(clouds[stem])]).astype(np.float64)
        try:
            views.append((detect_board(image, intrinsics, board, stem), cloud))
        except (CalibrationError, MessageError) as exc:
            skipped.append(SkippedView(name=stem, reason=str(exc).removeprefix(f"{stem}: ")))
    return views, skipped


def calibrate_folder(
    folder: Path,
    intrinsics: CameraIntrinsics,
    board: Checkerboard,
    nominal_in_lidar: MountPose,
    config: CameraLidarConfig | None = None,
) -> CameraLidarCalibration:
    """The LiDAR-to-camera mount from a folder of pairs, starting from the camera's nominal pose in
    the LiDAR frame."""
    views, skipped = read_views(folder, intrinsics, board)
    return calibrate_camera_lidar(views, board, camera_from_parent(nominal_in_lidar), config, skipped)


def mount_row(camera_id: str, cal: CameraLidarCalibration, lidar_in_base: MountPose) -> CameraMountRow:
    """The calibrated camera as a ``[[camera_mount]]`` row in the base frame."""
    base_from_lidar = lidar_in_base.parent_from_child()
    camera_from_base = cal.camera_from_lidar @ np.linalg.inv(base_from_lidar)
    pose = body_pose(camera_from_base)
    return CameraMountRow(
        camera_id=camera_id,
        x_m=pose.x_m,
        y_m=pose.y_m,
        z_m=pose.z_m,
        roll_rad=pose.roll_rad,
        pitch_rad=pose.pitch_rad,
        yaw_rad=pose.yaw_rad,
        source="calibrated",
        correction_m=cal.correction_m,
        correction_deg=math.degrees(cal.correction_rad),
        views=len(cal.views),
        rmse_m=cal.rmse_m,
        normal_spread_deg=math.degrees(cal.normal_spread_rad),
        in_lidar=body_pose(cal.camera_from_lidar),
        lidar_in_base=lidar_in_base,
    )


VIEW_COLUMNS = ("view", "board points", "RMSE before cm", "RMSE after cm", "corners px", "skipped")


def view_rows(cal: CameraLidarCalibration) -> list[tuple[str, ...]]:
    """Per view: name, LiDAR board points, RMSE under the nominal and the calibrated mount, PnP fit."""
    rows: list[tuple[str, ...]] = [
        (
            v.name,
            str(v.board_points),
            f"{v.nominal_rmse_m * 100:.2f}",
            f"{v.rmse_m * 100:.2f}",
            f"{v.reprojection_rmse_px:.2f}",
            "",
        )
        for v in cal.views
    ]
    rows += [(s.name, "", "", "", "", s.reason) for s in cal.skipped]
    return rows


def summary_lines(cal: CameraLidarCalibration, row: CameraMountRow) -> list[str]:
    """Before / after in the LiDAR frame, the mount in the base frame, the correction, fit and spread."""
    spread_axis = ", ".join(f"{v:+.2f}" for v in cal.weakest_direction)
    return [
        f"camera in the LiDAR frame, before: {degrees_text(body_pose(cal.nominal_camera_from_lidar))}",
        f"camera in the LiDAR frame, after:  {degrees_text(body_pose(cal.camera_from_lidar))}",
        f"camera {row.camera_id} in the base frame, after: {degrees_text(body_pose(row.camera_from_base()))}",
        f"correction {cal.correction_m * 100:.2f} cm, {math.degrees(cal.correction_rad):.3f} deg; "
        f"{len(cal.views)} views ({len(cal.skipped)} skipped), RMSE {cal.rmse_m * 100:.2f} cm; board normals "
        f"tilt {math.degrees(cal.normal_spread_rad):.1f} deg RMS towards their least-covered direction "
        f"({spread_axis}, camera frame)",
    ]


def _by_stem(folder: Path, suffixes: tuple[str, ...], what: str) -> dict[str, Path]:
    out: dict[str, Path] = {}
    for path in sorted(folder.iterdir()):
        if not path.is_file() or path.suffix.lower() not in suffixes:
            continue
        if path.stem in out:
            raise ConfigError(
                f"{folder}: expected one {what} per view name, got {out[path.stem].name} and {path.name}"
            )
        out[path.stem] = path
    return out


def _mapping(path: Path) -> dict[str, Any]:
    if path.suffix.lower() == ".toml":
        return load_toml(path)
    if path.suffix.lower() not in (".yaml", ".yml"):
        raise ConfigError(f"{path}: expected intrinsics as .toml, .yaml or .yml, got {path.suffix!r}")
    import yaml

    try:
        data = yaml.safe_load(path.read_text())
    except FileNotFoundError:
        raise ConfigError(f"{path}: expected an intrinsics file, got no such file") from None
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path}: expected valid YAML, got {type(exc).__name__}") from None
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: expected a mapping of intrinsics, got {type(data).__name__}")
    return data


def _number(path: Path, key: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ConfigError(f"{path}: {key}: expected a finite number, got {value!r}")
    return float(value)


def _integer(path: Path, key: str, value: Any) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value <= 0:
        raise ConfigError(f"{path}: {key}: expected a positive integer (pixels), got {value!r}")
    return value


def _list(path: Path, key: str, value: Any, size: int | None) -> list[float]:
    if not isinstance(value, list) or (size is not None and len(value) != size):
        want = f"{size} numbers" if size is not None else "a list of numbers"
        raise ConfigError(f"{path}: {key}: expected {want}, got {value!r}")
    return [_number(path, f"{key}[{i}]", v) for i, v in enumerate(value)]


def _matrix_data(path: Path, key: str, value: Any, size: int | None) -> list[float]:
    if not isinstance(value, dict) or "data" not in value:
        raise ConfigError(f"{path}: {key}: expected a table with rows, cols and data, got {value!r}")
    return _list(path, f"{key}.data", value["data"], size)
